"""Default symbology of the output layers, applied when QGIS loads them.

* residuals (``res_*``): graduated, diverging RdBu ramp, classes symmetric around 0;
* aspect classes: categorised, one colour per compass class (+ ``flat``);
* block heights (``hmax``): graduated green ramp;
* photon labels: categorised noise / ground / canopy / between.
"""

from __future__ import annotations

import math
from typing import Any

from qgis.core import (
    QgsCategorizedSymbolRenderer,
    QgsGradientColorRamp,
    QgsGraduatedSymbolRenderer,
    QgsProcessingContext,
    QgsProcessingLayerPostProcessorInterface,
    QgsRendererCategory,
    QgsRendererRange,
    QgsStyle,
    QgsSymbol,
    QgsVectorLayer,
)
from qgis.PyQt.QtGui import QColor

__all__ = [
    "residual_renderer",
    "aspect_renderer",
    "height_renderer",
    "label_renderer",
    "style_on_load",
    "ASPECT_COLOURS",
]

ASPECT_COLOURS = {
    "N": "#e41a1c", "NE": "#ff7f00", "E": "#ffd92f", "SE": "#4daf4a",
    "S": "#1b9e77", "SW": "#377eb8", "W": "#6a3d9a", "NW": "#e7298a", "flat": "#bdbdbd",
}
LABEL_COLOURS = {0: ("noise", "#bbbbbb"), 1: ("ground", "#a6611a"),
                 2: ("canopy", "#1b7837"), 3: ("between", "#4d4d4d")}

_RDBU = ["#b2182b", "#ef8a62", "#fddbc7", "#f7f7f7", "#d1e5f0", "#67a9cf", "#2166ac"]


def _symbol(layer: QgsVectorLayer, colour: str) -> QgsSymbol:
    sym = QgsSymbol.defaultSymbol(layer.geometryType())
    sym.setColor(QColor(colour))
    return sym


def _values(layer: QgsVectorLayer, field: str) -> list[Any]:
    idx = layer.fields().indexOf(field)
    if idx < 0:
        return []
    return [v for v in layer.uniqueValues(idx) if v is not None and not _null(v)]


def _null(v: Any) -> bool:
    return hasattr(v, "isNull") and v.isNull()


def residual_renderer(layer: QgsVectorLayer, field: str = "res_hmax",
                      n_classes: int = 7) -> QgsGraduatedSymbolRenderer:
    """Graduated RdBu renderer for ``field``, classes symmetric around 0 (red = photon low).

    The class width is ``2 * max|residual| / n_classes``, so the middle class holds 0.
    """
    vals = [float(v) for v in _values(layer, field) if isinstance(v, (int, float))]
    vmax = max((abs(v) for v in vals if math.isfinite(v)), default=1.0) or 1.0
    edges = [-vmax + 2 * vmax * i / n_classes for i in range(n_classes + 1)]
    ranges = []
    for i in range(n_classes):
        colour = _RDBU[round(i * (len(_RDBU) - 1) / max(n_classes - 1, 1))]
        lo, hi = edges[i], edges[i + 1]
        ranges.append(QgsRendererRange(lo, hi, _symbol(layer, colour), f"{lo:.1f} to {hi:.1f} m"))
    r = QgsGraduatedSymbolRenderer(field, ranges)
    ramp = QgsGradientColorRamp(QColor(_RDBU[0]), QColor(_RDBU[-1]))
    ramp.setStops([])
    r.setSourceColorRamp(ramp)
    return r


def aspect_renderer(layer: QgsVectorLayer,
                    field: str = "aspect_class") -> QgsCategorizedSymbolRenderer:
    """Categorised renderer: one fixed colour per aspect class."""
    cats = [QgsRendererCategory(name, _symbol(layer, colour), name)
            for name, colour in ASPECT_COLOURS.items()]
    return QgsCategorizedSymbolRenderer(field, cats)


def label_renderer(layer: QgsVectorLayer, field: str) -> QgsCategorizedSymbolRenderer:
    """Categorised renderer for a per-photon label column (noise/ground/canopy/between)."""
    cats = [QgsRendererCategory(name, _symbol(layer, colour), name)
            for name, colour in LABEL_COLOURS.values()]
    return QgsCategorizedSymbolRenderer(field, cats)


def height_renderer(layer: QgsVectorLayer, field: str = "hmax",
                    n_classes: int = 5) -> QgsGraduatedSymbolRenderer:
    """Graduated green renderer of block heights (equal intervals, 0 to the maximum)."""
    vals = [float(v) for v in _values(layer, field) if isinstance(v, (int, float))]
    vmax = max((v for v in vals if math.isfinite(v)), default=1.0)
    vmax = vmax if vmax > 0 else 1.0
    ramp = QgsStyle.defaultStyle().colorRamp("Greens") or QgsGradientColorRamp(
        QColor("#e5f5e0"), QColor("#00441b"))
    ranges = []
    for i in range(n_classes):
        lo, hi = vmax * i / n_classes, vmax * (i + 1) / n_classes
        colour = ramp.color(i / max(n_classes - 1, 1))
        sym = QgsSymbol.defaultSymbol(layer.geometryType())
        sym.setColor(colour)
        ranges.append(QgsRendererRange(lo, hi, sym, f"{lo:.1f} to {hi:.1f} m"))
    r = QgsGraduatedSymbolRenderer(field, ranges)
    r.setSourceColorRamp(ramp.clone())
    return r


_STYLERS = {
    "residual": residual_renderer,
    "aspect": aspect_renderer,
    "height": height_renderer,
    "label": label_renderer,
}


class _StylePostProcessor(QgsProcessingLayerPostProcessorInterface):
    """Applies one renderer to an output layer when QGIS loads it."""

    _keep: list[_StylePostProcessor] = []  # QGIS does not own Python post-processors

    def __init__(self, kind: str, field: str) -> None:
        super().__init__()
        self.kind = kind
        self.field = field

    def postProcessLayer(self, layer: Any, context: Any, feedback: Any) -> None:  # noqa: N802
        if isinstance(layer, QgsVectorLayer) and layer.fields().indexOf(self.field) >= 0:
            layer.setRenderer(_STYLERS[self.kind](layer, self.field))
            layer.triggerRepaint()

    @classmethod
    def create(cls, kind: str, field: str) -> _StylePostProcessor:
        p = cls(kind, field)
        cls._keep.append(p)
        return p


def style_on_load(context: QgsProcessingContext, dest_id: str | None, kind: str,
                  field: str) -> None:
    """Ask QGIS to style output ``dest_id`` with ``kind`` on ``field`` when it loads it."""
    if dest_id and context.willLoadLayerOnCompletion(dest_id):
        details = context.layerToLoadOnCompletionDetails(dest_id)
        details.setPostProcessor(_StylePostProcessor.create(kind, field))
