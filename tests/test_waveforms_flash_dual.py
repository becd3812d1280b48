"""``canopyblocks waveforms``, ``validate`` and ``run`` on the flash-lidar (ESFL) cubes and
dual-wavelength pairs ``canopyblocks simulate`` writes.

Independent checks: the simulator's truth in the file (per footprint: the illumination-
weighted mean of the class-2 points, and the highest point) for the footprints; for the
validation, the statistics recomputed here from the residual rows and the reference
ground recomputed from the class-2 points themselves.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import h5py
import numpy as np
import pytest

from canopyblocks.errors import FileFormatError


def _cli(*args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "canopyblocks", *map(str, args)],
                          capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def files(sample, tmp_path_factory) -> dict[str, Path]:
    """ESFL cubes and dual pairs simulated over the pyfor tile (a short line each)."""
    d = tmp_path_factory.mktemp("flash_dual")
    las = sample("als/pyfor_test.laz")
    out = {"las": Path(las)}
    for sensor in ("esfl", "dual"):
        path = d / f"{sensor}.h5"
        r = _cli("simulate", las, "--sensor", sensor, "--azimuth", "10", "--seed", "3",
                 "-o", path)
        assert r.returncode == 0, r.stderr
        out[sensor] = path
    return out


def test_esfl_footprints_against_the_simulators_truth(files, tmp_path):
    out = tmp_path / "esfl.gpkg"
    r = _cli("waveforms", files["esfl"], "--cell", "0", "-o", out)   # one row per footprint
    assert r.returncode == 0, r.stderr
    fp = gpd.read_file(out, layer="footprints")
    px = gpd.read_file(out, layer="pixels")
    with h5py.File(files["esfl"]) as f:
        truth_ground = f["truth/ground"][:]
        truth_top = f["truth/top"][:]
        x, y = f["x"][:], f["y"][:]
    assert len(fp) == truth_ground.size
    assert {"beam", "shot_number", "lon", "lat", "ground", "top", "height", "flag"} \
        <= set(fp.columns)
    assert set(fp["beam"]) == {"ESFL"} and fp.crs.to_epsg() == 32617
    assert fp.geometry.has_z.all()
    ok = fp["flag"].to_numpy() == "ok"
    assert ok.sum() >= 0.8 * len(fp)
    # ground: the lowest Gaussian of the 4 x 4 pixels against the weighted class-2 mean
    err = fp["ground"].to_numpy(float)[ok] - truth_ground[ok]
    assert np.median(np.abs(err)) < 0.3 and np.abs(err).max() < 1.5
    # top: the 4 x 4 region (2.8 m) sees at most the 8.4 m footprint's highest point
    # (but for a noise sample over the threshold now and then)
    dtop = fp["top"].to_numpy(float)[ok] - truth_top[ok]
    assert np.mean(dtop < 1.0) >= 0.9 and np.median(dtop) > -1.5
    np.testing.assert_allclose(fp["height"], fp["top"] - fp["ground"], equal_nan=True)
    # positions: the footprint centres the simulator wrote (pixel means, within a pixel)
    gx, gy = fp.geometry.x.to_numpy(), fp.geometry.y.to_numpy()
    assert np.hypot(gx - x, gy - y).max() < 0.7
    # the pixels: 16 (the 4 x 4 region, all bright under the 8.4 m beam) per footprint
    assert px.groupby("shot_number").size().median() == 16


def test_dual_footprints_against_the_simulators_truth(files, tmp_path):
    out = tmp_path / "dual.parquet"
    r = _cli("waveforms", files["dual"], "-o", out)
    assert r.returncode == 0, r.stderr
    fp = gpd.read_parquet(out)
    with h5py.File(files["dual"]) as f:
        truth_ground = f["truth/ground"][:]
    assert set(fp["beam"]) == {"dual"} and len(fp) == truth_ground.size
    ok = fp["flag"].to_numpy() == "ok"
    assert ok.sum() >= 5
    err = fp["ground"].to_numpy(float)[ok] - truth_ground[ok]
    assert np.abs(err).max() < 1.5
    # the tree height runs from the first return to the ground start, above the centre
    h = fp["height"].to_numpy(float)[ok]
    assert np.all((h > 0) & (h < 40))
    assert np.all(fp["ground_start"][ok] >= fp["ground"][ok])
    assert not (tmp_path / "dual_pixels.parquet").exists()


def test_validate_esfl_and_dual(files, tmp_path):
    from canopyblocks.readers.las import read_las

    pts = read_las(str(files["las"]))
    g = pts.classification == 2
    for sensor in ("esfl", "dual"):
        fp_path = tmp_path / f"{sensor}.gpkg"
        assert _cli("waveforms", files[sensor], "-o", fp_path).returncode == 0
        out = tmp_path / f"v_{sensor}.gpkg"
        r = _cli("validate", fp_path, "--points", files["las"], "-o", out)
        assert r.returncode == 0, r.stderr
        res = gpd.read_file(out, layer="residuals_footprints")
        stats = gpd.read_file(out, layer="stats_footprints")
        use = res["use"].to_numpy(bool)
        assert use.sum() >= 5
        for metric in ("ground", "height"):
            row = stats[(stats["metric"] == metric) & (stats["group"] == "all")].iloc[0]
            d = (res[metric] - res[f"ref_{metric}"]).to_numpy(float)[use]
            d = d[np.isfinite(d)]
            assert row["n"] == d.size
            assert row["rmse"] == pytest.approx(np.sqrt(np.mean(d * d)), rel=1e-9)
            assert row["bias"] == pytest.approx(d.mean(), rel=1e-9, abs=1e-12)
        # the reference ground is the tile's own: within the class-2 points' range nearby
        c = res[use].geometry.centroid
        for cx, cy, rg in zip(c.x, c.y, res.loc[use, "ref_ground"]):
            near = g & (np.hypot(pts.x - cx, pts.y - cy) < 15)
            assert pts.z[near].min() - 0.5 <= rg <= pts.z[near].max() + 0.5
        assert abs(stats.loc[stats["metric"] == "ground", "bias"].iloc[0]) < 3.0


def test_validate_esfl_needs_its_pixels(files, tmp_path):
    fp_path = tmp_path / "esfl.csv"
    assert _cli("waveforms", files["esfl"], "-o", fp_path).returncode == 0
    assert (tmp_path / "esfl_pixels.csv").exists()
    (tmp_path / "esfl_pixels.csv").unlink()
    r = _cli("validate", fp_path, "--points", files["las"], "--crs", "EPSG:32617",
             "-o", tmp_path / "v.gpkg")
    assert r.returncode == 2 and "pixels" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "v.gpkg").exists()


def test_options_of_the_other_sensor_are_refused(files, tmp_path):
    out = tmp_path / "x.gpkg"
    for path, extra, word in ((files["dual"], ("--fraction", "0.5"), "--fraction"),
                              (files["esfl"], ("--dual-method", "refined"), "--dual-method"),
                              (files["esfl"], ("--setting", "a2"), "--setting"),
                              (files["dual"], ("--beam", "BEAM0000"), "--beam")):
        r = _cli("waveforms", path, "-o", out, *extra)
        assert r.returncode == 2 and word in r.stderr and "Traceback" not in r.stderr
        assert not out.exists()


def test_esfl_options_change_the_chain(files, tmp_path):
    a, b = tmp_path / "a.gpkg", tmp_path / "b.gpkg"
    assert _cli("waveforms", files["esfl"], "-o", a).returncode == 0
    assert _cli("waveforms", files["esfl"], "--fraction", "0.9", "--noise-threshold", "6",
                "-o", b).returncode == 0
    pa, pb = (gpd.read_file(p, layer="pixels") for p in (a, b))
    assert len(pb) < len(pa)   # a higher energy fraction keeps fewer pixels


def test_waveform_product_refuses_other_files(sample, tmp_path):
    from canopyblocks.readers.flash_dual import waveform_product

    with pytest.raises(FileFormatError, match="blocks"):
        waveform_product(sample("icesat2/vegr_atl03_clip.h5"))
    p = tmp_path / "x.h5"
    p.write_text("not hdf5")
    with pytest.raises(FileFormatError, match="not HDF5"):
        waveform_product(p)


@pytest.mark.parametrize("sensor", ["esfl", "dual"])
def test_run_chain_leads_with_the_answer(files, tmp_path, sensor):
    out = tmp_path / sensor
    r = _cli("run", files["las"], "--sensor", sensor, "--azimuth", "10", "-o", out)
    assert r.returncode == 0, r.stderr
    for name in ("footprints.gpkg", "validation.gpkg", "stats.csv", "report.html",
                 f"{sensor}.h5"):
        assert (out / name).exists(), name
    html = (out / "report.html").read_text()
    first = html.index("<h2>")
    assert html[first:].startswith("<h2>Summary</h2>")
    assert html.index("canopy height bias") < html.index("<h2>", first + 1)
    assert "canopy height: n=" in r.stderr and "ground elevation: n=" in r.stderr
    # run on the file it simulated gives the same numbers
    again = tmp_path / f"{sensor}_again"
    r2 = _cli("run", files["las"], "--photons", out / f"{sensor}.h5", "-o", again)
    assert r2.returncode == 0, r2.stderr
    assert (again / "stats.csv").read_text() == (out / "stats.csv").read_text()


def test_run_noise_option_belongs_to_its_sensor(files, tmp_path):
    r = _cli("run", files["las"], "--sensor", "dual", "--esfl-noise", "0.02",
             "-o", tmp_path / "x")
    assert r.returncode == 2 and "--esfl-noise" in r.stderr
    assert not (tmp_path / "x").exists()


def test_info_tells_the_products_apart(files):
    for sensor, word in (("esfl", "ESFL flash-lidar cubes"),
                         ("dual", "dual-wavelength waveform pairs")):
        r = _cli("info", files[sensor])
        assert r.returncode == 0, r.stderr
        with h5py.File(files[sensor]) as f:
            n = f["x"].shape[0]
        assert word in r.stdout and f"shots: {n}" in r.stdout and "waveforms" in r.stdout
