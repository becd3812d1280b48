"""Every algorithm of the provider through the real ``qgis_process`` with the README's runtime.

The environment is exactly what the README documents for the QGIS application: Debian's
QGIS 3.40, the runtime ``scripts/install_qgis.sh`` builds (``/opt/canopyblocks-qgis-python``),
``PYTHONPATH=<runtime>:<checkout>/core`` and the plugin from the built zip in a fresh
profile -- not the test virtualenv.  Each output is checked against values computed here
independently (h5py, laspy, the command line's rasters), on the bundled data and on
simulations made by the algorithms themselves.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyogrio
import pytest
import rasterio

pytestmark = [pytest.mark.qgis, pytest.mark.pdal]

ROOT = Path(__file__).resolve().parents[2]
TILE = ROOT / "tests" / "data" / "als" / "lasR_bcts_1.laz"
ALGORITHMS = ("aspecterrors", "blockheights", "calibrate", "coregister", "corridor",
              "flashdualfootprints", "footprintvalidation", "gedifootprints",
              "referencerasters", "simulate",
              "simulatewaveforms", "validate", "waveformplot")


@pytest.fixture(scope="module")
def qp(qgis_profile: Path, qgis_process_env: Any, pdal_bin: str):
    """``qp(alg, **params) -> results``: one ``qgis_process --json run``; fails with its
    output when the algorithm fails."""
    env = qgis_process_env(qgis_profile)
    env["CANOPYBLOCKS_PDAL"] = pdal_bin

    def run(alg: str, **params: object) -> dict[str, Any]:
        args = ["qgis_process", "--json", "run", f"canopyblocks:{alg}", "--"]
        args += [f"{k}={v}" for k, v in params.items()]
        r = subprocess.run(args, env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, f"{alg} failed in qgis_process:\n{r.stdout}\n{r.stderr}"
        assert "Traceback" not in r.stderr, r.stderr
        return dict(json.loads(r.stdout)["results"])
    return run


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("qgis_process_all")


def test_every_algorithm_is_listed_with_tags_and_help(qgis_profile, qgis_process_env) -> None:
    env = qgis_process_env(qgis_profile)
    r = subprocess.run(["qgis_process", "--json", "list"], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    algs = json.loads(r.stdout)["providers"]["canopyblocks"]["algorithms"]
    assert {f"canopyblocks:{a}" for a in ALGORITHMS} <= set(algs)
    # the toolbox search finds them by the products users know; a Help button each
    tags = {t for a in ALGORITHMS for t in algs[f"canopyblocks:{a}"]["tags"]}
    assert {"ATL03", "MABEL", "GEDI", "LAZ", "LAS"} <= tags
    assert all(algs[f"canopyblocks:{a}"]["help_url"].startswith("https://")
               for a in ALGORITHMS)
    h = subprocess.run(["qgis_process", "help", "canopyblocks:blockheights"], env=env,
                       capture_output=True, text=True, timeout=120)
    assert h.returncode == 0 and "<br>" not in h.stdout and "<b>" not in h.stdout


@pytest.fixture(scope="module")
def simulated(qp, work) -> Path:
    """ICESat-2 photons simulated over a real tile by the simulate algorithm."""
    out = work / "sim.h5"
    qp("simulate", INPUT=TILE, AZIMUTH=0, SEED=1, OUTPUT=out)
    return out


def _photons(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """s and h of gt1r read with plain h5py (s = segment_dist_x + dist_ph_along)."""
    with h5py.File(path) as f:
        g = f["gt1r"]
        h = g["heights/h_ph"][()].astype(float)
        along = g["heights/dist_ph_along"][()].astype(float)
        cnt = g["geolocation/segment_ph_cnt"][()]
        x0 = g["geolocation/segment_dist_x"][()].astype(float)
    return np.repeat(x0, cnt)[: along.size] + along, h


def test_simulate_writes_photons_within_the_tile(simulated) -> None:
    import laspy

    s, h = _photons(simulated)
    las = laspy.read(TILE)
    assert s.size > 200
    assert las.z.min() - 2 <= h.min() and h.max() <= las.z.max() + 2


@pytest.fixture(scope="module")
def blocks(qp, simulated, work) -> Path:
    out = work / "blocks.gpkg"
    qp("blockheights", INPUT=simulated, TRACK="gt1r", LENGTHS="25", OUTPUT=out)
    return out


def test_blockheights_one_block_per_25_m_holding_photons(blocks, simulated) -> None:
    s, _ = _photons(simulated)
    expected = np.unique(np.floor((s - s.min()) / 25.0)).size
    df = pyogrio.read_dataframe(blocks)
    assert len(df) == expected
    assert int(df["n_photons"].sum()) == s.size


@pytest.fixture(scope="module")
def rasters(qp, work) -> dict[str, Path]:
    res = qp("referencerasters", INPUT=TILE, RESOLUTION=2, OUTPUT_DIR=work / "rasters")
    return {k: Path(res[k]) for k in ("DTM", "DSM_MAX", "DSM_P90")}


def test_referencerasters_equal_the_command_line(rasters, work, pdal_bin) -> None:
    cli = work / "cli_rasters"
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "-q", "rasters", str(TILE),
                        "-o", str(cli), "--resolution", "2", "--pdal", pdal_bin],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    for key, name in (("DTM", "dtm.tif"), ("DSM_MAX", "dsm_max.tif"), ("DSM_P90", "dsm_p90.tif")):
        with rasterio.open(rasters[key]) as a, rasterio.open(cli / name) as b:
            assert a.transform == b.transform and a.shape == b.shape
            np.testing.assert_array_equal(a.read(1), b.read(1))


def test_corridor_one_polygon_per_block(qp, blocks, work) -> None:
    out = work / "corridors.gpkg"
    qp("corridor", INPUT=blocks, WIDTH=13, OUTPUT=out)
    df = pyogrio.read_dataframe(out)
    assert len(df) == len(pyogrio.read_dataframe(blocks))
    assert float(df.geometry.area.median()) == pytest.approx(13 * 25, rel=0.05)


@pytest.fixture(scope="module")
def residuals(qp, blocks, rasters, work) -> Path:
    out = work / "residuals.gpkg"
    qp("validate", INPUT=blocks, DTM=rasters["DTM"], DSM_MAX=rasters["DSM_MAX"],
       DSM_P90=rasters["DSM_P90"], WIDTH=13, OFFSET=0, OUTPUT=out,
       STATS=work / "stats.csv")
    return out


def test_validate_residuals_are_photon_minus_reference(residuals, blocks) -> None:
    df = pyogrio.read_dataframe(residuals)
    assert len(df) == len(pyogrio.read_dataframe(blocks))
    used = df[df["use"].astype(bool)]
    assert len(used) >= 5
    np.testing.assert_allclose(used["res_ground"], used["ground"] - used["ref_ground"],
                               atol=1e-6)
    # photons simulated from the same tile: the ground is that tile's ground
    assert abs(float(np.median(used["res_ground"]))) < 2.0


def test_aspecterrors_groups_the_residuals(qp, residuals, work) -> None:
    out = work / "aspect.gpkg"
    qp("aspecterrors", INPUT=residuals, OUTPUT=out)
    df = pyogrio.read_dataframe(out)
    assert len(df) >= 1


def test_calibrate_one_row_per_length(qp, simulated, rasters, work) -> None:
    out = work / "cal.csv"
    qp("calibrate", INPUT=simulated, TRACK="gt1r", LENGTHS="25", DTM=rasters["DTM"],
       DSM_MAX=rasters["DSM_MAX"], DSM_P90=rasters["DSM_P90"], WIDTH=13, OFFSET=0,
       OUTPUT=out)
    df = pyogrio.read_dataframe(out)
    assert list(df["length"].astype(float)) == [25.0]


def test_coregister_finds_no_offset_or_says_it_cannot(qp, blocks, rasters, work) -> None:
    out = work / "offsets.json"
    qp("coregister", INPUT=blocks, DTM=rasters["DTM"], OFFSET=0, RANGE=8, OUTPUT=out)
    joint = json.loads(out.read_text())["all"]
    assert joint["rmse_after"] <= joint["rmse_before"] + 1e-9
    if joint["determined"]:  # the simulator geolocates photons exactly
        assert abs(joint["east"]) < 3 and abs(joint["north"]) < 3
    else:  # a short track over one tile: too few ground blocks, and the file says why
        assert joint["reason"]


@pytest.fixture(scope="module")
def l1b_shots(gedi_l1b) -> list[int]:
    with h5py.File(gedi_l1b) as f:
        return [int(v) for b in f if b.startswith("BEAM") for v in f[b]["shot_number"][()]]


def test_gedifootprints_one_footprint_per_shot(qp, gedi_l1b, l1b_shots, work) -> None:
    out = work / "footprints.gpkg"
    qp("gedifootprints", INPUT=gedi_l1b, OUTPUT=out)
    df = pyogrio.read_dataframe(out)
    assert len(df) == len(l1b_shots)
    assert set(df["shot_number"].astype("int64")) == set(l1b_shots)


def test_waveformplot_names_the_shot(qp, gedi_l1b, l1b_shots, work) -> None:
    out = work / "waveforms.html"
    qp("waveformplot", INPUT=gedi_l1b, SHOTS=str(l1b_shots[0]), OUTPUT=out)
    assert str(l1b_shots[0]) in out.read_text()


def test_footprintvalidation_on_simulated_gedi_over_the_tile(qp, work) -> None:
    sim = work / "gedi_sim.h5"
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "-q", "simulate", str(TILE),
                        "--sensor", "gedi", "--azimuth", "0", "--seed", "2", "-o", str(sim)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    fp = work / "gedi_sim_footprints.gpkg"
    qp("gedifootprints", INPUT=sim, OUTPUT=fp)
    out = work / "fp_residuals.gpkg"
    qp("footprintvalidation", INPUT=fp, POINTS=TILE, OFFSET=0, OUTPUT=out,
       STATS=work / "fp_stats.csv")
    df = pyogrio.read_dataframe(out)
    assert len(df) == len(pyogrio.read_dataframe(fp))
    used = df[df["use"].astype(bool)]
    assert len(used) >= 3
    # waveforms simulated from these points: ground within a metre of the points' ground
    assert abs(float(np.median(used["res_ground"]))) < 1.0


def test_an_activated_virtualenv_is_refused_with_what_to_do(qgis_profile, qgis_process_env,
                                                            work) -> None:
    """Issue 12 item 9: QGIS started from a shell with the project's venv active took the
    venv's PyPI wheels and crashed ("Not a datatype", double free); now one clear refusal."""
    env = qgis_process_env(qgis_profile)
    venv = Path(sys.prefix)
    if venv == Path(sys.base_prefix):
        pytest.skip("the tests do not run in a virtualenv")
    env["VIRTUAL_ENV"] = str(venv)
    env["PATH"] = f"{venv / 'bin'}:{env['PATH']}"
    out = work / "venv_sim.h5"
    r = subprocess.run(["qgis_process", "run", "canopyblocks:simulate", "--", f"INPUT={TILE}",
                        f"OUTPUT={out}"], env=env, capture_output=True, text=True,
                       timeout=300)
    text = r.stdout + r.stderr
    assert r.returncode != 0
    assert "deactivate" in text and str(venv) in text
    assert "double free" not in text and "Not a datatype" not in text
    assert "Traceback" not in text  # nor QGIS's own Processing failing to load
    assert not out.exists()


