"""Estimator presets and bias calibrations through the command line (issue 11 wiring).

Photons are simulated over the real bcts tile (seed 002 simulator, two realisations
written as two beams); the corridor reference rasters are made here with plain numpy
(class-2 mean, maximum and 90th percentile per 2 m cell), independent of PDAL and of the
code under test.  The checks are arithmetic a user can redo: a calibrated Hmax equals the
uncalibrated one plus the file's intercept; a file fitted for other estimators is refused.
"""

from __future__ import annotations

import json
import subprocess
import sys

import geopandas as gpd
import numpy as np
import pytest

from canopyblocks.readers.las import read_las
from canopyblocks.simulate import SimParams, line_through, simulate_photons
from canopyblocks.simulate.writers import write_simulation_atl03

pytestmark = pytest.mark.filterwarnings("ignore::canopyblocks.errors.SparseBlockWarning")

RES = 2.0


def _cells(x, y, bounds):
    x0, y1 = np.floor(bounds[0]), np.ceil(bounds[3])
    nx = int(np.ceil((bounds[2] - x0) / RES))
    ny = int(np.ceil((y1 - bounds[1]) / RES))
    c = np.clip(((x - x0) // RES).astype(int), 0, nx - 1)
    r = np.clip(((y1 - y) // RES).astype(int), 0, ny - 1)
    return r * nx + c, nx, ny, x0, y1


def _write(values, x0, y1, crs, path):
    import rasterio
    from rasterio.transform import Affine

    with rasterio.open(path, "w", driver="GTiff", width=values.shape[1],
                       height=values.shape[0], count=1, dtype="float32", crs=crs,
                       nodata=-9999, transform=Affine(RES, 0.0, x0, 0.0, -RES, y1)) as dst:
        dst.write(np.where(np.isfinite(values), values, -9999).astype("float32"), 1)


@pytest.fixture(scope="module")
def site(sample, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("estimator_cli")
    pts = read_las([sample("als/lasR_bcts_1.laz")])
    bounds = (pts.x.min(), pts.y.min(), pts.x.max(), pts.y.max())
    k, nx, ny, x0, y1 = _cells(pts.x, pts.y, bounds)
    g = pts.classification == 2
    s = np.bincount(k[g], pts.z[g], minlength=nx * ny)
    n = np.bincount(k[g], minlength=nx * ny)
    dtm = np.where(n > 0, s / np.maximum(n, 1), np.nan).reshape(ny, nx)
    dsm = np.full(nx * ny, -np.inf)
    np.maximum.at(dsm, k, pts.z)
    dsm[~np.isfinite(dsm)] = np.nan
    order = np.lexsort((pts.z, k))          # 90th percentile per cell, brute force by sort
    ks, zs = k[order], pts.z[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    counts = np.diff(np.r_[starts, ks.size])
    p90 = np.full(nx * ny, np.nan)
    p90[ks[starts]] = zs[starts + np.floor(0.9 * (counts - 1)).astype(int)]
    paths = {}
    for name, v in (("dtm", dtm), ("dsm_max", dsm.reshape(ny, nx)),
                    ("dsm_p90", p90.reshape(ny, nx))):
        paths[name] = tmp / f"{name}.tif"
        _write(v, x0, y1, pts.crs, paths[name])
    sim = simulate_photons(pts, line_through(bounds, 10.0, inset=5), SimParams(),
                           realisations=2, seed=3)
    h5 = tmp / "sim.h5"
    write_simulation_atl03(sim, h5, realisations=(0, 1), beams=("gt1l", "gt1r"))
    return {"h5": h5, "tmp": tmp, **paths}


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "canopyblocks", *map(str, args)],
                          capture_output=True, text=True, timeout=600)


def test_bias_calibration_from_the_command_line(site):
    tmp = site["tmp"]
    refs = ["--dtm", site["dtm"], "--dsm-max", site["dsm_max"], "--dsm-p90", site["dsm_p90"]]
    cal = tmp / "cal.json"
    r = _cli("calibrate", site["h5"], "--method", "bias", "--preset", "icesat2",
             "--length", "25", *refs, "--offset", "0", "--photon-vcrs", "EPSG:3005",
             "--width", "13", "-o", cal)
    assert r.returncode == 0, r.stderr
    doc = json.loads(cal.read_text())
    assert doc["estimators"] == "noise=density,ground=paper,top=p98"
    assert doc["preset"] == "icesat2" and doc["corridor_width"] == 13.0
    assert cal.with_suffix(".csv").exists()
    hmax = [m for m in doc["models"] if m["metric"] == "hmax"]
    assert hmax and all(m["length"] == 25.0 for m in hmax)
    raw, fixed = tmp / "raw.gpkg", tmp / "fixed.gpkg"
    assert _cli("blocks", site["h5"], "--preset", "icesat2", "--length", "25",
                "-o", raw).returncode == 0
    r = _cli("blocks", site["h5"], "--preset", "icesat2", "--length", "25",
             "--calibration", cal, "-o", fixed)
    assert r.returncode == 0, r.stderr
    a, b = gpd.read_file(raw), gpd.read_file(fixed)
    assert (a["estimators"] == doc["estimators"]).all()
    m = hmax[0]
    ok = np.isfinite(a["hmax"].to_numpy(float))
    np.testing.assert_allclose(b["hmax"].to_numpy(float)[ok],
                               m["slope"] * a["hmax"].to_numpy(float)[ok] + m["intercept"],
                               atol=1e-6)
    np.testing.assert_allclose(b["top"].to_numpy(float)[ok],
                               b["ground"].to_numpy(float)[ok] + b["hmax"].to_numpy(float)[ok],
                               atol=1e-6)
    # refused on blocks made with other estimators, one line, exit 2, nothing written
    bad = tmp / "bad.gpkg"
    r = _cli("blocks", site["h5"], "--length", "25", "--calibration", cal, "-o", bad)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "fitted on blocks made with" in r.stderr and not bad.exists()


def test_bias_calibration_of_the_default_estimators(site):
    """``calibrate --preset atl08 --method bias`` end to end: the calibration is for the
    recommended estimators, and ``blocks`` without --preset (the same default) applies it:
    every calibrated Hmax is the raw one moved by the fitted line."""
    tmp = site["tmp"]
    refs = ["--dtm", site["dtm"], "--dsm-max", site["dsm_max"], "--dsm-p90", site["dsm_p90"]]
    cal = tmp / "cal_atl08.json"
    r = _cli("calibrate", site["h5"], "--method", "bias", "--preset", "atl08",
             "--length", "25", *refs, "--offset", "0", "--photon-vcrs", "EPSG:3005",
             "-o", cal)
    assert r.returncode == 0, r.stderr
    doc = json.loads(cal.read_text())
    assert doc["preset"] == "atl08"
    assert doc["estimators"] == "noise=atl08,ground=atl08,top=atl08"
    assert doc["corridor_width"] == 13.0   # the ICESat-2 footprint: the default width
    raw, fixed = tmp / "raw_atl08.gpkg", tmp / "fixed_atl08.gpkg"
    assert _cli("blocks", site["h5"], "--length", "25", "-o", raw).returncode == 0
    r = _cli("blocks", site["h5"], "--length", "25", "--calibration", cal, "-o", fixed)
    assert r.returncode == 0, r.stderr
    a, b = gpd.read_file(raw), gpd.read_file(fixed)
    assert (a["estimators"] == doc["estimators"]).all()
    m = [m for m in doc["models"] if m["metric"] == "hmax"][0]
    ok = np.isfinite(a["hmax"].to_numpy(float))
    assert ok.sum() >= 5
    np.testing.assert_allclose(b["hmax"].to_numpy(float)[ok],
                               m["slope"] * a["hmax"].to_numpy(float)[ok] + m["intercept"],
                               atol=1e-6)


def test_footprint_reference_in_validate(site, sample):
    """``validate --reference footprint --points``: the blocks' ground against the
    Gaussian-weighted ALS ground is close (simulated photons keep the tile's heights)."""
    tmp = site["tmp"]
    blocks = tmp / "paper.gpkg"
    assert _cli("blocks", site["h5"], "--preset", "paper", "--length", "25",
                "-o", blocks).returncode == 0
    out = tmp / "val_fp.gpkg"
    r = _cli("validate", blocks, "--reference", "footprint", "--points",
             sample("als/lasR_bcts_1.laz"), "--offset", "0", "-o", out)
    assert r.returncode == 0, r.stderr
    stats = gpd.read_file(out, layer="stats")
    g = stats[(stats["metric"] == "ground") & (stats["group"] == "all")].iloc[0]
    # the paper's ground sits about 1.5 m above the lowest photons (DESIGN 1.10)
    assert 0.3 < g["bias"] < 3.0 and g["n"] >= 10
    # and without tiles: a clear error
    r = _cli("validate", blocks, "--reference", "footprint", "-o", tmp / "x.gpkg")
    assert r.returncode == 2 and "--points" in r.stderr
