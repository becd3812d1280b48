"""The flash-lidar and dual-wavelength footprints algorithm in headless QGIS, on files the
'Simulate waveforms' algorithm writes over a real tile: rows against the simulator's
truth (read with h5py), the pixels layer, and the styled layer rendered: every footprint
drawn in a height colour at its own position (pixels checked)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

pytestmark = [pytest.mark.qgis]

SENSORS = {"esfl": 1, "dual": 2}   # the simulate-waveforms algorithm's sensor options


def _image_array(img: Any) -> np.ndarray:
    from qgis.PyQt.QtGui import QImage

    img = img.convertToFormat(QImage.Format.Format_ARGB32)
    ptr = img.constBits()
    ptr.setsize(img.sizeInBytes())
    return np.frombuffer(ptr, np.uint8).reshape(img.height(), img.width(), 4).copy()


def _render(layer: Any, size: int = 600) -> tuple[np.ndarray, Any]:
    from qgis.core import QgsMapRendererParallelJob, QgsMapSettings
    from qgis.PyQt.QtCore import QSize
    from qgis.PyQt.QtGui import QColor

    settings = QgsMapSettings()
    settings.setLayers([layer])
    settings.setBackgroundColor(QColor("white"))
    settings.setOutputSize(QSize(size, size))
    settings.setDestinationCrs(layer.crs())
    extent = layer.extent()
    extent.scale(1.3)
    settings.setExtent(extent)
    job = QgsMapRendererParallelJob(settings)
    job.start()
    job.waitForFinished()
    return _image_array(job.renderedImage()), settings


@pytest.fixture(scope="module")
def simulated(tmp_path_factory, sample) -> dict[str, Path]:
    import processing
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback

    d = tmp_path_factory.mktemp("qgis_flash_dual")
    out = {}
    for sensor, index in SENSORS.items():
        path = d / f"{sensor}.h5"
        processing.run("canopyblocks:simulatewaveforms", {
            "INPUT": [str(sample("als/pyfor_test.laz"))], "SENSOR": index, "AZIMUTH": 10.0,
            "SEED": 2, "OUTPUT": str(path)}, context=QgsProcessingContext(),
            feedback=QgsProcessingFeedback())
        out[sensor] = path
    return out


@pytest.mark.parametrize("sensor", list(SENSORS))
def test_footprints_against_truth_and_rendered(run_alg, open_layer, layer_rows, simulated,
                                               tmp_path, sensor):
    from qgis.core import QgsWkbTypes
    from qgis_plugin.styles import height_renderer

    params = {"INPUT": str(simulated[sensor]), "OUTPUT": str(tmp_path / "fp.gpkg")}
    if sensor == "esfl":
        params.update(CELL=0.0, PIXELS=str(tmp_path / "pixels.gpkg"))  # one row a footprint
    res = run_alg("canopyblocks:flashdualfootprints", params)
    layer = open_layer(res["OUTPUT"])
    assert QgsWkbTypes.hasZ(layer.wkbType())
    rows = layer_rows(layer)
    with h5py.File(simulated[sensor]) as f:
        truth = f["truth/ground"][()]
    assert len(rows) == truth.size
    ok = [r for r in rows if r["flag"] == "ok"]
    assert len(ok) >= 5
    err = np.array([r["ground"] - truth[int(r["shot_number"])] for r in ok])
    assert np.abs(err).max() < 1.5 and np.median(np.abs(err)) < 0.5
    assert all(0 < r["height"] < 45 for r in ok)
    if sensor == "esfl":
        px = layer_rows(open_layer(res["PIXELS"]))   # the 4 x 4 region, all bright
        per = np.bincount([int(r["shot_number"]) for r in px])
        assert np.median(per[per > 0]) == 16
    # the layer styled as the plugin styles it on load, rendered: each ok footprint's
    # pixel (from its coordinates) is drawn in a green height colour, not the background
    layer.setRenderer(height_renderer(layer, "height"))
    img, settings = _render(layer)
    m2p = settings.mapToPixel()
    hits = 0
    for r in ok:
        p = m2p.transform(r["_xy"][0], r["_xy"][1])
        x, y = int(round(p.x())), int(round(p.y()))
        patch = img[y - 1:y + 2, x - 1:x + 2]
        b, g, red = patch[..., 0].astype(int), patch[..., 1].astype(int), \
            patch[..., 2].astype(int)
        assert ((g > red + 10) & (g > b)).any(), (r["shot_number"], patch[..., :3].tolist())
        hits += 1
    assert hits == len(ok)


def test_gedi_file_is_sent_to_the_gedi_algorithm(run_alg, gedi_l1b, tmp_path):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="GEDI footprints"):
        run_alg("canopyblocks:flashdualfootprints", {
            "INPUT": str(gedi_l1b), "OUTPUT": str(tmp_path / "x.gpkg")})
