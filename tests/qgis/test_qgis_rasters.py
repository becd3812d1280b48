"""Reference rasters as QGIS sees them: CRSs it identifies by their codes, a DTM without holes
and a fill mask marking exactly the cells PDAL's own pipeline leaves empty.

The rasters are made by the plugin's algorithm (``processing.run``) and read back through
QGIS's raster provider; the empty cells are counted independently from a PDAL pipeline
written here (mean of class 2 within the cell circle, no filling).
"""

from __future__ import annotations

import gc
import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytestmark = [pytest.mark.qgis, pytest.mark.pdal]

BCTS = ("als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz")
BOUNDS = (885100.0, 629380.0, 885140.0, 629420.0)  # straddles the two tiles


def _band(layer: Any) -> tuple[np.ndarray, float | None]:
    """Band 1 through QGIS's provider, and its nodata value."""
    prov = layer.dataProvider()
    block = prov.block(1, layer.extent(), layer.width(), layer.height())
    a = np.array([[block.value(r, c) for c in range(layer.width())]
                  for r in range(layer.height())])
    nodata = prov.sourceNoDataValue(1) if prov.sourceHasNoDataValue(1) else None
    return a, nodata


def _raw_empty(pdal_bin: str, tiles: list[Path], out: Path) -> np.ndarray:
    x0, y0, x1, y1 = BOUNDS
    res = 2.0
    stages: list[object] = [{"type": "readers.las", "filename": str(t)} for t in tiles]
    stages += [{"type": "filters.range", "limits": "Classification[2:2]"},
               {"type": "writers.gdal", "filename": str(out), "output_type": "mean",
                "resolution": res, "radius": res * 2 ** 0.5 / 2, "origin_x": x0,
                "origin_y": y0, "width": int((x1 - x0) / res),
                "height": int((y1 - y0) / res), "nodata": -9999, "window_size": 0}]
    r = subprocess.run([pdal_bin, "pipeline", "--stdin"], input=json.dumps(stages),
                       text=True, capture_output=True, timeout=300)
    assert r.returncode == 0, r.stderr
    import rasterio

    with rasterio.open(out) as src:
        return src.read(1) == -9999


def test_rasters_identified_filled_and_masked(run_alg, sample, pdal_bin, tmp_path,
                                               monkeypatch) -> None:
    from qgis.core import QgsRasterLayer

    monkeypatch.setenv("CANOPYBLOCKS_PDAL", pdal_bin)
    tiles = [sample(p) for p in BCTS]
    res = run_alg("canopyblocks:referencerasters", {
        "INPUT": [str(t) for t in tiles], "RESOLUTION": 2.0,
        "EXTENT": f"{BOUNDS[0]},{BOUNDS[2]},{BOUNDS[1]},{BOUNDS[3]} [EPSG:3005]",
        "OUTPUT_DIR": str(tmp_path / "r")})
    assert set(res) >= {"DTM", "DSM_MAX", "DSM_P90", "DTM_FILL_MASK"}
    empty = _raw_empty(pdal_bin, tiles, tmp_path / "raw.tif")
    assert 0 < empty.sum() < empty.size
    layers = {k: QgsRasterLayer(res[k], k) for k in ("DTM", "DSM_MAX", "DSM_P90",
                                                     "DTM_FILL_MASK")}
    try:
        for name, layer in layers.items():
            crs = layer.crs()
            assert layer.isValid() and crs.isValid(), name
            # QGIS 3.40 gives a compound CRS no authid of its own; its parts have theirs
            assert crs.horizontalCrs().authid() == "EPSG:3005", (name, crs.toWkt())
            assert crs.verticalCrs().authid() == "EPSG:5713", name
            assert "unknown" not in crs.description().lower(), crs.description()
        dtm, dtm_nodata = _band(layers["DTM"])
        mask, _ = _band(layers["DTM_FILL_MASK"])
        assert dtm.shape == empty.shape
        assert not (dtm == dtm_nodata).any() and np.isfinite(dtm).all()  # no hole left
        assert int((mask == 1).sum()) == int(empty.sum())
        assert np.array_equal(mask == 1, empty)
    finally:
        layers.clear()
        gc.collect()


def test_unknown_vertical_crs_is_not_an_unknown_crs(run_alg, sample, pdal_bin, tmp_path,
                                                   monkeypatch) -> None:
    """LAS files without a vertical CRS: PDAL writes a compound CRS named "unknown"; QGIS
    showed that name.  Now the horizontal part carries its code and the name says which
    part is unknown."""
    from qgis.core import QgsRasterLayer

    monkeypatch.setenv("CANOPYBLOCKS_PDAL", pdal_bin)
    res = run_alg("canopyblocks:referencerasters", {
        "INPUT": [str(sample("als/pyfor_test.laz"))], "RESOLUTION": 2.0,
        "EXTENT": "405100,405120,3276400,3276420 [EPSG:32617]",
        "OUTPUT_DIR": str(tmp_path / "r")})
    layer = QgsRasterLayer(res["DTM"], "dtm")
    try:
        crs = layer.crs()
        assert layer.isValid() and crs.isValid()
        assert crs.horizontalCrs().authid() == "EPSG:32617"
        assert crs.description() == "WGS 84 / UTM zone 17N + unknown height"
    finally:
        del layer
        gc.collect()


def test_a_folder_of_tiles_is_a_survey(run_alg, sample, tmp_path) -> None:  # noqa: ANN001
    """The algorithm takes a folder of tiles (read tile by tile) and gives the rasters of the
    same tiles given as files, with progress per tile."""
    import shutil

    from qgis.core import QgsProcessingFeedback

    folder = tmp_path / "survey"
    folder.mkdir()
    for p in BCTS:
        shutil.copy(sample(p), folder)
    ext = f"{BOUNDS[0]},{BOUNDS[2]},{BOUNDS[1]},{BOUNDS[3]} [EPSG:3005]"
    seen: list[float] = []
    fb = QgsProcessingFeedback()
    fb.progressChanged.connect(seen.append)
    a = run_alg("canopyblocks:referencerasters", {
        "SURVEY": str(folder), "RESOLUTION": 2.0, "EXTENT": ext,
        "OUTPUT_DIR": str(tmp_path / "a")}, feedback=fb)
    b = run_alg("canopyblocks:referencerasters", {
        "INPUT": [str(sample(p)) for p in BCTS], "RESOLUTION": 2.0, "EXTENT": ext,
        "OUTPUT_DIR": str(tmp_path / "b")})
    import rasterio

    for key in ("DTM", "DSM_MAX", "DSM_P90"):
        with rasterio.open(a[key]) as x, rasterio.open(b[key]) as y:
            assert np.array_equal(x.read(1), y.read(1)), key
    assert len(seen) > 3 and max(seen) == 100
