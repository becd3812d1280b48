"""``canopyblocks:validate``: blocks + reference rasters -> residual polygons and statistics."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
)

from ..core_bridge import import_core
from ..layers import write_frame
from ..styles import style_on_load
from .base import SEED_001, CanopyBlocksAlgorithm, optional_number

__all__ = ["ValidateAlgorithm", "raster_path"]


def raster_path(alg: Any, parameters: dict[str, Any], name: str,
                context: QgsProcessingContext) -> str:
    """The file behind a raster-layer parameter (GDAL-readable path)."""
    layer = alg.parameterAsRasterLayer(parameters, name, context)
    if layer is None:
        raise QgsProcessingException(alg.invalidRasterError(parameters, name))
    return layer.source()


class ValidateAlgorithm(CanopyBlocksAlgorithm):
    """Photon block metrics against reference rasters over per-block corridors."""

    ALG_ID = "validate"
    DISPLAY = "Validate blocks against reference rasters"
    GROUP = "Validation"
    GROUP_ID = "validation"
    HELP = (
        "For each block: draws its corridor polygon (width in metres), takes the mean DTM "
        "(reference ground), the maximum of the DSM-max (reference top) and of the DSM-90 "
        "cells touched by the polygon, the terrain slope and aspect (Horn) from the DTM, and "
        "the residuals photon minus reference for ground, top, Hmax and H90. The statistics "
        "table holds n, bias, RMSE, MAE, OLS slope/intercept and r^2 per block length and "
        "metric.<br><br>Method: " + SEED_001 + ", section 2.3.<br>"
        "Photon heights (ellipsoidal for ATL03/MABEL) and reference heights must share a "
        "vertical datum. When they differ give a geoid raster (N, metres above the ellipsoid: "
        "H = h - N) or a constant offset N = h_photon - H_reference (0 when both are known "
        "to be in the same datum, e.g. photons simulated from the reference cloud); a known "
        "mismatch without a conversion stops with an error."
    )

    INPUT = "INPUT"
    DTM = "DTM"
    DSM_MAX = "DSM_MAX"
    DSM_P90 = "DSM_P90"
    WIDTH = "WIDTH"
    OFFSET = "OFFSET"
    GEOID = "GEOID"
    SLOPE_THRESHOLD = "SLOPE_THRESHOLD"
    PHOTON_VCRS = "PHOTON_VCRS"
    OUTPUT = "OUTPUT"
    STATS = "STATS"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.addParameter(QgsProcessingParameterFeatureSource(
            self.INPUT, "Blocks", [QgsProcessing.TypeVectorPoint]))
        self.add_reference_parameters()
        self.addParameter(QgsProcessingParameterRasterLayer(
            self.GEOID, "Geoid undulation raster (optional)", optional=True))
        self.addParameter(QgsProcessingParameterString(
            self.PHOTON_VCRS, "Photons' vertical CRS (e.g. EPSG:4979 for ATL03/GEDI ellipsoid "
            "heights, EPSG:5703 for NAVD88; empty = what the blocks record)", optional=True))
        self.addParameter(QgsProcessingParameterNumber(
            self.SLOPE_THRESHOLD, "Slope below which the aspect class is 'flat' (degrees)",
            type=QgsProcessingParameterNumber.Double, defaultValue=2.0, minValue=0.0,
            maxValue=90.0))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Residuals", type=QgsProcessing.TypeVectorPolygon))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.STATS, "Statistics", type=QgsProcessing.TypeVector))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        pipeline = import_core("canopyblocks.validation.block_validation")
        blocks = self.source_frame(parameters, self.INPUT, context, feedback)
        progress.update(0.1, f"{len(blocks)} blocks read")
        kwargs: dict[str, Any] = {}
        offset = optional_number(self, parameters, self.OFFSET, context)
        if offset is not None:
            kwargs["offset"] = offset
        vcrs = self.parameterAsString(parameters, self.PHOTON_VCRS, context).strip()
        if vcrs:
            kwargs["photon_vertical_crs"] = vcrs
        if parameters.get(self.GEOID) not in (None, ""):
            kwargs["geoid"] = raster_path(self, parameters, self.GEOID, context)
        result = pipeline.validate_blocks(
            blocks,
            dtm=raster_path(self, parameters, self.DTM, context),
            dsm_max=raster_path(self, parameters, self.DSM_MAX, context),
            dsm_p90=raster_path(self, parameters, self.DSM_P90, context),
            width=self.parameterAsDouble(parameters, self.WIDTH, context),
            slope_threshold=self.parameterAsDouble(parameters, self.SLOPE_THRESHOLD, context),
            progress=progress.sub(0.1, 0.9), **kwargs)
        residuals, stats = result.residuals, result.stats
        dest = write_frame(self, parameters, self.OUTPUT, context, residuals, feedback)
        style_on_load(context, dest, "residual", "res_hmax")
        sdest = write_frame(self, parameters, self.STATS, context, stats, feedback)
        return {self.OUTPUT: dest, self.STATS: sdest}
