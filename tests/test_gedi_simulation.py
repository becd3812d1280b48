"""GEDI waveform simulation from airborne lidar (DESIGN 4.9, issue 9).

Synthetic LAS scenes with known truth (flat ground, a 10 degree slope, a two-layer
canopy at 50 % cover) are simulated, written in the GEDI L1B layout, read back with the
L1B reader and processed with the L2A-style processing: ground within 0.05 m (RMSE) of
the plane the points were placed on, RH98 within 0.3 m of the noise-free truth and near
the top layer that was placed. Same seed -> identical bytes. The command line writes
each sensor's file; the simulated footprints validate against the tiles they came from.
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from canopyblocks.outputs.h5_gedi_l1b import write_gedi_l1b
from canopyblocks.readers.gedi import read_gedi_l1b
from canopyblocks.readers.las import read_las
from canopyblocks.simulate.gedi_waveforms import GediSimParams, simulate_gedi
from canopyblocks.simulate.tracks import SimTrack
from canopyblocks.waveforms.process import process_waveforms

X0, Y0 = 500_000.0, 4_000_000.0
SLOPE = np.tan(np.radians(10.0))
LAYERS = (12.0, 25.0)


def _scene(kind: str, path: Path, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, 200.0, 0.5)
    xx, yy = np.meshgrid(g, g)
    xx = xx.ravel() + rng.uniform(0, 0.5, xx.size)
    yy = yy.ravel() + rng.uniform(0, 0.5, yy.size)
    zg = 100.0 + (SLOPE * xx if kind == "slope" else np.zeros_like(xx))
    x, y, z, c = [xx], [yy], [zg], [np.full(xx.size, 2)]
    if kind == "canopy":   # 4 m checkerboard: half the area under two layers, no ground
        cov = ((np.floor(xx / 4) + np.floor(yy / 4)) % 2) == 0
        x, y, z, c = [xx[~cov]], [yy[~cov]], [zg[~cov]], [np.full((~cov).sum(), 2)]
        for h in LAYERS:
            x.append(xx[cov])
            y.append(yy[cov])
            z.append(zg[cov] + h + rng.normal(0, 0.3, cov.sum()))
            c.append(np.full(cov.sum(), 5))
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = [0.01, 0.01, 0.01]
    hdr.offsets = [X0, Y0, 0.0]
    hdr.add_crs(pyproj.CRS("EPSG:32612"))
    las = laspy.LasData(hdr)
    las.x = np.concatenate(x) + X0
    las.y = np.concatenate(y) + Y0
    las.z = np.concatenate(z)
    las.classification = np.concatenate(c).astype(np.uint8)
    las.write(path)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("gedi_scenes")
    out = {}
    for kind in ("flat", "slope", "canopy"):
        out[kind] = tmp / f"{kind}.las"
        _scene(kind, out[kind])
    return out


TRACK = SimTrack.line(X0 + 30, Y0 + 30, X0 + 170, Y0 + 170)


@pytest.mark.parametrize("kind", ["flat", "slope", "canopy"])
def test_round_trip_recovers_truth(scenes: dict[str, Path], kind: str,
                                   tmp_path: Path) -> None:
    pts = read_las([scenes[kind]])
    sim = simulate_gedi(pts, TRACK, params=GediSimParams(spacing=10.0), seed=3)
    path = write_gedi_l1b(tmp_path / "l1b.h5", [sim.batch], truth={"BEAM0101": sim.truth})
    res = process_waveforms(read_gedi_l1b(path, "BEAM0101"))
    ok = (res["flag"] == "ok").to_numpy()
    assert ok.sum() >= 18
    xs = sim.truth["x"].to_numpy()
    plane = 100.0 + (SLOPE * (xs - X0) if kind == "slope" else np.zeros_like(xs))
    # the simulator's truth is the plane (independent check of the weighting)
    np.testing.assert_allclose(sim.truth["truth_ground"], plane, atol=0.01)
    e = res["ground"].to_numpy()[ok] - plane[ok]
    assert np.sqrt(np.mean(e ** 2)) <= 0.05, e
    d = res["rh98"].to_numpy()[ok] - sim.truth["truth_rh98"].to_numpy()[ok]
    assert np.sqrt(np.mean(d ** 2)) <= 0.3, d
    rh98 = res["rh98"].to_numpy()[ok]
    if kind == "canopy":
        # the top layer placed at 25 m: RH98 within a pulse width of it
        assert np.all(np.abs(rh98 - LAYERS[1]) <= 2.0), rh98
        c = res["cover"].to_numpy()[ok]
        assert np.all(np.abs(sim.truth["truth_cover"].to_numpy()[ok] - 0.5) <= 0.1)
        assert np.abs(np.median(c) - 0.5) <= 0.15, c
    else:
        assert np.all(rh98 < 4.0)   # bare ground: RH98 is the pulse's half width


def test_same_seed_same_bytes(scenes: dict[str, Path], tmp_path: Path) -> None:
    pts = read_las([scenes["canopy"]])
    digests = []
    for name in ("a.h5", "b.h5"):
        sim = simulate_gedi(pts, TRACK, seed=7)
        write_gedi_l1b(tmp_path / name, [sim.batch], truth={"BEAM0101": sim.truth})
        digests.append(hashlib.sha256((tmp_path / name).read_bytes()).hexdigest())
    assert digests[0] == digests[1]
    other = simulate_gedi(pts, TRACK, seed=8)
    assert not np.array_equal(other.batch.waveforms, sim.batch.waveforms)


def _cli(*args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "canopyblocks", *map(str, args)],
                          capture_output=True, text=True, timeout=600)


def test_simulate_cli_each_sensor(sample, tmp_path: Path) -> None:
    tiles = [sample("als/lasR_bcts_1.laz"), sample("als/lasR_bcts_2.laz")]
    for sensor in ("gedi", "esfl", "dual"):
        out = tmp_path / f"{sensor}.h5"
        r = _cli("simulate", *tiles, "--sensor", sensor, "--azimuth", "10", "--seed", "1",
                 "-o", out, "--report", tmp_path / f"rep_{sensor}")
        assert r.returncode == 0, r.stderr
        assert out.exists() and f"{sensor} footprints" in r.stderr
    assert (tmp_path / "rep_gedi" / "gedi_round_trip.csv").exists()
    # the GEDI file goes through the real reader, the waveforms command and validation
    fp = tmp_path / "fp.gpkg"
    r = _cli("waveforms", tmp_path / "gedi.h5", "-o", fp)
    assert r.returncode == 0, r.stderr
    val = tmp_path / "val.gpkg"
    r = _cli("validate", fp, "--points", tiles[0], "--points", tiles[1], "--offset", "0",
             "-o", val)
    assert r.returncode == 0, r.stderr
    import geopandas as gpd

    stats = gpd.read_file(val, layer="stats_footprints")
    g = stats[(stats["metric"] == "ground") & (stats["group"] == "all")].iloc[0]
    assert g["n"] >= 5 and abs(g["bias"]) < 1.5
    r = _cli("simulate", tiles[0], "--sensor", "gedi", "--azimuth", "10", "-o",
             tmp_path / "x.gpkg")
    assert r.returncode == 2 and "*.h5" in r.stderr


def test_run_with_gedi_waveforms(scenes: dict[str, Path], tmp_path: Path) -> None:
    """``run TILES --photons L1B.h5``: footprints validated against the tiles they were
    simulated from: ground residuals within a few cm of zero (flat truth)."""
    import pandas as pd

    from canopyblocks.simulate.sensor_files import simulate_gedi_to_file

    pts = read_las([scenes["canopy"]])
    l1b = tmp_path / "sim.h5"
    simulate_gedi_to_file(pts, TRACK, l1b, params=GediSimParams(spacing=10.0), seed=2)
    out = tmp_path / "chain"
    r = _cli("run", scenes["canopy"], "--photons", l1b, "--offset", "0", "-o", out)
    assert r.returncode == 0, r.stderr
    for name in ("footprints.gpkg", "validation.gpkg", "stats.csv", "report.html"):
        assert (out / name).exists(), name
    stats = pd.read_csv(out / "stats.csv")
    g = stats[(stats["metric"] == "ground") & (stats["group"] == "all")].iloc[0]
    assert g["n"] >= 15 and abs(g["bias"]) < 0.1 and g["rmse"] < 0.15
    # the report opens with a summary that counts footprints, cover as a fraction
    import html
    import re

    page = html.unescape((out / "report.html").read_text())
    first = page.split("<h2>")[1]
    assert first.startswith("Summary") and "GEDI footprints" in first
    assert re.search(r"ground bias [-+]\d+\.\d\d m \(95 % interval [^)]*\), RMSE", first)
    assert "<th>n (footprints)</th>" in page and "n (blocks)" not in page
    assert "<th>bias (fraction)</th>" in page
    groups = re.findall(r"<td>((?:beam|aspect|slope|cover) [^<]*)</td>\s*<td>(\d+)</td>",
                        page)
    assert groups and min(int(n) for _, n in groups) >= 3
    # run's reference is simulate's noise-free truth, the same function: equal per footprint
    import geopandas as gpd

    from canopyblocks.simulate.gedi_waveforms import simulate_gedi

    truth = simulate_gedi(pts, TRACK, params=GediSimParams(spacing=10.0), seed=2).truth
    res = gpd.read_file(out / "validation.gpkg", layer="residuals_footprints")
    truth = truth.assign(shot_number=truth["shot_number"].astype(res["shot_number"].dtype))
    both = res.merge(truth, on="shot_number")
    assert len(both) >= 15
    np.testing.assert_allclose(both["ref_ground"], both["truth_ground_lowest_mode"],
                               atol=0.002)
    np.testing.assert_allclose(both["ref_rh98"], both["truth_rh98_lowest_mode"], atol=0.011)
    np.testing.assert_allclose(both["ref_cover"], both["truth_cover_waveform"], atol=1e-3)
    assert set(both["reference"]) == {"waveform"}
    assert "formed into the waveform" in first
    # ... and what the scene was built with: flat ground at 100 m, the top layer at 25 m
    # (RH98 above it by the pulse's reach: sigma 0.99 m)
    np.testing.assert_allclose(both["ref_ground"], 100.0, atol=0.1)
    assert np.all((both["ref_rh98"] > LAYERS[1]) & (both["ref_rh98"] < LAYERS[1] + 2.5))


def test_run_sensor_gedi_scores_a_simulation_near_zero(sample, tmp_path: Path) -> None:
    """``run --sensor gedi`` over the bundled forest tiles: the footprints of a simulation
    against the reference formed as their waveforms are, RH98 and ground bias within 0.5 m
    of zero (the noise's effect only); the weighted-points reference stays one option away
    and shows the canopy-top energy a waveform loses below its noise thresholds."""
    import geopandas as gpd
    import pandas as pd

    from canopyblocks.reference.footprint_params import FootprintReferenceParams
    from canopyblocks.validation.footprints import validate_footprints

    tiles = [sample("als/lasR_bcts_1.laz"), sample("als/lasR_bcts_2.laz")]
    out = tmp_path / "chain"
    r = _cli("run", *tiles, "--sensor", "gedi", "--seed", "0", "-o", out)
    assert r.returncode == 0, r.stderr
    stats = pd.read_csv(out / "stats.csv")
    alls = stats[stats["group"] == "all"].set_index("metric")
    assert alls.loc["rh98", "n"] >= 8
    for metric in ("rh98", "ground"):
        assert abs(alls.loc[metric, "bias"]) < 0.5, alls.loc[metric]
    fp = gpd.read_file(out / "footprints.gpkg", layer="footprints")
    fp.attrs["vertical_datum"] = "unknown"
    old = validate_footprints(fp, tiles, offset=0.0,
                              params=FootprintReferenceParams.gedi(definition="points"))
    assert set(old.residuals["reference"]) == {"points"}
    new = gpd.read_file(out / "validation.gpkg", layer="residuals_footprints")
    both = old.residuals.merge(new, on="shot_number", suffixes=("_old", ""))
    # the layer keeps the points' values beside the waveform-formed ones
    np.testing.assert_allclose(both["ref_rh98_points"], both["ref_rh98_old"], atol=1e-9)
    # all returns above the class-2 plane reach higher than the energy a waveform shows
    assert (both["ref_rh98_points"] > both["ref_rh98"]).mean() > 0.8


def _shrub_scene(path: Path, shrub_height: float = 0.6, seed: int = 0) -> None:
    """Flat class-2 ground at 100 m under dense low returns (class 3) ``shrub_height``
    above it on every other 1 m cell -- the low last returns of a conifer stand."""
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, 200.0, 0.5)
    xx, yy = np.meshgrid(g, g)
    xx = xx.ravel() + rng.uniform(0, 0.5, xx.size)
    yy = yy.ravel() + rng.uniform(0, 0.5, yy.size)
    shrub = ((np.floor(xx) + np.floor(yy)) % 2) == 0
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = [0.01, 0.01, 0.01]
    hdr.offsets = [X0, Y0, 0.0]
    hdr.add_crs(pyproj.CRS("EPSG:32612"))
    las = laspy.LasData(hdr)
    las.x, las.y = xx + X0, yy + Y0
    las.z = np.where(shrub, 100.0 + shrub_height, 100.0)
    las.classification = np.where(shrub, 3, 2).astype(np.uint8)
    las.write(path)


def test_both_ground_truths_are_recorded_and_named(tmp_path: Path) -> None:
    """Low returns above the ground: the class-2 truth stays on the ground the points
    were placed on, the waveform's lowest mode lies between it and the shrubs, and the
    processed ground reproduces the lowest mode, not the class-2 mean."""
    from canopyblocks.simulate.sensor_files import gedi_round_trip

    las = tmp_path / "shrubs.las"
    _shrub_scene(las)
    sim = simulate_gedi(read_las([las]), TRACK, params=GediSimParams(spacing=10.0), seed=4)
    t = sim.truth
    np.testing.assert_allclose(t["truth_ground"], 100.0, atol=0.01)     # placed there
    mode = t["truth_ground_lowest_mode"].to_numpy()
    assert np.all((mode > 100.2) & (mode < 100.65)), mode             # merged with shrubs
    path = write_gedi_l1b(tmp_path / "l1b.h5", [sim.batch], truth={"BEAM0101": t})
    rt = gedi_round_trip(path, t).set_index(["metric", "truth"])
    assert rt.loc[("ground", "lowest mode"), "rmse"] <= 0.05
    assert rt.loc[("ground", "class-2 mean"), "bias"] >= 0.2          # the definitions differ
    for k in (50, 98):   # RH above each ground differs by the same offset
        d = t[f"truth_rh{k}"] - t[f"truth_rh{k}_lowest_mode"]
        np.testing.assert_allclose(d, mode - 100.0, atol=0.02)


def test_shot_spacing_is_honoured_for_gedi(scenes: dict[str, Path], tmp_path: Path) -> None:
    out = {}
    for spacing in (10, 20):
        h5 = tmp_path / f"s{spacing}.h5"
        r = _cli("simulate", scenes["flat"], "--sensor", "gedi", "--line",
                 f"{X0 + 30},{Y0 + 30},{X0 + 170},{Y0 + 170}", "--shot-spacing", spacing,
                 "-o", h5)
        assert r.returncode == 0, r.stderr
        import h5py

        with h5py.File(h5) as f:
            out[spacing] = f["BEAM0101/shot_number"].shape[0]
    length = float(np.hypot(140.0, 140.0))               # 197.99 m
    assert out == {10: int(length // 10) + 1, 20: int(length // 20) + 1}, out
    r = _cli("simulate", scenes["flat"], "--sensor", "esfl", "--azimuth", "0",
             "--shot-spacing", "10", "-o", tmp_path / "e.h5")
    assert r.returncode == 2 and "--shot-spacing" in r.stderr, r.stderr
    r = _cli("simulate", scenes["flat"], "--sensor", "gedi", "--azimuth", "0",
             "--shot-spacing", "0.00001", "-o", tmp_path / "t.h5")
    assert r.returncode == 2 and "spacing" in r.stderr and "Traceback" not in r.stderr
