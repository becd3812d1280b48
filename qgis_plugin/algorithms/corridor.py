"""``canopyblocks:corridor``: block points -> one corridor polygon per block."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingFeedback,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterNumber,
)

from ..core_bridge import import_core
from ..layers import write_frame
from .base import SEED_001, CanopyBlocksAlgorithm, optional_number

__all__ = ["CorridorAlgorithm"]


class CorridorAlgorithm(CanopyBlocksAlgorithm):
    """Corridor polygons along the track, cut at the photon blocks' edges."""

    ALG_ID = "corridor"
    DISPLAY = "Block corridors"
    GROUP = "Validation"
    GROUP_ID = "validation"
    HELP = (
        "Draws a corridor of the given width along the track (the polyline through the block "
        "centres, per track and block length) and cuts it at the blocks' edges "
        "(s_start, s_end): one polygon per block, carrying track, length, block, s_start, "
        "s_end. These are the areas over which reference rasters are summarised.<br><br>"
        "Method: " + SEED_001 + " (2 m corridor: MABEL's footprint). Empty width: the "
        "footprint of the photons' sensor, known from the track ids (ICESat-2 beams 13 m, "
        "MABEL channels 2 m).<br>"
        "<b>Blocks</b>: output of 'Block canopy heights from photons' (metric CRS)."
    )

    INPUT = "INPUT"
    WIDTH = "WIDTH"
    OUTPUT = "OUTPUT"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.addParameter(QgsProcessingParameterFeatureSource(
            self.INPUT, "Blocks", [QgsProcessing.TypeVectorPoint]))
        self.addParameter(QgsProcessingParameterNumber(
            self.WIDTH, "Corridor width (m, full width; empty = the footprint of the photons' "
            "sensor: ICESat-2 13, MABEL 2)",
            type=QgsProcessingParameterNumber.Double, optional=True, minValue=0.001))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Corridors", type=QgsProcessing.TypeVectorPolygon))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        layers = import_core("canopyblocks.workflows.layers")
        blocks = self.source_frame(parameters, self.INPUT, context, feedback)
        progress.update(0.3, f"{len(blocks)} blocks read")
        width = optional_number(self, parameters, self.WIDTH, context)
        polys = layers.block_corridors(blocks, width=width)
        progress.update(0.7, "corridors drawn")
        dest = write_frame(self, parameters, self.OUTPUT, context, polys, feedback)
        return {self.OUTPUT: dest}
