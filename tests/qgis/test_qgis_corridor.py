"""canopyblocks:corridor in-process and through the qgis_process command line."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

pytestmark = [pytest.mark.qgis]

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def blocks_gpkg(run_alg, atl03_sample, tmp_path) -> Path:
    out = tmp_path / "blocks.gpkg"
    run_alg("canopyblocks:blockheights", {"INPUT": str(atl03_sample), "TRACK": "gt1r",
                                          "LENGTHS": "25", "OUTPUT": str(out)})
    return out


def _direct_corridors(blocks_path: Path, width: float):
    from canopyblocks import read_blocks
    from canopyblocks.reference.corridor import block_corridors

    blocks = read_blocks(blocks_path)
    return blocks, block_corridors(blocks, width=width)


def test_corridor_polygons(run_alg, open_layer, layer_rows, blocks_gpkg, tmp_path):
    out = tmp_path / "corridor.gpkg"
    run_alg("canopyblocks:corridor", {"INPUT": str(blocks_gpkg), "WIDTH": 13.0,
                                      "OUTPUT": str(out)})
    layer = open_layer(out)
    assert layer.crs().authid() == "EPSG:32613"
    rows = layer_rows(layer)
    blocks, direct = _direct_corridors(blocks_gpkg, 13.0)
    assert len(rows) == len(blocks) == len(direct)
    assert {r["block"] for r in rows} == set(blocks["block"].astype(int))
    # a nearly straight 820 m ICESat-2 track: each polygon is ~13 m x 25 m
    areas = sorted(r["_area"] for r in rows)
    assert areas[len(areas) // 2] == pytest.approx(13.0 * 25.0, rel=0.02)
    by_block = {int(r["block"]): r["_area"] for r in rows}
    for b, geom in zip(direct["block"].astype(int), direct.geometry):
        assert by_block[b] == pytest.approx(geom.area, rel=1e-9)


def test_built_zip_in_clean_profile_lists_algorithms(qgis_profile, qgis_process_env):
    r = subprocess.run(["qgis_process", "--json", "list"], env=qgis_process_env(qgis_profile),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    listing = json.loads(r.stdout)
    prov = listing["providers"]["canopyblocks"]
    ids = set(prov["algorithms"])
    for alg in ("blockheights", "corridor", "referencerasters", "validate", "aspecterrors",
                "calibrate", "simulate"):
        assert f"canopyblocks:{alg}" in ids


def test_qgis_process_runs_corridor(qgis_profile, qgis_process_env, blocks_gpkg, open_layer,
                                   tmp_path):
    out = tmp_path / "corridor_cli.gpkg"
    r = subprocess.run(
        ["qgis_process", "--json", "run", "canopyblocks:corridor", "--",
         f"INPUT={blocks_gpkg}", "WIDTH=2", f"OUTPUT={out}"],
        env=qgis_process_env(qgis_profile), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    result = json.loads(r.stdout)
    assert result["results"]["OUTPUT"].startswith(str(out))
    layer = open_layer(out)
    blocks, direct = _direct_corridors(blocks_gpkg, 2.0)
    assert layer.featureCount() == len(direct)
    total = sum(f.geometry().area() for f in layer.getFeatures())
    assert total == pytest.approx(float(direct.geometry.area.sum()), rel=1e-9)


def test_qgis_process_runs_blockheights_on_real_atl03(qgis_profile, qgis_process_env,
                                                     atl03_sample, blocks_gpkg, open_layer,
                                                     layer_rows, tmp_path):
    """Inside qgis_process (QGIS's own GEOS/HDF5 loaded globally) the ATL03 reader works and
    gives the in-process numbers."""
    out = tmp_path / "blocks_cli.gpkg"
    r = subprocess.run(
        ["qgis_process", "--json", "run", "canopyblocks:blockheights", "--",
         f"INPUT={atl03_sample}", "TRACK=gt1r", "LENGTHS=25", f"OUTPUT={out}"],
        env=qgis_process_env(qgis_profile), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    cli = {int(x["block"]): x for x in layer_rows(open_layer(out))}
    inproc = {int(x["block"]): x for x in layer_rows(open_layer(blocks_gpkg))}
    assert cli.keys() == inproc.keys() and len(cli) == 33  # 820 m of track / 25 m
    for b, x in inproc.items():
        assert cli[b]["flag"] == x["flag"] and cli[b]["n_photons"] == x["n_photons"]
        if x["hmax"] is not None:
            assert cli[b]["hmax"] == pytest.approx(x["hmax"], abs=1e-9)


def test_qgis_process_without_core_says_how_to_install(qgis_profile, qgis_process_env,
                                                        blocks_gpkg, tmp_path):
    env = qgis_process_env(qgis_profile, core_on_path=False)
    r = subprocess.run(
        ["qgis_process", "run", "canopyblocks:corridor", "--",
         f"INPUT={blocks_gpkg}", f"OUTPUT={tmp_path / 'x.gpkg'}"],
        env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode != 0
    text = r.stdout + r.stderr
    assert "install canopyblocks into QGIS's Python" in text
    assert not (tmp_path / "x.gpkg").exists()


def test_qgis_process_with_pypi_wheels_explains_the_library_clash(qgis_profile, qgis_process_env,
                                                                  atl03_sample, tmp_path):
    """The venv's h5py and pyproj wheels bundle their own HDF5/PROJ; inside qgis_process
    QGIS's copies win and the process aborts (double free; on a loaded machine it hung until
    killed): the plugin refuses before importing them, says why and what to install instead,
    and the process exits normally with an error."""
    import sysconfig

    site = Path(sysconfig.get_paths()["purelib"])
    if not (site / "h5py.libs").is_dir():
        pytest.skip("this venv's h5py is not a PyPI wheel with its own HDF5")
    env = qgis_process_env(qgis_profile, runtime=site)
    out = tmp_path / "never.gpkg"
    r = subprocess.run(
        ["qgis_process", "run", "canopyblocks:blockheights", "--",
         f"INPUT={atl03_sample}", "TRACK=gt1r", f"OUTPUT={out}"],
        env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr[-500:]
    text = r.stdout + r.stderr
    assert "would clash with QGIS's own" in text and "h5py" in text
    assert "double free" not in text
    assert "reading " not in r.stdout  # refused before any input was opened
    assert not out.exists()