def test_blockheights_output_crs_equals_the_pyproj_transform(qp, simulated, blocks,
                                                             work) -> None:
    """Issue 12 item 10: the block layer in a chosen metric CRS (the CLI's --crs)."""
    import pyproj

    out = work / "blocks_3005.gpkg"
    qp("blockheights", INPUT=simulated, TRACK="gt1r", LENGTHS="25", CRS="EPSG:3005",
       OUTPUT=out)
    got = pyogrio.read_dataframe(out)
    ref = pyogrio.read_dataframe(blocks)
    assert got.crs.to_epsg() == 3005
    t = pyproj.Transformer.from_crs(4326, 3005, always_xy=True)
    x, y = t.transform(ref["lon"].to_numpy(), ref["lat"].to_numpy())
    np.testing.assert_allclose(got.geometry.x, x, atol=0.01)
    np.testing.assert_allclose(got.geometry.y, y, atol=0.01)


def test_validate_photon_vertical_crs_applies_the_datum_rule(qgis_profile, qgis_process_env,
                                                             blocks, rasters, work,
                                                             pdal_bin) -> None:
    """Issue 12 item 10: declaring the photons ellipsoidal (EPSG:4979) against the tile's
    CGVD28 heights is refused unless a geoid or offset is given -- in QGIS's words."""
    env = qgis_process_env(qgis_profile)
    args = ["qgis_process", "run", "canopyblocks:validate", "--", f"INPUT={blocks}",
            f"DTM={rasters['DTM']}", f"DSM_MAX={rasters['DSM_MAX']}",
            f"DSM_P90={rasters['DSM_P90']}", "WIDTH=13", "PHOTON_VCRS=EPSG:4979",
            f"OUTPUT={work / 'res_vcrs.gpkg'}", f"STATS={work / 'st_vcrs.csv'}"]
    r = subprocess.run(args, env=env, capture_output=True, text=True, timeout=300)
    text = r.stdout + r.stderr
    assert r.returncode != 0 and "Geoid undulation raster" in text and "--geoid" not in text
    r = subprocess.run([*args[:-2], "OFFSET=0", f"OUTPUT={work / 'res_vcrs.gpkg'}",
                        f"STATS={work / 'st_vcrs.csv'}"], env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr


def _preset_index(name: str) -> int:
    """The QGIS enum index of a preset (the options follow the CLI's --preset order)."""
    from qgis_plugin.algorithms.blockheights import preset_options

    return [n for _, n in preset_options()[0]].index(name)


def test_blockheights_preset_and_calibration_equal_the_command_line(qp, simulated, rasters,
                                                                    work) -> None:
    """Issue 12 item 11 / issue 11: the icesat2 preset and a bias calibration in QGIS give
    the command line's blocks (the calibration fitted by the command line)."""
    cal = work / "cal.json"
    cli = [sys.executable, "-m", "canopyblocks", "-q"]
    r = subprocess.run([*cli, "calibrate", str(simulated), "--method", "bias", "--preset",
                        "icesat2", "--dtm", str(rasters["DTM"]), "--dsm-max",
                        str(rasters["DSM_MAX"]), "--dsm-p90", str(rasters["DSM_P90"]),
                        "--offset", "0", "--width", "13", "--length", "25", "-o", str(cal)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    ref = work / "cli_blocks_cal.gpkg"
    r = subprocess.run([*cli, "blocks", str(simulated), "--preset", "icesat2", "--calibration",
                        str(cal), "--length", "25", "-o", str(ref)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = work / "qgis_blocks_cal.gpkg"
    qp("blockheights", INPUT=simulated, TRACK="gt1r", LENGTHS="25", PRESET=_preset_index("icesat2"),
       CALIBRATION=cal, OUTPUT=out)
    got = pyogrio.read_dataframe(out).sort_values("block")
    want = pyogrio.read_dataframe(ref, layer="blocks").sort_values("block")
    assert list(got["block"]) == list(want["block"])
    np.testing.assert_allclose(got["hmax"], want["hmax"], atol=1e-6, equal_nan=True)
    assert set(got["estimators"]) == set(want["estimators"]) and "calibration" in got


@pytest.mark.parametrize("sensor,index", [("gedi", 0), ("esfl", 1), ("dual", 2)])
def test_simulatewaveforms_writes_each_sensor_with_truth(qp, work, sensor, index) -> None:
    """Issue 9: QGIS algorithms for the three sensors; the file holds waveforms and truth
    along a track inside the tile (checked with h5py and laspy)."""
    import laspy

    out = work / f"wave_{sensor}.h5"
    qp("simulatewaveforms", INPUT=TILE, SENSOR=index, AZIMUTH=0, SEED=4, OUTPUT=out)
    las = laspy.read(TILE)
    with h5py.File(out) as f:
        if sensor == "gedi":
            beams = [b for b in f if b.startswith("BEAM")]
            assert beams and all("rxwaveform" in f[b] for b in beams)
            truth = np.concatenate([f[b]["canopyblocks_truth"]["truth_ground"][()] for b in beams])
        else:
            assert f.attrs["sensor"] == sensor
            truth = f["truth/ground"][()]
    ground = las.z[las.classification == 2]
    assert truth.size >= 3
    ok = np.isfinite(truth)
    assert ground.min() - 1 <= truth[ok].min() and truth[ok].max() <= ground.max() + 1



@pytest.mark.parametrize("sensor,index", [("esfl", 1), ("dual", 2)])
def test_flashdualfootprints_on_simulated_files(qp, work, sensor, index) -> None:
    """Issue 31: flash-lidar cubes and dual-wavelength pairs written by the simulate
    algorithm, processed by the footprints algorithm in the real app: one row per
    footprint (ESFL with a 0 m cell), ground within 1.5 m of the file's truth."""
    h5 = work / f"fd_{sensor}.h5"
    qp("simulatewaveforms", INPUT=TILE, SENSOR=index, AZIMUTH=0, SEED=4, OUTPUT=h5)
    out = work / f"fd_{sensor}.gpkg"
    qp("flashdualfootprints", INPUT=h5, CELL=0, OUTPUT=out)
    fp = pyogrio.read_dataframe(out)
    with h5py.File(h5) as f:
        truth = f["truth/ground"][()]
    assert len(fp) == truth.size
    ok = (fp["flag"] == "ok").to_numpy()
    assert ok.sum() >= 3
    err = fp["ground"].to_numpy(float)[ok] - truth[fp["shot_number"].to_numpy()[ok]]
    assert np.abs(err).max() < 1.5


def test_validate_footprint_reference_equals_the_command_line(qp, blocks, work) -> None:
    """Issue 11 item 3 / issue 12 item 11: the footprint-matched reference in QGIS's
    validate gives the command line's residuals (validate --reference footprint)."""
    ref = work / "cli_fp.gpkg"
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "-q", "validate", str(blocks),
                        "--reference", "footprint", "--points", str(TILE), "--diameter", "13",
                        "--offset", "0", "-o", str(ref)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    out = work / "qgis_fp.gpkg"
    qp("validate", INPUT=blocks, REFERENCE=1, POINTS=TILE, DIAMETER=13, OFFSET=0, OUTPUT=out,
       STATS=work / "qgis_fp_stats.csv")
    got = pyogrio.read_dataframe(out).sort_values("block")
    want = pyogrio.read_dataframe(ref, layer="residuals").sort_values("block")
    assert list(got["block"]) == list(want["block"])
    for col in ("ref_ground", "res_ground", "res_hmax"):
        np.testing.assert_allclose(got[col], want[col], atol=1e-6, equal_nan=True)


def test_calibrate_bias_method_writes_the_command_lines_calibration(qp, simulated, rasters,
                                                                     work) -> None:
    """Issue 12 item 11: the bias calibration in QGIS equals calibrate --method bias."""
    cli = work / "cli_bias.json"
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "-q", "calibrate",
                        str(simulated), "--method", "bias", "--preset", "icesat2", "--dtm",
                        str(rasters["DTM"]), "--dsm-max", str(rasters["DSM_MAX"]),
                        "--dsm-p90", str(rasters["DSM_P90"]), "--offset", "0", "--width",
                        "13", "--length", "25", "-o", str(cli)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = work / "qgis_bias.json"
    qp("calibrate", INPUT=simulated, TRACK="gt1r", LENGTHS="25", DTM=rasters["DTM"],
       DSM_MAX=rasters["DSM_MAX"], DSM_P90=rasters["DSM_P90"], WIDTH=13, OFFSET=0, METHOD=1,
       PRESET=_preset_index("icesat2"), OUTPUT=work / "qgis_bias.csv", CALIBRATION=out)
    got, want = json.loads(out.read_text()), json.loads(cli.read_text())
    assert got["estimators"] == want["estimators"]
    assert len(got["models"]) == len(want["models"])
    for g, w in zip(got["models"], want["models"]):
        assert {k: v for k, v in g.items() if isinstance(v, str)} == \
            {k: v for k, v in w.items() if isinstance(v, str)}
        for k, v in w.items():
            if not isinstance(v, str):
                assert g[k] == pytest.approx(v, rel=1e-9, abs=1e-9), k
