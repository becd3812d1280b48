"""The full-waveform algorithms in headless QGIS: GEDI footprints from the real L1B
subset (checked against the official L2A of the same shots), footprint validation of
simulated waveforms against the tiles they came from, and waveform plots."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

pytestmark = [pytest.mark.qgis]


def test_gedi_footprints_reproduce_l2a(run_alg, open_layer, layer_rows, gedi_l1b, gedi_l2a,
                                       tmp_path):
    out = tmp_path / "fp.gpkg"
    res = run_alg("canopyblocks:gedifootprints", {
        "INPUT": str(gedi_l1b), "BEAMS": "BEAM0101, BEAM1011", "SETTING": 0,
        "L2A": str(gedi_l2a), "OUTPUT": str(out)})
    layer = open_layer(res["OUTPUT"])
    rows = layer_rows(layer)
    assert len(rows) == 73 + 16
    from qgis.core import QgsWkbTypes

    assert QgsWkbTypes.hasZ(layer.wkbType())
    with h5py.File(gedi_l2a) as f:
        ref = {int(s): float(g) for b in ("BEAM0101", "BEAM1011")
               for s, g in zip(f[b]["shot_number"][:], f[b]["geolocation/elev_lowestmode_a1"][:])}
    d = np.array([r["ground"] - ref[int(r["shot_number"])] for r in rows
                  if r["flag"] == "ok" and int(r["shot_number"]) in ref])
    assert d.size >= 80 and np.sqrt(np.mean(d ** 2)) < 0.05
    assert all("d_rh98" in r for r in rows)
    # the shot's UTC as a QGIS date-time, inside the orbit the granule name states
    # (O01964 started 2019-04-18 08:03:38 UTC; an orbit lasts about 92 minutes)
    from qgis.PyQt.QtCore import QDateTime, Qt

    start = QDateTime.fromString("2019-04-18T08:03:38Z", Qt.ISODate)
    for r in rows:
        t = r["time_utc"]
        assert isinstance(t, QDateTime) and t.isValid(), t
        assert 0 <= start.secsTo(t) <= 93 * 60, t.toString(Qt.ISODate)


def test_footprint_validation_and_plots(run_alg, open_layer, layer_rows, sample, gedi_l1b,
                                        tmp_path):
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import line_through
    from canopyblocks.simulate.sensor_files import simulate_gedi_to_file

    laz = [sample("als/lasR_bcts_1.laz"), sample("als/lasR_bcts_2.laz")]
    pts = read_las(laz)
    sim = tmp_path / "sim.h5"
    simulate_gedi_to_file(pts, line_through(pts.bounds, 10.0, inset=17), sim, seed=1)
    fp = run_alg("canopyblocks:gedifootprints", {"INPUT": str(sim),
                                                  "OUTPUT": str(tmp_path / "fp.gpkg")})
    val = run_alg("canopyblocks:footprintvalidation", {
        "INPUT": fp["OUTPUT"], "POINTS": [str(p) for p in laz], "DIAMETER": 22.0,
        "OFFSET": 0.0, "OUTPUT": str(tmp_path / "res.gpkg"),
        "STATS": str(tmp_path / "stats.csv")})
    res = layer_rows(open_layer(val["OUTPUT"]))
    assert len(res) >= 5 and all("res_ground" in r for r in res)
    ground = [r["res_ground"] for r in res if r.get("use")]
    assert ground and abs(float(np.mean(ground))) < 1.5
    with h5py.File(gedi_l1b) as f:
        shots = [int(s) for s in f["BEAM0101"]["shot_number"][:2]]
    html = tmp_path / "view.html"
    out = run_alg("canopyblocks:waveformplot", {
        "INPUT": str(gedi_l1b), "SHOTS": ", ".join(map(str, shots)), "SETTING": 0,
        "OUTPUT": str(html)})
    text = Path(out["OUTPUT"]).read_text()
    assert all(str(s) in text for s in shots)
    assert len(list(tmp_path.glob("view_*.png"))) == 2


def test_coregister_algorithm(run_alg, sample, tmp_path):
    """Simulated photons over the real tile (no inserted offset): a small, determined offset
    per beam and for all, written as JSON."""
    import json

    import rasterio
    from rasterio.transform import Affine

    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03

    laz = sample("als/lasR_bcts_1.laz")
    pts = read_las([laz])
    b = pts.bounds
    g = pts.classification == 2
    res = 2.0
    nx, ny = int((b[2] - b[0]) // res) + 1, int((b[3] - b[1]) // res) + 1
    k = (((b[3] - pts.y[g]) // res).astype(int) * nx + ((pts.x[g] - b[0]) // res).astype(int))
    n = np.bincount(k, minlength=nx * ny)
    dtm = np.where(n > 0, np.bincount(k, pts.z[g], minlength=nx * ny) / np.maximum(n, 1),
                   -9999).reshape(ny, nx)
    tif = tmp_path / "dtm.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=nx, height=ny, count=1,
                       dtype="float32", crs=pts.crs, nodata=-9999,
                       transform=Affine(res, 0, b[0], 0, -res, b[3])) as dst:
        dst.write(dtm.astype("float32"), 1)
    sim = simulate_photons(pts, line_through(b, 10.0, inset=8), SimParams(), seed=2)
    h5 = tmp_path / "sim.h5"
    write_simulation_atl03(sim, h5)
    out = run_alg("canopyblocks:coregister", {
        "INPUT": str(h5), "DTM": str(tif), "OFFSET": 0.0, "CRS": "EPSG:3005", "RANGE": 10.0,
        "OUTPUT": str(tmp_path / "offsets.json"), "OFFSETS": str(tmp_path / "offsets.gpkg")})
    doc = json.loads(Path(out["OUTPUT"]).read_text())
    assert "all" in doc and abs(doc["all"]["vertical"]) < 0.6
    assert abs(doc["all"]["along_track"]) <= 3 and abs(doc["all"]["cross_track"]) <= 3
    # the offsets also as a layer: one row per track and 'all', the same numbers
    import geopandas as gpd

    table = gpd.read_file(out["OFFSETS"]).set_index("track")
    assert set(table.index) == {k for k in doc if isinstance(doc[k], dict)
                                and "vertical" in doc[k]}
    for k in table.index:
        for f in ("east", "north", "along_track", "cross_track", "vertical"):
            assert table.loc[k, f] == pytest.approx(doc[k][f], abs=1e-4)  # JSON: 4 decimals
