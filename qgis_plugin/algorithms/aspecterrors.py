"""``canopyblocks:aspecterrors``: residual layer -> error statistics per aspect/slope class."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingFeedback,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
)

from ..core_bridge import import_core
from ..layers import write_frame
from ..styles import style_on_load
from .base import SEED_001, CanopyBlocksAlgorithm

__all__ = ["AspectErrorsAlgorithm"]

#: (menu label, groups argument of canopyblocks.validation.stats.block_stats)
GROUPINGS = (
    ("aspect class", (("aspect", "aspect_class"),)),
    ("slope class", (("slope", "slope_class"),)),
    ("aspect and slope class", (("aspect", "aspect_class"), ("slope", "slope_class"))),
)


class AspectErrorsAlgorithm(CanopyBlocksAlgorithm):
    """Aspect-grouped (or slope-grouped) error statistics of validated blocks."""

    ALG_ID = "aspecterrors"
    DISPLAY = "Errors by terrain aspect and slope"
    GROUP = "Validation"
    GROUP_ID = "validation"
    HELP = (
        "Groups the validated blocks (output 'Residuals' of 'Validate blocks against reference "
        "rasters') by terrain aspect class (N, NE, ..., NW, flat below the slope threshold) "
        "and/or slope class (degrees) and computes n, bias, RMSE, MAE, OLS slope/intercept "
        "and r^2 per block length, metric and class (group 'aspect:E', 'slope:5-10', ...), "
        "plus the 'all' group; only blocks flagged usable (photon flag ok and reference ok) "
        "count. A second output maps the usable blocks (their corridor polygons) coloured "
        "by aspect class, with their residuals as attributes.<br><br>"
        "Method: " + SEED_001 + " (largest errors were found on easterly aspects)."
    )

    INPUT = "INPUT"
    GROUP_BY = "GROUP_BY"
    OUTPUT = "OUTPUT"
    MAP = "MAP"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.addParameter(QgsProcessingParameterFeatureSource(
            self.INPUT, "Residuals", [QgsProcessing.TypeVector]))
        self.addParameter(QgsProcessingParameterEnum(
            self.GROUP_BY, "Group by", options=[g[0] for g in GROUPINGS],
            defaultValue=0))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Statistics per class", type=QgsProcessing.TypeVector))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.MAP, "Blocks by aspect class (map)", type=QgsProcessing.TypeVectorPolygon,
            optional=True, createByDefault=True))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        layers = import_core("canopyblocks.workflows.layers")
        residuals = self.source_frame(parameters, self.INPUT, context, feedback)
        groups = GROUPINGS[self.parameterAsEnum(parameters, self.GROUP_BY, context)][1]
        progress.update(0.3, f"{len(residuals)} blocks read")
        stats, used = layers.aspect_statistics(residuals, groups)
        dest = write_frame(self, parameters, self.OUTPUT, context, stats, feedback)
        results: dict[str, Any] = {self.OUTPUT: dest}
        if parameters.get(self.MAP) is not None and "aspect_class" in residuals.columns:
            keep = [c for c in ("track", "length", "block", "aspect_class", "aspect", "slope",
                                "slope_class", "res_ground", "res_top", "res_hmax", "res_h90",
                                "use", "geometry") if c in residuals.columns]
            mdest = write_frame(self, parameters, self.MAP, context, used[keep], feedback)
            style_on_load(context, mdest, "aspect", "aspect_class", name="Errors by aspect - "
                          + self.source_name(parameters, self.INPUT, context))
            results[self.MAP] = mdest
        return results
