"""The QGIS co-registration algorithm says ``undetermined`` the way the command line does.

Photons simulated over the real bcts tile are exactly geolocated (no offset); the
algorithm must write the same offsets.json as ``canopyblocks coregister`` on the same
inputs, and an undetermined offset must reach the user as a warning, its lines saying
``undetermined``. Rasters moved 50 km away are refused (a QGIS error naming the share of
the track's blocks on them).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, sample):
    import rasterio
    from rasterio.transform import Affine

    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03

    d = tmp_path_factory.mktemp("qgis_coreg")
    pts = read_las([sample("als/lasR_bcts_1.laz")])
    b = pts.bounds
    g = pts.classification == 2
    res = 2.0
    nx, ny = int((b[2] - b[0]) // res) + 1, int((b[3] - b[1]) // res) + 1
    k = (((b[3] - pts.y[g]) // res).astype(int) * nx + ((pts.x[g] - b[0]) // res).astype(int))
    n = np.bincount(k, minlength=nx * ny)
    dtm = np.where(n > 0, np.bincount(k, pts.z[g], minlength=nx * ny) / np.maximum(n, 1),
                   -9999).reshape(ny, nx)
    tifs = {}
    for name, dx in (("dtm", 0.0), ("far", 50_000.0)):
        tifs[name] = d / f"{name}.tif"
        with rasterio.open(tifs[name], "w", driver="GTiff", width=nx, height=ny, count=1,
                           dtype="float32", crs=pts.crs, nodata=-9999,
                           transform=Affine(res, 0, b[0] + dx, 0, -res, b[3])) as dst:
            dst.write(dtm.astype("float32"), 1)
    sim = simulate_photons(pts, line_through(b, 10.0, inset=8), SimParams(), seed=5)
    h5 = write_simulation_atl03(sim, d / "sim.h5")
    return {"dir": d, "h5": h5, **tifs}


def test_qgis_coregister_equals_cli_and_warns_when_undetermined(run_alg, inputs):
    from qgis.core import QgsProcessingFeedback

    infos: list[str] = []
    warns: list[str] = []

    class Feedback(QgsProcessingFeedback):
        def pushInfo(self, info: str) -> None:  # noqa: N802
            infos.append(info)
            super().pushInfo(info)

        def pushWarning(self, warning: str) -> None:  # noqa: N802
            warns.append(warning)
            super().pushWarning(warning)

    d = inputs["dir"]
    out = run_alg("canopyblocks:coregister", {
        "INPUT": str(inputs["h5"]), "DTM": str(inputs["dtm"]), "OFFSET": 0.0,
        "CRS": "EPSG:3005", "RANGE": 15.0, "OUTPUT": str(d / "qgis.json")},
        feedback=Feedback())
    doc = json.loads(Path(out["OUTPUT"]).read_text())
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "coregister", str(inputs["h5"]),
                        "--dtm", str(inputs["dtm"]), "--offset", "0", "--crs", "EPSG:3005",
                        "-o", str(d / "cli.json")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    cli = json.loads((d / "cli.json").read_text())
    assert {k: v for k, v in doc.items() if k != "_meta"} == \
        {k: v for k, v in cli.items() if k != "_meta"}
    status = doc["all"]["status"]
    assert any(line.endswith(status) for line in infos), infos
    if status == "undetermined":
        assert any("undetermined" in w for w in warns), warns
        assert "undetermined" in r.stderr


def test_qgis_coregister_refuses_rasters_off_the_track(run_alg, inputs):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match=r"cover 0 of \d+ blocks \(0 %\)"):
        run_alg("canopyblocks:coregister", {
            "INPUT": str(inputs["h5"]), "DTM": str(inputs["far"]), "OFFSET": 0.0,
            "CRS": "EPSG:3005", "RANGE": 15.0, "OUTPUT": str(inputs["dir"] / "far.json")})
