"""Many granules (DESIGN 6): serial == processes == Dask byte for byte; reruns skip;
a corrupt granule is reported and the rest complete; numbers equal a direct validation."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest

from canopyblocks.errors import InputError, NoUsableDataError
from canopyblocks.readers.las import read_las
from canopyblocks.simulate import SimParams, line_through, simulate_photons
from canopyblocks.simulate.writers import write_simulation_atl03
from canopyblocks.workflows.batch import BatchConfig, find_units, run_batch, tile_index

pytestmark = [pytest.mark.pdal, pytest.mark.slow,
              pytest.mark.filterwarnings("ignore::canopyblocks.errors.CanopyBlocksWarning")]

# the paper's method: its blocks do not depend on the photons outside them, so a unit (the
# photons over its tiles) equals the whole track blocked directly, block for block
CONFIG = BatchConfig(lengths=(25.0,), width=13.0, offset=0.0, preset="paper")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, sample, pdal_bin):
    root = tmp_path_factory.mktemp("batch_in")
    tiles = root / "tiles"
    tiles.mkdir()
    for name in ("lasR_bcts_1.laz", "lasR_bcts_2.laz"):
        shutil.copy(sample(f"als/{name}"), tiles / name)
    pts = read_las(sorted(str(p) for p in tiles.iterdir()))
    b = pts.bounds
    cx, cy = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2
    granules = root / "granules"
    granules.mkdir()
    for i, (az, dx) in enumerate(((10.0, -40.0), (10.0, 30.0), (5.0, 0.0))):
        tr = line_through(b, az, centre=(cx + dx, cy), inset=7, name="gt1r")
        sim = simulate_photons(pts, tr, SimParams(), realisations=2, seed=20 + i)
        write_simulation_atl03(sim, granules / f"ATL03_sim{i}.h5", realisations=(0, 1))
    # a corrupt granule among good ones: a truncated copy
    good = (granules / "ATL03_sim0.h5").read_bytes()
    (granules / "ATL03_sim9_truncated.h5").write_bytes(good[: len(good) // 3])
    return {"granules": granules, "tiles": tiles}


def _files(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and "rasters" not in p.parts and p.name != "report.html"}


def test_units_from_tracks_and_tiles(inputs):
    idx = tile_index(sorted(str(p) for p in inputs["tiles"].iterdir()))
    good = sorted(str(p) for p in inputs["granules"].iterdir() if "truncated" not in p.name)
    units = find_units(good, idx)
    # each simulated granule has 2 beams, each crossing both tiles (north-south tracks)
    assert len(units) == 6
    assert all(len(u.tiles) == 2 for u in units)
    assert [u.key for u in units] == sorted(u.key for u in units)


def test_serial_processes_and_dask_agree(inputs, tmp_path):
    pytest.importorskip("distributed")
    good = sorted(str(p) for p in inputs["granules"].iterdir() if "truncated" not in p.name)
    outs = {}
    for backend in ("serial", "processes", "dask"):
        out = tmp_path / backend
        res = run_batch(good, [inputs["tiles"]], out, CONFIG, backend=backend, workers=2)
        assert not res.failed, res.failed
        outs[backend] = _files(out)
    assert outs["serial"].keys() == outs["processes"].keys() == outs["dask"].keys()
    for name in outs["serial"]:
        assert outs["serial"][name] == outs["processes"][name], name
        assert outs["serial"][name] == outs["dask"][name], name


def test_rerun_skips_and_corrupt_granule_is_reported(inputs, tmp_path):
    out = tmp_path / "run"
    res = run_batch([inputs["granules"]], [inputs["tiles"]], out, CONFIG)
    bad = [u for u in res.units if "truncated" in u["key"]]
    assert res.failed == bad and len(bad) == 1  # the corrupt granule, reported
    assert "truncated or corrupt" in bad[0]["error"]
    ok = [u for u in res.units if u["status"] == "ok"]
    assert len(ok) == 6
    manifest = json.loads((out / "manifest.json").read_text())
    assert {u["key"] for u in manifest["units"]} >= {u["key"] for u in ok}
    stats = (out / "stats.csv").read_text()
    assert "hmax" in stats
    before = {p: p.stat().st_mtime_ns for p in (out / "parts").rglob("*.parquet")}
    again = run_batch([inputs["granules"]], [inputs["tiles"]], out, CONFIG)
    assert again.skipped == 6
    after = {p: p.stat().st_mtime_ns for p in (out / "parts").rglob("*.parquet")}
    assert before == after  # nothing recomputed
    assert (out / "stats.csv").read_text() == stats


def test_batch_numbers_equal_a_direct_validation(inputs, tmp_path):
    """One unit's residuals equal the whole track's blocks validated directly against the
    unit's corridor rasters (one set over both tiles: a block over their seam sees both)."""
    from canopyblocks.blocks import BlockParams, compute_blocks
    from canopyblocks.outputs.tables import read_layer
    from canopyblocks.readers import read_atl03
    from canopyblocks.validation.block_validation import validate_blocks

    g = str(inputs["granules"] / "ATL03_sim1.h5")
    out = tmp_path / "one"
    run_batch([g], [inputs["tiles"]], out, CONFIG, beams=["gt1r"])
    got = read_layer(next((out / "parts").rglob("residuals.parquet")))
    rasters = out / "rasters" / "ATL03_sim1" / "gt1r"
    track = read_atl03(g, "gt1r", crs=got.crs)
    blocks = compute_blocks(track, BlockParams(lengths=(25.0,)))
    direct = validate_blocks(blocks, dtm=rasters / "dtm.tif",
                             dsm_max=rasters / "dsm_max.tif", dsm_p90=rasters / "dsm_p90.tif",
                             width=13.0, offset=0.0).residuals
    mine = got[got["use"]].sort_values("block")
    direct = direct[direct["use"]].sort_values("block")
    assert len(mine) > 10
    assert set(mine["tile"]) == {p.name for p in inputs["tiles"].iterdir()}
    np.testing.assert_array_equal(mine["block"].to_numpy(), direct["block"].to_numpy())
    for c in ("res_ground", "res_hmax", "ref_top"):
        np.testing.assert_allclose(mine[c].to_numpy(float), direct[c].to_numpy(float),
                                   equal_nan=True)


