"""``canopyblocks:flashdualfootprints``: flash-lidar (ESFL) cubes or dual-wavelength
waveform pairs -> footprints layer (the flash-lidar and dual-wavelength papers' chains)."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFile,
    QgsProcessingParameterNumber,
)

from ..core_bridge import import_core
from ..layers import write_frame
from ..styles import style_on_load
from .base import CanopyBlocksAlgorithm, input_label, optional_number

__all__ = ["FlashDualFootprintsAlgorithm"]

NOISE_FITS = ("ml", "lsq")
DUAL_METHODS = ("paper", "refined")


class FlashDualFootprintsAlgorithm(CanopyBlocksAlgorithm):
    """Terrain and canopy height from flash-lidar cubes or dual-wavelength pairs."""

    ALG_ID = "flashdualfootprints"
    DISPLAY = "Flash-lidar and dual-wavelength footprints"
    GROUP = "Full-waveform lidar"
    GROUP_ID = "waveforms"
    HELP = (
        "Reads a flash-lidar (ESFL) cubes file or a dual-wavelength waveform pairs file (as "
        "'Simulate waveforms' writes them; the kind is told from the file) and processes "
        "it the way its paper does.<br>"
        "Flash lidar: per footprint the pixels of the 4 x 4 region whose energy reaches "
        "the energy fraction of the brightest, merged into one waveform per 5 m grid cell; "
        "noise from each waveform's histogram, signal above mean + 4 sd; terrain = the "
        "lowest Gaussian, top = the highest sample above noise; the outlier rule and a "
        "curvature filter of the terrain; height = top - terrain.<br>"
        "Dual wavelength: the visible / near-infrared ratio finds the ground start; ground "
        "= the centre of the ground return, tree height = first return to ground start."
        "<br>The layer is PointZ at the ground in the file's CRS (ground, top, height, "
        "flag), styled by height; heights stay in the tiles' vertical datum. The optional "
        "pixels layer holds the pixels each flash-lidar row merges (what lies under them "
        "is its reference in validation)."
    )

    INPUT = "INPUT"
    FRACTION = "FRACTION"
    CELL = "CELL"
    NOISE_THRESHOLD = "NOISE_THRESHOLD"
    NOISE_FIT = "NOISE_FIT"
    DUAL_METHOD = "DUAL_METHOD"
    OUTPUT = "OUTPUT"
    PIXELS = "PIXELS"
    ADVANCED = ("CELL", "NOISE_THRESHOLD", "NOISE_FIT", "DUAL_METHOD")

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.addParameter(QgsProcessingParameterFile(
            self.INPUT, "Flash-lidar cubes or dual-wavelength pairs (HDF5)",
            behavior=QgsProcessingParameterFile.File,
            fileFilter="HDF5 (*.h5 *.hdf5);;All files (*.*)"))
        self.addParameter(QgsProcessingParameterNumber(
            self.FRACTION, "Flash lidar: energy fraction of the brightest pixel (f)",
            type=QgsProcessingParameterNumber.Double, defaultValue=0.5, minValue=0.01,
            maxValue=1.0))
        self.addParameter(QgsProcessingParameterNumber(
            self.CELL, "Flash lidar: grid cell, m (0: one waveform per footprint)",
            type=QgsProcessingParameterNumber.Double, defaultValue=5.0, minValue=0.0))
        self.addParameter(QgsProcessingParameterNumber(
            self.NOISE_THRESHOLD, "Signal threshold, noise sd above the noise mean",
            type=QgsProcessingParameterNumber.Double, defaultValue=4.0, minValue=0.1))
        self.addParameter(QgsProcessingParameterEnum(
            self.NOISE_FIT, "Flash lidar: noise fit to the histogram",
            options=["maximum likelihood (ml)", "least squares (lsq)"], defaultValue=0))
        self.addParameter(QgsProcessingParameterEnum(
            self.DUAL_METHOD, "Dual wavelength: method",
            options=["the paper's steps (paper)", "refined"], defaultValue=0))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Footprints", type=QgsProcessing.TypeVectorPoint))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.PIXELS, "Flash-lidar pixels", type=QgsProcessing.TypeVectorPoint,
            optional=True, createByDefault=False))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        sniff = import_core("canopyblocks.workflows.inputs")
        wf = import_core("canopyblocks.workflows.waveforms_flash_dual")
        path = self.parameterAsFile(parameters, self.INPUT, context)
        product = sniff.waveform_product(path)
        if product == "GEDI L1B":
            raise QgsProcessingException(f"{path} is GEDI L1B: use 'GEDI footprints from "
                                         "L1B waveforms'")
        fraction = optional_number(self, parameters, self.FRACTION, context)
        cell = optional_number(self, parameters, self.CELL, context)
        k = optional_number(self, parameters, self.NOISE_THRESHOLD, context)
        fit = NOISE_FITS[self.parameterAsEnum(parameters, self.NOISE_FIT, context)]
        method = DUAL_METHODS[self.parameterAsEnum(parameters, self.DUAL_METHOD, context)]
        if product == "ESFL":
            options = wf.SensorOptions(fraction=fraction, cell=cell, noise_fit=fit,
                                       noise_threshold=k)
        else:
            options = wf.SensorOptions(noise_threshold=k, dual_method=method)
        layers = wf.sensor_footprints(path, product, options=options,
                                      progress=progress.sub(0.0, 0.9))
        fp = layers["footprints"]
        flags = ", ".join(f"{f} {n}" for f, n in fp["flag"].value_counts().items())
        feedback.pushInfo(f"{len(fp)} {product} footprints ({flags})")
        dest = write_frame(self, parameters, self.OUTPUT, context, fp, feedback)
        style_on_load(context, dest, "height", "height",
                      name=f"{product} footprints - {input_label(path)}")
        out: dict[str, Any] = {self.OUTPUT: dest}
        if wf.LAYER_PIXELS in layers and parameters.get(self.PIXELS) is not None:
            import geopandas as gpd

            px = layers[wf.LAYER_PIXELS]
            pts = gpd.GeoDataFrame(px, geometry=gpd.points_from_xy(px["x"], px["y"]),
                                   crs=fp.crs)
            out[self.PIXELS] = write_frame(self, parameters, self.PIXELS, context, pts,
                                           feedback)
        return out
