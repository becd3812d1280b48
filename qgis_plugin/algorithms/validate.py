"""``canopyblocks:validate``: blocks + reference rasters -> residual polygons and statistics."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterMultipleLayers,
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


#: The REFERENCE menu's entries as the workflow names them, in the menu's order.
REFERENCES = ("corridor", "footprint")


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
    REFERENCE = "REFERENCE"
    POINTS = "POINTS"
    DIAMETER = "DIAMETER"
    OUTPUT = "OUTPUT"
    STATS = "STATS"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.addParameter(QgsProcessingParameterFeatureSource(
            self.INPUT, "Blocks", [QgsProcessing.TypeVectorPoint]))
        self.addParameter(QgsProcessingParameterEnum(
            self.REFERENCE, "Reference", options=[
                "corridor: corridor statistics of the DTM and DSMs (as in the paper)",
                "footprint: the footprint-matched reference, Gaussian-weighted airborne "
                "points in each footprint (needs the LAS/LAZ tiles)"], defaultValue=0))
        self.add_reference_parameters(optional=True)
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.POINTS, "Airborne LAS/LAZ tiles (footprint-matched reference)",
            QgsProcessing.TypeFile, optional=True))
        self.addParameter(QgsProcessingParameterNumber(
            self.DIAMETER, "Footprint diameter for the footprint-matched reference (m)",
            type=QgsProcessingParameterNumber.Double, defaultValue=13.0, minValue=0.5))
        self.addParameter(QgsProcessingParameterRasterLayer(
            self.GEOID, "Geoid undulation raster", optional=True))
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
        layers = import_core("canopyblocks.workflows.layers")
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
        rasters = {k: raster_path(self, parameters, k, context)
                   if parameters.get(k) not in (None, "") else None
                   for k in (self.DTM, self.DSM_MAX, self.DSM_P90)}
        result = layers.validate_block_layer(
            blocks, reference=REFERENCES[self.parameterAsEnum(parameters, self.REFERENCE,
                                                              context)],
            dtm=rasters[self.DTM], dsm_max=rasters[self.DSM_MAX],
            dsm_p90=rasters[self.DSM_P90],
            points=[str(f) for f in self.parameterAsFileList(parameters, self.POINTS, context)],
            diameter=self.parameterAsDouble(parameters, self.DIAMETER, context),
            width=optional_number(self, parameters, self.WIDTH, context),
            slope_threshold=self.parameterAsDouble(parameters, self.SLOPE_THRESHOLD, context),
            progress=progress.sub(0.1, 0.9), **kwargs)
        residuals, stats = result.residuals, result.stats
        dest = write_frame(self, parameters, self.OUTPUT, context, residuals, feedback)
        style_on_load(context, dest, "residual", "res_hmax",
                      name=f"Residuals - {self.source_name(parameters, self.INPUT, context)}")
        sdest = write_frame(self, parameters, self.STATS, context, stats, feedback)
        return {self.OUTPUT: dest, self.STATS: sdest}