def test_bad_batch_arguments(inputs, tmp_path, sample):
    with pytest.raises(InputError, match="backend"):
        run_batch([inputs["granules"]], [inputs["tiles"]], tmp_path, CONFIG,
                  backend="spark")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="no input files"):
        run_batch([tmp_path], [inputs["tiles"]], tmp_path / "o", CONFIG)
    with pytest.raises(InputError, match="width"):
        BatchConfig(width=0)
    far = tmp_path / "far"
    far.mkdir()
    with pytest.raises(NoUsableDataError, match="crosses"):
        # the harmony granule is sea ice elsewhere on Earth
        shutil.copy(sample("icesat2/harmony_ATL03_gt1l.h5"), far / "ATL03_far.h5")
        run_batch([far], [inputs["tiles"]], tmp_path / "o2", CONFIG)


# ---- issue 23: granules that miss the tiles, output folder, datum rule ----------------------


def test_a_granule_missing_the_tiles_is_listed_as_skipped(inputs, tmp_path, sample):
    from canopyblocks.cli import main

    grans = tmp_path / "grans"
    grans.mkdir()
    shutil.copy(inputs["granules"] / "ATL03_sim1.h5", grans / "ATL03_sim1.h5")
    # the harmony granule is sea ice elsewhere on Earth: thousands of km from the tiles
    shutil.copy(sample("icesat2/harmony_ATL03_gt1l.h5"), grans / "ATL03_far.h5")
    out = tmp_path / "out"
    res = run_batch([grans], [inputs["tiles"]], out, CONFIG)
    (far,) = res.not_crossing
    assert far["key"] == "ATL03_far.h5:*" and far["status"] == "skipped"
    km = float(far["error"].split(" passes ")[-1].split(" km")[0].replace(",", ""))
    assert km > 1000.0, far["error"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert any(u["key"] == "ATL03_far.h5:*" and u["status"] == "skipped"
               for u in manifest["units"])
    assert "ATL03_far.h5" in (out / "report.html").read_text()
    code = main(["-q", "batch", str(grans), "--tiles", str(inputs["tiles"]), "-o",
                 str(tmp_path / "cli"), "--offset", "0", "--backend", "serial"])
    assert code == 0


def test_batch_cli_says_which_granule_was_skipped(inputs, tmp_path, sample):
    import subprocess
    import sys

    grans = tmp_path / "grans"
    grans.mkdir()
    shutil.copy(inputs["granules"] / "ATL03_sim1.h5", grans / "ATL03_sim1.h5")
    shutil.copy(sample("icesat2/harmony_ATL03_gt1l.h5"), grans / "ATL03_far.h5")
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "batch", str(grans), "--tiles",
                        str(inputs["tiles"]), "-o", str(tmp_path / "out"), "--offset", "0",
                        "--backend", "serial"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "skipped" in r.stderr and "ATL03_far.h5" in r.stderr and "km" in r.stderr


@pytest.mark.parametrize("where", ["same", "inside"])
def test_output_folder_in_the_input_folder_refused(inputs, tmp_path, where):
    grans = tmp_path / "grans"
    shutil.copytree(inputs["granules"], grans)
    out = grans if where == "same" else grans / "results"
    before = sorted(p.name for p in grans.iterdir())
    with pytest.raises(InputError, match="input folder") as e:
        run_batch([grans], [inputs["tiles"]], out, CONFIG)
    assert str(grans) in str(e.value)
    assert sorted(p.name for p in grans.iterdir()) == before  # nothing written into it


def test_batch_applies_the_datum_rule_at_the_door(inputs, tmp_path):
    """The tiles are CGVD28 (EPSG:5713, from their GeoTIFF keys); ATL03 heights are
    ellipsoidal: without --geoid/--offset the batch is refused before any work, as
    validate, run and calibrate refuse it."""
    from canopyblocks.errors import DatumError

    out = tmp_path / "out"
    with pytest.raises(DatumError, match="CGVD28"):
        run_batch([inputs["granules"]], [inputs["tiles"]], out, BatchConfig(lengths=(25.0,)))
    assert not out.exists()


def test_rerun_with_other_settings_refused(inputs, tmp_path):
    """A rerun reuses finished units and rasters: with another corridor width or raster
    resolution they would be reported as if made with the new settings."""
    out = tmp_path / "out"
    g = str(inputs["granules"] / "ATL03_sim1.h5")
    run_batch([g], [inputs["tiles"]], out, CONFIG, beams=["gt1r"])
    stats = (out / "stats.csv").read_text()
    other = BatchConfig(lengths=(25.0,), width=7.0, offset=0.0)
    with pytest.raises(InputError, match=r"width 13\.0 -> 7\.0"):
        run_batch([g], [inputs["tiles"]], out, other, beams=["gt1r"])
    assert (out / "stats.csv").read_text() == stats
    again = run_batch([g], [inputs["tiles"]], out, CONFIG, beams=["gt1r"])
    assert again.skipped == 1


def test_one_merged_table_beside_the_partitions(inputs, tmp_path):
    """residuals.parquet holds every unit's rows, in unit order, equal to the partitions."""
    from canopyblocks.outputs.tables import read_layer

    good = sorted(str(p) for p in inputs["granules"].iterdir() if "truncated" not in p.name)
    out = tmp_path / "merged"
    res = run_batch(good, [inputs["tiles"]], out, CONFIG)
    ok = [u for u in res.units if u["status"] == "ok"]
    parts = [read_layer(out / u["files"][1]) for u in ok]
    merged = read_layer(out / "residuals.parquet")
    assert len(merged) == sum(len(p) for p in parts) > 0
    assert merged.crs == parts[0].crs
    want = pd.concat([pd.DataFrame(p) for p in parts], ignore_index=True)
    for c in ("granule", "track", "block", "res_ground", "res_hmax", "x", "y"):
        np.testing.assert_array_equal(merged[c].to_numpy(), want[c].to_numpy())
    assert merged.geometry.geom_equals(gpd.GeoSeries(want.geometry, crs=merged.crs)).all()


def test_merged_table_in_one_crs_across_utm_zones():
    """Units in two UTM zones: the second is reprojected into the first's CRS, its x/y
    recomputed from lon/lat (checked against pyproj directly)."""
    from pyproj import Transformer
    from shapely.geometry import Point

    from canopyblocks.workflows.batch.runner import merged_residuals

    def unit(lon: float, epsg: int) -> gpd.GeoDataFrame:
        lons, lats = np.array([lon, lon + 0.001]), np.array([45.0, 45.001])
        x, y = Transformer.from_crs("EPSG:4326", epsg, always_xy=True).transform(lons, lats)
        return gpd.GeoDataFrame({"lon": lons, "lat": lats, "x": x, "y": y,
                                 "res_hmax": [1.0, 2.0]},
                                geometry=[Point(a, b).buffer(5) for a, b in zip(x, y)],
                                crs=f"EPSG:{epsg}")

    a, b = unit(-122.9, 32610), unit(-117.1, 32611)
    m = merged_residuals([a, b])
    assert m.crs.to_epsg() == 32610 and len(m) == 4
    x, y = Transformer.from_crs("EPSG:4326", 32610, always_xy=True).transform(
        b["lon"].to_numpy(), b["lat"].to_numpy())
    np.testing.assert_allclose(m["x"].to_numpy()[2:], x, atol=1e-6)
    np.testing.assert_allclose(m["y"].to_numpy()[2:], y, atol=1e-6)
    c = m.geometry.iloc[2:].centroid
    np.testing.assert_allclose(c.x.to_numpy(), x, atol=0.05)  # the buffer's centre moved too
    np.testing.assert_allclose(m["x"].to_numpy()[:2], a["x"].to_numpy())  # first unit as is


def test_the_same_photons_never_count_twice(inputs, tmp_path):
    """A granule given again (a path through '..', a renamed copy) is counted once, with a
    warning; the merged table is the single granule's, rows and time_utc included."""
    from canopyblocks.errors import CanopyBlocksWarning
    from canopyblocks.outputs.tables import read_layer
    from canopyblocks.readers import read_atl03

    g0 = inputs["granules"] / "ATL03_sim0.h5"
    copy = tmp_path / "renamed_copy.h5"
    shutil.copy(g0, copy)
    dotted = str(inputs["granules"] / ".." / "granules" / g0.name)
    one = run_batch([str(g0)], [inputs["tiles"]], tmp_path / "one", CONFIG)
    with pytest.warns(CanopyBlocksWarning, match="same photons") as caught:
        many = run_batch([str(g0), dotted, str(copy)], [inputs["tiles"]], tmp_path / "many",
                         CONFIG)
    assert sum("same photons" in str(w.message) for w in caught) == 2
    assert len(many.units) == len(one.units)
    a = read_layer(tmp_path / "one" / "residuals.parquet")
    b = read_layer(tmp_path / "many" / "residuals.parquet")
    assert len(b) == len(a) > 0
    np.testing.assert_array_equal(a["res_hmax"].to_numpy(), b["res_hmax"].to_numpy())
    # each block's time: inside the photons' own time span (a simulated clock: UTC is NaT)
    assert "time_utc" in b.columns and b.columns.get_loc("time_utc") == b.columns.get_loc("time") + 1
    t = read_atl03(g0, "gt1r").time
    assert ((b["time"] >= t.min()) & (b["time"] <= t.max())).all()


def test_a_unit_over_part_of_the_track_gives_the_whole_tracks_blocks(inputs, tmp_path):
    """With one tile of two, the track runs on beyond the unit's box: its blocks are still
    the whole track's (same grid, each block whole), every column equal."""
    from canopyblocks import BlockParams, blocks_from_file
    from canopyblocks.blocks.estimators import preset
    from canopyblocks.outputs.tables import read_layer

    g = str(inputs["granules"] / "ATL03_sim1.h5")
    tile = sorted(inputs["tiles"].iterdir())[0]
    out = tmp_path / "part"
    cfg = BatchConfig(lengths=(10.0, 25.0, 50.0), width=13.0, offset=0.0, preset="paper")
    run_batch([g], [tile], out, cfg, beams=["gt1r"])
    got = read_layer(next((out / "parts").rglob("blocks.parquet")))
    full = blocks_from_file(g, BlockParams(lengths=cfg.lengths), estimators=preset("paper"),
                            beams=["gt1r"], crs=got.crs, workers=1).blocks
    assert 10 < len(got) < len(full)  # a part of the track
    m = got.merge(full, on=["track", "length", "block"], how="left",
                  suffixes=("", "_full"), indicator=True)
    assert (m["_merge"] == "both").all()
    for c in ("s_start", "s_end", "n_photons", "n_kept", "top", "ground", "hmax", "h90"):
        np.testing.assert_allclose(m[c].to_numpy(float), m[f"{c}_full"].to_numpy(float),
                                   rtol=0, atol=1e-9, equal_nan=True, err_msg=c)
    assert (m["flag"] == m["flag_full"]).all()
