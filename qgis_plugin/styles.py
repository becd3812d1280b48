"""Default symbology of the output layers, applied when QGIS loads them.

* residuals (``res_*``): graduated, diverging RdBu ramp, classes symmetric around 0;
* aspect classes: categorised, one colour per compass class (+ ``flat``);
* block heights (``hmax``): green classes from light (not white) to dark green per block
  length, blocks without a height (sparse) drawn grey, not hidden;
* photon labels: categorised noise / ground / canopy / between;
* rasters: DTM in a terrain ramp with its elevation enabled, DSMs in greens, the DTM's
  fill mask with its filled cells in orange over the DTM.

Elevation (QGIS 3.26+ Elevation Profile): photons at their height ``h``; blocks and
footprints as vertical bars from ``ground`` up by ``hmax`` / ``rh98`` (absolute clamping,
data-defined Z offset and extrusion); Z geometries at their own Z.
"""

from __future__ import annotations

import math
from typing import Any

from qgis.core import (
    Qgis,
    QgsAggregateCalculator,
    QgsCategorizedSymbolRenderer,
    QgsColorRampShader,
    QgsGradientColorRamp,
    QgsGraduatedSymbolRenderer,
    QgsMapLayerElevationProperties,
    QgsPalettedRasterRenderer,
    QgsProcessingContext,
    QgsProcessingLayerPostProcessorInterface,
    QgsProcessingUtils,
    QgsProperty,
    QgsRasterLayer,
    QgsRasterShader,
    QgsRendererCategory,
    QgsRendererRange,
    QgsSingleBandPseudoColorRenderer,
    QgsStyle,
    QgsSymbol,
    QgsVectorLayer,
    QgsWkbTypes,
)
from qgis.PyQt.QtGui import QColor

