"""``canopyblocks:footprintvalidation``: footprints vs airborne points (DESIGN 2.7, 4.10)."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingFeedback,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
)

from ..core_bridge import import_core
from ..layers import write_frame
from ..styles import style_on_load
from .base import CanopyBlocksAlgorithm, optional_number

__all__ = ["FootprintValidationAlgorithm"]


class FootprintValidationAlgorithm(CanopyBlocksAlgorithm):
    """GEDI (or simulated) footprints against the footprint-matched airborne reference."""

    ALG_ID = "footprintvalidation"
    DISPLAY = "Validate footprints against airborne lidar"
    GROUP = "Full-waveform lidar"
    GROUP_ID = "waveforms"
    HELP = (
        "Compares each footprint's ground, RH98, RH50 and cover with the airborne points "
        "under it formed into the waveform the sensor would record (a Gaussian footprint, "
        "22 m diameter for GEDI, weighted by point density; the returns' energy and the "
        "pulse) and read by the same algorithm: ground = its lowest mode, RH above it, "
        "cover from its energy. Residual = footprint minus reference "
        "(m); statistics per beam, aspect, slope and cover class. GEDI elevations are "
        "ellipsoidal: give the vertical offset N = h_GEDI - H_airborne (0 for simulated "
        "waveforms, which keep the tiles' heights)."
    )

    INPUT = "INPUT"
    POINTS = "POINTS"
    DIAMETER = "DIAMETER"
    OFFSET = "OFFSET"
    OUTPUT = "OUTPUT"
    STATS = "STATS"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.addParameter(QgsProcessingParameterFeatureSource(
            self.INPUT, "Footprints", [QgsProcessing.TypeVectorPoint]))
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.POINTS, "Airborne LAS/LAZ tiles", layerType=QgsProcessing.TypeFile))
        self.addParameter(QgsProcessingParameterNumber(
            self.DIAMETER, "Footprint diameter (m)", type=QgsProcessingParameterNumber.Double,
            defaultValue=22.0, minValue=1.0))
        self.addParameter(QgsProcessingParameterNumber(
            self.OFFSET, "Vertical offset N = h_footprint - H_reference (m; empty = none)",
            type=QgsProcessingParameterNumber.Double, optional=True))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Footprint residuals", type=QgsProcessing.TypeVectorPolygon))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.STATS, "Footprint statistics", type=QgsProcessing.TypeVector))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        layers = import_core("canopyblocks.workflows.layers")
        footprints = self.source_frame(parameters, self.INPUT, context, feedback)
        tiles = self.parameterAsFileList(parameters, self.POINTS, context)
        kwargs: dict[str, Any] = {}
        offset = optional_number(self, parameters, self.OFFSET, context)
        if offset is not None:
            kwargs["offset"] = offset
        result = layers.validate_footprint_layer(
            footprints, tiles, diameter=self.parameterAsDouble(parameters, self.DIAMETER,
                                                               context),
            progress=progress.sub(0.1, 0.9), **kwargs)
        dest = write_frame(self, parameters, self.OUTPUT, context, result.residuals, feedback)
        style_on_load(context, dest, "residual", "res_rh98", name="Footprint residuals - "
                      + self.source_name(parameters, self.INPUT, context))
        sdest = write_frame(self, parameters, self.STATS, context, result.stats, feedback)
        return {self.OUTPUT: dest, self.STATS: sdest}
