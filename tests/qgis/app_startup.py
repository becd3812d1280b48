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
                 if layer.renderer() and layer.renderer().type() == "RuleRenderer" else
                 [c.label() for c in layer.renderer().categories()]
                 if layer.renderer() and layer.renderer().type() == "categorizedSymbol"
                 else [])
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
    blocks = next(lyr for lyr in layers if lyr.name().startswith("Blocks"))
    extent = settings.layerExtentToOutputExtent(blocks, blocks.extent())
    extent.scale(1.3)
    settings.setExtent(extent)
    job = QgsMapRendererParallelJob(settings)
    job.start()
    job.waitForFinished()
    job.renderedImage().save(str(path), "png")


def _bars_profile(blocks: Any, path: Path) -> dict[str, Any]:
    """The Elevation Profile of the loaded, plugin-styled blocks (QGIS's own profile engine
    with the layer's elevation properties as loaded, "respect layer symbology" as QGIS
    leaves it), and where each 25 m block's bar must be: (column, top row, ground row)
    computed from its attributes alone."""
    from qgis.core import (
        QgsFeatureRequest,
        QgsGeometry,
        QgsLineString,
        QgsPoint,
        QgsProfilePlotRenderer,
        QgsProfileRequest,
    )

    feats = [f for f in blocks.getFeatures(QgsFeatureRequest().setFilterExpression(
        '"length" = 25'))]
    feats.sort(key=lambda f: f["s_start"])
    pts = [f.geometry().asPoint() for f in feats]
    line = QgsLineString([QgsPoint(pts[0].x(), pts[0].y()), QgsPoint(pts[-1].x(),
                                                                      pts[-1].y())])
    length = line.length()
    grounds = [float(f["ground"]) for f in feats if f["hmax"] is not None
               and not (hasattr(f["hmax"], "isNull") and f["hmax"].isNull())]
    tops = [float(f["ground"]) + float(f["hmax"]) for f in feats if f["hmax"] is not None
            and not (hasattr(f["hmax"], "isNull") and f["hmax"].isNull())]
    z0, z1 = min(grounds) - 5.0, max(tops) + 5.0
    w, h = 1200, 600
    req = QgsProfileRequest(line.clone())
    req.setCrs(blocks.crs())
    req.setTolerance(5.0)
    renderer = QgsProfilePlotRenderer([blocks], req)
    renderer.startGeneration()
    renderer.waitForFinished()
    img = renderer.renderToImage(w, h, 0.0, length, z0, z1)
    img.save(str(path), "png")
    geom = QgsGeometry(line.clone())
    bars = []
    for f in feats:
        hm = f["hmax"]
        if hm is None or (hasattr(hm, "isNull") and hm.isNull()) or float(hm) < 2.0:
            continue
        d = geom.lineLocatePoint(f.geometry())
        g = float(f["ground"])
        bars.append({"col": round(d / length * w), "top_row": round((z1 - g - float(hm)) /
                     (z1 - z0) * h), "ground_row": round((z1 - g) / (z1 - z0) * h),
                     "hmax": float(hm)})
    return {"respect_symbology": blocks.elevationProperties().respectLayerSymbology(),
            "bars": bars}