__all__ = [
    "residual_renderer",
    "aspect_renderer",
    "height_renderer",
    "label_renderer",
    "style_on_load",
    "load_raster_on_completion",
    "set_elevation",
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


def truth_renderer(layer: QgsVectorLayer, field: str = "noise") -> QgsCategorizedSymbolRenderer:
    """Simulated photons: signal (from a surface) in green, background noise in grey."""
    cats = [QgsRendererCategory(False, _symbol(layer, "#1b7837"), "signal photon"),
            QgsRendererCategory(True, _symbol(layer, "#bdbdbd"), "background noise")]
    return QgsCategorizedSymbolRenderer(field, cats)


def _draw_rank(layer: Any) -> int:
    """Blocks/footprints 0, photons 1, lines 2, polygons 3, tables 4, rasters 5 (top of
    the legend first)."""
    if isinstance(layer, QgsRasterLayer):
        return 5
    if not isinstance(layer, QgsVectorLayer) or not layer.isSpatial():
        return 4
    if layer.geometryType() == Qgis.GeometryType.Point:
        # blocks and footprints above the thousands of photons they summarise
        return 1 if layer.fields().indexOf("h") >= 0 else 0
    return {Qgis.GeometryType.Line: 2}.get(layer.geometryType(), 3)


def _reorder(layer: Any, context: Any) -> None:
    """Sort the project's top-level layers: points on top, then lines, polygons, tables,
    rasters at the bottom (stable: loading order within a rank)."""
    project = context.project() if context is not None else None
    if project is None:
        return
    root = project.layerTreeRoot()
    nodes = [n for n in root.children() if hasattr(n, "layer") and n.layer() is not None]
    ranked = sorted(nodes, key=lambda n: _draw_rank(n.layer()))
    if ranked == nodes:
        return
    for i, node in enumerate(ranked):
        clone = node.clone()
        root.insertChildNode(i, clone)
        root.removeChildNode(node)


def _class_expression(field: str, tops: dict[float | None, float], n_classes: int) -> str:
    """A QGIS expression giving each feature its class key ``"<length>:<i>"`` (or ``"<i>"``
    when there is one group): equal intervals from 0 to the group's maximum ``tops[length]``;
    NULL for features without a value, which the renderer's catch-all category draws."""
    def one(top: float) -> str:
        return (f'to_string(max(0, min({n_classes - 1}, '
                f'floor({n_classes} * "{field}" / {top!r}))))')

    if None in tops:
        return f'CASE WHEN "{field}" IS NULL THEN NULL ELSE {one(tops[None])} END'
    whens = " ".join(f'WHEN "length" = {L!r} THEN \'{L:g}:\' || {one(top)}'
                     for L, top in tops.items())
    return f'CASE WHEN "{field}" IS NULL THEN NULL {whens} END'


def height_renderer(layer: QgsVectorLayer, field: str = "hmax",
                    n_classes: int = 5) -> QgsCategorizedSymbolRenderer:
    """Block heights: graduated green classes (equal intervals from 0 to the maximum), one
    set per block length (each length on its own scale, toggled in the legend), or one set
    when there is one length; features without a value (sparse blocks) drawn grey by the
    catch-all category, not hidden.

    A categorised renderer on an expression, not a rule-based one: QGIS's Elevation Profile
    draws nothing of a rule-based layer when it respects the layer symbology (its default;
    measured on QGIS 3.40), and draws categorised and graduated layers in their colours.
    """
    ramp = QgsStyle.defaultStyle().colorRamp("Greens") or QgsGradientColorRamp(
        QColor("#e5f5e0"), QColor("#00441b"))
    lengths = sorted(float(v) for v in _values(layer, "length") if isinstance(v, (int, float)))
    groups: list[float | None] = list(lengths) if len(lengths) > 1 else [None]
    tops: dict[float | None, float] = {}
    for L in groups:
        if L is None:
            vals = [float(v) for v in _values(layer, field) if isinstance(v, (int, float))]
            top_v: Any = max((v for v in vals if math.isfinite(v)), default=None)
        else:
            params = QgsAggregateCalculator.AggregateParameters()
            params.filter = f'"length" = {L!r}'
            top_v, ok = layer.aggregate(Qgis.Aggregate.Max, field, params)
            top_v = top_v if ok and isinstance(top_v, (int, float)) else None
        tops[L] = float(top_v) if top_v is not None and math.isfinite(top_v) and top_v > 0 \
            else 1.0
    cats = []
    for L in groups:
        for i in range(n_classes):
            lo, hi = tops[L] * i / n_classes, tops[L] * (i + 1) / n_classes
            sym = QgsSymbol.defaultSymbol(layer.geometryType())
            # the lowest class a visible light green, not near-white
            sym.setColor(ramp.color(0.3 + 0.7 * i / max(n_classes - 1, 1)))
            key = f"{i}" if L is None else f"{L:g}:{i}"
            label = f"{lo:.1f} to {hi:.1f} m" if L is None else \
                f"{L:g} m blocks: {lo:.1f} to {hi:.1f} m"
            cats.append(QgsRendererCategory(key, sym, label))
    empty = QgsSymbol.defaultSymbol(layer.geometryType())
    empty.setColor(QColor(0, 0, 0, 0) if layer.geometryType() == Qgis.GeometryType.Polygon
                   else QColor("#9e9e9e"))
    if layer.geometryType() == Qgis.GeometryType.Polygon:
        empty.symbolLayer(0).setStrokeColor(QColor("#757575"))
    cats.append(QgsRendererCategory(None, empty, f"no {field} (sparse / no value)"))
    return QgsCategorizedSymbolRenderer(_class_expression(field, tops, n_classes), cats)


_STYLERS = {
    "residual": residual_renderer,
    "aspect": aspect_renderer,
    "height": height_renderer,
    "label": label_renderer,
    "truth": truth_renderer,
}


def set_elevation(layer: QgsVectorLayer) -> bool:
    """Elevation properties so the layer shows in the Elevation Profile; True when set.

    Photons (``h``) at their height; blocks and footprints (``ground`` with ``hmax`` or
    ``rh98``) as bars from the ground to the canopy top; Z geometries at their Z.
    """
    fields = {f.name() for f in layer.fields()}
    props = layer.elevationProperties()
    dd = props.dataDefinedProperties()
    has_z = QgsWkbTypes.hasZ(layer.wkbType())
    height = next((f for f in ("hmax", "rh98") if f in fields), None)
    if not has_z and "h" in fields:
        dd.setProperty(QgsMapLayerElevationProperties.Property.ZOffset, QgsProperty.fromField("h"))
    elif "ground" in fields and not has_z:
        dd.setProperty(QgsMapLayerElevationProperties.Property.ZOffset,
                       QgsProperty.fromField("ground"))
    elif not has_z:
        return False
    if height is not None and "ground" in fields:
        props.setExtrusionEnabled(True)
        dd.setProperty(QgsMapLayerElevationProperties.Property.ExtrusionHeight,
                       QgsProperty.fromField(height))
    props.setClamping(Qgis.AltitudeClamping.Absolute)
    props.setDataDefinedProperties(dd)
    return True


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
            set_elevation(layer)
            _reorder(layer, context)
            layer.triggerRepaint()

    @classmethod
    def create(cls, kind: str, field: str) -> _StylePostProcessor:
        p = cls(kind, field)
        cls._keep.append(p)
        return p


def style_on_load(context: QgsProcessingContext, dest_id: str | None, kind: str,
                  field: str, name: str | None = None) -> None:
    """Ask QGIS to style output ``dest_id`` with ``kind`` on ``field`` when it loads it,
    under the layer name ``name`` (what it was made from: two runs, two names)."""
    if dest_id and context.willLoadLayerOnCompletion(dest_id):
        details = context.layerToLoadOnCompletionDetails(dest_id)
        details.setPostProcessor(_StylePostProcessor.create(kind, field))
        if name:
            details.name = name
            details.forceName = True


class _RasterPostProcessor(QgsProcessingLayerPostProcessorInterface):
    """Terrain ramp and elevation for a DTM, greens for a DSM, when QGIS loads it."""

    _keep: list[_RasterPostProcessor] = []

    def __init__(self, kind: str) -> None:
        super().__init__()
        self.kind = kind

    def postProcessLayer(self, layer: Any, context: Any, feedback: Any) -> None:  # noqa: N802
        if not isinstance(layer, QgsRasterLayer):
            return
        if self.kind == "raster_mask":  # filled cells in orange, measured ones not drawn
            classes = [QgsPalettedRasterRenderer.Class(1, QColor(255, 127, 0, 200),
                                                       "DTM cell filled by interpolation"),
                       QgsPalettedRasterRenderer.Class(0, QColor(0, 0, 0, 0),
                                                       "DTM cell from ground points")]
            layer.setRenderer(QgsPalettedRasterRenderer(layer.dataProvider(), 1, classes))
            _reorder(layer, context)
            layer.triggerRepaint()
            return
        stats = layer.dataProvider().bandStatistics(1)
        lo, hi = float(stats.minimumValue), float(stats.maximumValue)
        ramp_name = "Spectral" if self.kind == "raster_dtm" else "Greens"
        ramp = QgsStyle.defaultStyle().colorRamp(ramp_name)
        shader = QgsColorRampShader(lo, hi, ramp)
        shader.classifyColorRamp(5, -1)
        raster_shader = QgsRasterShader()
        raster_shader.setRasterShaderFunction(shader)
        layer.setRenderer(QgsSingleBandPseudoColorRenderer(layer.dataProvider(), 1,
                                                            raster_shader))
        if self.kind == "raster_dtm":  # the terrain line of the Elevation Profile
            layer.elevationProperties().setEnabled(True)
        _reorder(layer, context)
        layer.triggerRepaint()

    @classmethod
    def create(cls, kind: str) -> _RasterPostProcessor:
        p = cls(kind)
        cls._keep.append(p)
        return p


def load_raster_on_completion(context: QgsProcessingContext, path: str, name: str,
                              output_name: str, kind: str) -> None:
    """Load raster ``path`` into the project when the algorithm ends, styled by ``kind``
    (``raster_dtm``, ``raster_dsm`` or ``raster_mask``)."""
    details = QgsProcessingContext.LayerDetails(name, context.project(), output_name,
                                                QgsProcessingUtils.LayerHint.Raster)
    details.setPostProcessor(_RasterPostProcessor.create(kind))
    context.addLayerToLoadOnCompletion(path, details)
