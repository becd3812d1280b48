"""Run inside the real QGIS application (``qgis --code app_startup.py``) by test_qgis_app.py.

Reads its settings from the environment (CANOPYBLOCKS_APP_JSON: a JSON of inputs and output
folder), runs the chain with ``processing.runAndLoadResults`` as a user would from the
toolbox, describes every loaded layer (renderer, elevation properties, draw order), renders
the map to a PNG, writes ``result.json`` and quits.  Not a test module: pytest does not
collect it (no ``test_`` prefix).
"""

from __future__ import annotations

import json
import os
import traceback
from pathlib import Path
from typing import Any

from qgis.core import (
    Qgis,
    QgsApplication,
    QgsMapLayerElevationProperties,
    QgsMapRendererParallelJob,
    QgsMapSettings,
    QgsProject,
    QgsRasterLayer,
    QgsVectorLayer,
    QgsWkbTypes,
)
from qgis.PyQt.QtCore import QSize, QTimer
from qgis.PyQt.QtGui import QColor

CFG = json.loads(os.environ["CANOPYBLOCKS_APP_JSON"])
OUT = Path(CFG["out"])
MESSAGES: list[dict[str, Any]] = []


def _log(message: str, tag: str, level: Any) -> None:
    if level in (Qgis.MessageLevel.Critical,) or "Traceback" in message or \
            "Cannot open" in message:  # e.g. OGR trying LAS/LAZ inputs as vector layers
        MESSAGES.append({"tag": tag, "level": int(level), "message": message[:2000]})


def _describe(layer: Any) -> dict[str, Any]:
    d: dict[str, Any] = {"name": layer.name(), "source": layer.source()}
    if isinstance(layer, QgsVectorLayer):
        props = layer.elevationProperties()
        dd = props.dataDefinedProperties()
        prop = QgsMapLayerElevationProperties.Property
        d.update(kind="vector", features=layer.featureCount(),
                 renderer=layer.renderer().type() if layer.renderer() else None,
                 clamping=int(props.clamping()), extrusion=props.extrusionEnabled(),
                 z_field=dd.property(prop.ZOffset).field() if dd.isActive(prop.ZOffset)
                 else None,
                 has_z=QgsWkbTypes.hasZ(layer.wkbType()),
                 rules=[r.label() for r in layer.renderer().rootRule().children()]
                 if layer.renderer() and layer.renderer().type() == "RuleRenderer" else [])
    elif isinstance(layer, QgsRasterLayer):
        d.update(kind="raster", renderer=layer.renderer().type() if layer.renderer() else None,
                 elevation=layer.elevationProperties().isEnabled())
    return d


def _render(layers: list[Any], path: Path) -> None:
    settings = QgsMapSettings()
    settings.setLayers(layers)
    settings.setBackgroundColor(QColor("white"))
    settings.setOutputSize(QSize(1200, 900))
    dtm = next(lyr for lyr in layers if isinstance(lyr, QgsRasterLayer))
    settings.setDestinationCrs(dtm.crs())
    blocks = next(lyr for lyr in layers if lyr.name() == "Blocks")
    extent = settings.layerExtentToOutputExtent(blocks, blocks.extent())
    extent.scale(1.3)
    settings.setExtent(extent)
    job = QgsMapRendererParallelJob(settings)
    job.start()
    job.waitForFinished()
    job.renderedImage().save(str(path), "png")


def run() -> None:
    result: dict[str, Any] = {"steps": {}}
    try:
        import processing

        tmp = OUT
        steps = [
            ("simulate", {"INPUT": [CFG["tile"]], "AZIMUTH": 0.0, "SEED": 3,
                          "OUTPUT": str(tmp / "sim.h5"),
                          "PHOTONS": str(tmp / "sim_photons.gpkg")}),
            ("blockheights", {"INPUT": str(tmp / "sim.h5"), "TRACK": "gt1r",
                              "LENGTHS": "25, 10", "OUTPUT": str(tmp / "blocks.gpkg"),
                              "PHOTONS": str(tmp / "photons.gpkg")}),
            ("referencerasters", {"INPUT": [CFG["tile"]], "RESOLUTION": 2.0,
                                  "OUTPUT_DIR": str(tmp / "rasters")}),
        ]
        for alg, params in steps:
            result["steps"][alg] = {k: str(v) for k, v in processing.runAndLoadResults(
                f"canopyblocks:{alg}", params).items()}
        r = result["steps"]["referencerasters"]
        more = [
            ("validate", {"INPUT": str(tmp / "blocks.gpkg"), "DTM": r["DTM"],
                          "DSM_MAX": r["DSM_MAX"], "DSM_P90": r["DSM_P90"], "WIDTH": 13.0,
                          "OFFSET": 0.0, "OUTPUT": str(tmp / "residuals.gpkg"),
                          "STATS": str(tmp / "stats.csv")}),
            ("aspecterrors", {"INPUT": str(tmp / "residuals.gpkg"),
                              "OUTPUT": str(tmp / "aspect_stats.csv"),
                              "MAP": str(tmp / "aspect_map.gpkg")}),
            ("gedifootprints", {"INPUT": CFG["l1b"], "OUTPUT": str(tmp / "footprints.gpkg")}),
        ]
        for alg, params in more:
            result["steps"][alg] = {k: str(v) for k, v in processing.runAndLoadResults(
                f"canopyblocks:{alg}", params).items()}
        root = QgsProject.instance().layerTreeRoot()
        ordered = [n.layer() for n in root.findLayers()]
        result["layers"] = [_describe(layer) for layer in ordered]
        track_layers = [lyr for lyr in ordered if "GEDI" not in lyr.name()
                        and lyr.isSpatial()]
        _render(track_layers, OUT / "map.png")
    except Exception:  # noqa: BLE001 - reported to the test
        result["error"] = traceback.format_exc()
    result["messages"] = MESSAGES
    (OUT / "result.json").write_text(json.dumps(result, indent=1))
    QgsProject.instance().clear()
    os._exit(0)  # QGIS's own teardown under Xvfb is not what is tested here


QgsApplication.messageLog().messageReceived.connect(_log)
QTimer.singleShot(500, run)