def _canvas_screenshot(layers: list[Any], blocks: Any, path: Path) -> dict[str, Any]:
    """The desktop's own map canvas with the loaded layers, grabbed to a PNG; and the canvas
    pixel of each block point (from its coordinates)."""
    import time

    from qgis.core import QgsCoordinateTransform
    from qgis.utils import iface

    iface.mainWindow().showMaximized()
    end = time.monotonic() + 2.0
    while time.monotonic() < end:  # let the window take the screen
        QgsApplication.processEvents()
        time.sleep(0.05)
    QgsProject.instance().setCrs(blocks.crs())
    canvas = iface.mapCanvas()
    canvas.setDestinationCrs(blocks.crs())
    canvas.setLayers(layers)
    ext = canvas.mapSettings().layerExtentToOutputExtent(blocks, blocks.extent())
    ext.scale(1.2)
    canvas.setExtent(ext)
    done: list[bool] = []
    canvas.mapCanvasRefreshed.connect(lambda: done.append(True))
    canvas.refreshAllLayers()
    end = time.monotonic() + 30.0
    while not done and time.monotonic() < end:  # the canvas renders in the event loop
        QgsApplication.processEvents()
        time.sleep(0.05)
    canvas.waitWhileRendering()
    QgsApplication.processEvents()
    canvas.grab().save(str(path), "png")
    xform = canvas.getCoordinateTransform()
    tr = QgsCoordinateTransform(blocks.crs(), canvas.mapSettings().destinationCrs(),
                                QgsProject.instance())
    points = []
    for f in blocks.getFeatures():
        p = xform.transform(tr.transform(f.geometry().asPoint()))
        hm = f["hmax"]
        points.append({"x": round(p.x()), "y": round(p.y()), "length": float(f["length"]),
                       "has_hmax": not (hm is None or (hasattr(hm, "isNull") and hm.isNull()))})
    return {"size": [canvas.width(), canvas.height()], "points": points}


def _dialog(alg_id: str, path: Path, photon_file: Path | None = None) -> dict[str, Any]:
    """Open the algorithm's dialog as the toolbox does, grab it to a PNG, and report what it
    shows: the number boxes' texts, the labels, the collapsible groups."""
    import processing
    from qgis.gui import QgsDoubleSpinBox
    from qgis.PyQt.QtWidgets import QGroupBox, QLabel

    dlg = processing.createAlgorithmDialog(f"canopyblocks:{alg_id}", {})
    dlg.resize(900, 900)
    dlg.show()
    for _ in range(20):
        QgsApplication.processEvents()
    beams: list[str] = []
    if photon_file is not None:  # choose the file as a user would: the beam box fills
        from qgis.core import QgsProcessingContext

        wrappers = dlg.mainWidget().wrappers
        wrappers["INPUT"].setParameterValue(str(photon_file), QgsProcessingContext())
        for _ in range(10):
            QgsApplication.processEvents()
        box = wrappers["TRACK"].widget
        beams = [box.itemData(i) for i in range(box.count()) if box.itemData(i)]
    dlg.grab().save(str(path), "png")
    spins = {}
    for spin in dlg.findChildren(QgsDoubleSpinBox):
        # the parameter a box belongs to: the label just above it in the panel's layout
        spins[spin.objectName() or str(len(spins))] = spin.text()
    from qgis.PyQt.QtWidgets import QWidget

    info = {"spins": sorted(spins.values()), "beams": beams,
            "labels": [lbl.text() for lbl in dlg.findChildren(QLabel) if lbl.text()],
            "visible_labels": [lbl.text() for lbl in dlg.findChildren(QLabel)
                               if lbl.text() and lbl.isVisible()],
            "groups": [(g.title(), True) for g in dlg.findChildren(QGroupBox)]
            + [(w.text(), True) for w in dlg.findChildren(QWidget)
               if hasattr(w, "text") and callable(w.text) and isinstance(w.text(), str)
               and "Advanced" in w.text()]}
    dlg.close()
    return info


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
        blocks = next(lyr for lyr in ordered if lyr.name().startswith("Blocks"))
        result["profile"] = _bars_profile(blocks, OUT / "profile.png")
        result["canvas"] = _canvas_screenshot(track_layers, blocks, OUT / "canvas.png")
        from qgis.utils import iface

        iface.mainWindow().grab().save(str(OUT / "window.png"), "png")
        result["dialog"] = _dialog("blockheights", OUT / "dialog.png", OUT / "sim.h5")
    except Exception:  # noqa: BLE001 - reported to the test
        result["error"] = traceback.format_exc()
    result["messages"] = MESSAGES
    (OUT / "result.json").write_text(json.dumps(result, indent=1))
    QgsProject.instance().clear()
    os._exit(0)  # QGIS's own teardown under Xvfb is not what is tested here


QgsApplication.messageLog().messageReceived.connect(_log)
QTimer.singleShot(500, run)
