"""``canopyblocks:simulate``: ICESat-2-like photons from airborne lidar (seed 002)."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsCoordinateTransform,
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
)

from ..core_bridge import import_core
from ..layers import qgs_crs, write_frame
from ..styles import style_on_load
from .base import SEED_002, CanopyBlocksAlgorithm, input_label, las_files, table_choices

__all__ = ["SimulateAlgorithm", "track_vertices", "add_tiles_and_track_parameters"]

BEAMS = ("strong", "weak")


class SimulateAlgorithm(CanopyBlocksAlgorithm):
    """Photons along a track over an airborne point cloud, written as an ATL03-layout file."""

    ALG_ID = "simulate"
    DISPLAY = "Simulate ICESat-2 photons from airborne lidar"
    GROUP = "Simulation"
    GROUP_ID = "simulation"
    HELP = (
        "Footprints every 0.7 m along a track over an airborne point cloud; the points within "
        "a footprint, weighted exp(-2 r^2 / R^2) and broadened by the 0.25 m point-spread, form "
        "a height distribution from which a Poisson number of photons per shot is drawn "
        "(boreal 1.0, temperate 1.9, tropical 0.6 per strong-beam shot). Solar background "
        "noise (MHz, the same for both beams) falls uniformly in a 200 m window around the "
        "airborne ground smoothed over 1 km. Truth (ground, top, "
        "RH metrics, canopy cover) is kept per photon. Output: an ATL03-layout HDF5 file that "
        "'Block canopy heights from photons' reads, and optionally the photons as points.<br>"
        "<br>Method: " + SEED_002 + ".<br>"
        "<b>Track</b>: the first line of the track layer, or else a straight line through the "
        "middle of the point cloud at the given azimuth (degrees clockwise from grid north)."
    )

    INPUT = "INPUT"
    TRACK_LINE = "TRACK_LINE"
    AZIMUTH = "AZIMUTH"
    DIAMETER = "DIAMETER"
    PHOTON_RATE = "PHOTON_RATE"
    BEAM = "BEAM"
    BACKGROUND_RATE = "BACKGROUND_RATE"
    SEED = "SEED"
    OUTPUT = "OUTPUT"
    PHOTONS = "PHOTONS"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        add_tiles_and_track_parameters(self)
        self.addParameter(QgsProcessingParameterNumber(
            self.DIAMETER, "Footprint diameter (m; 13 start, 17 end of mission)",
            type=QgsProcessingParameterNumber.Double, defaultValue=13.0, minValue=0.1))
        rates, default = table_choices("--photon-rate")
        self.addParameter(QgsProcessingParameterEnum(
            self.PHOTON_RATE, "Ecosystem photon rate", options=list(rates),
            defaultValue=default))
        self.addParameter(QgsProcessingParameterEnum(
            self.BEAM, "Beam", options=list(BEAMS), defaultValue=0))
        self.addParameter(QgsProcessingParameterNumber(
            self.BACKGROUND_RATE,
            "Background noise rate (MHz; 0 off, night ~0.15, day ~3)",
            type=QgsProcessingParameterNumber.Double, defaultValue=0.0, minValue=0.0))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.OUTPUT, "Simulated photons (ATL03 layout)", fileFilter="HDF5 (*.h5)"))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.PHOTONS, "Simulated photons with truth",
            type=QgsProcessing.TypeVectorPoint, optional=True,
            createByDefault=False))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        params_mod = import_core("canopyblocks.workflows.params")
        workflow = import_core("canopyblocks.workflows.simulate")
        inputs = import_core("canopyblocks.workflows.inputs")
        files = las_files(self, parameters, self.INPUT, context)
        params = params_mod.SimParams(
            diameter=self.parameterAsDouble(parameters, self.DIAMETER, context),
            photon_rate=self._photon_rate(parameters, context),
            beam=BEAMS[self.parameterAsEnum(parameters, self.BEAM, context)],
            background_rate_mhz=self.parameterAsDouble(parameters, self.BACKGROUND_RATE,
                                                       context))
        out = self.parameterAsFileOutput(parameters, self.OUTPUT, context)
        sim = workflow.simulate_photon_file(
            files, out, params,
            vertices=track_vertices(self, parameters, self.TRACK_LINE, context,
                                    inputs.las_crs(files[0])),
            azimuth=self.parameterAsDouble(parameters, self.AZIMUTH, context),
            seed=self.parameterAsInt(parameters, self.SEED, context), progress=progress)
        results: dict[str, Any] = {self.OUTPUT: out}
        if parameters.get(self.PHOTONS) is not None:
            photons = sim.photon_track().to_geodataframe()
            results[self.PHOTONS] = write_frame(self, parameters, self.PHOTONS, context,
                                                photons, feedback)
            style_on_load(context, results[self.PHOTONS], "truth", "noise",
                          name=f"Simulated photons - {input_label(out)}")
        return results

    def _photon_rate(self, parameters: dict[str, Any], context: QgsProcessingContext) -> str:
        """PHOTON_RATE's name; a model saved with the old parameter name PRESET still runs
        (with a warning in the log)."""
        rates = table_choices("--photon-rate")[0]
        if "PRESET" in parameters and self.PHOTON_RATE not in parameters:
            import warnings

            from ..core_bridge import import_core
            warnings.warn("the parameter PRESET is deprecated and will be removed; use "
                          "PHOTON_RATE", import_core("canopyblocks.errors")
                          .CanopyBlocksDeprecationWarning, stacklevel=2)
            return rates[self.parameterAsEnum(parameters, "PRESET", context)]
        return rates[self.parameterAsEnum(parameters, self.PHOTON_RATE, context)]


def add_tiles_and_track_parameters(alg: Any) -> None:
    """INPUT (LAS/LAZ files), TRACK_LINE (optional line layer), AZIMUTH and SEED: the
    parameters every simulation algorithm shares."""
    alg.addParameter(QgsProcessingParameterMultipleLayers(
        "INPUT", "Airborne LAS/LAZ files (one metric CRS)", QgsProcessing.TypeFile))
    alg.addParameter(QgsProcessingParameterFeatureSource(
        "TRACK_LINE", "Track line", [QgsProcessing.TypeVectorLine], optional=True))
    alg.addParameter(QgsProcessingParameterNumber(
        "AZIMUTH", "Track azimuth when no line is given (degrees from north)",
        type=QgsProcessingParameterNumber.Double, defaultValue=0.0, minValue=-360.0,
        maxValue=360.0))
    alg.addParameter(QgsProcessingParameterNumber(
        "SEED", "Random seed", type=QgsProcessingParameterNumber.Integer, defaultValue=0,
        minValue=0))


def track_vertices(alg: Any, parameters: dict[str, Any], name: str,
                   context: QgsProcessingContext, crs: Any) -> list[tuple[float, float]] | None:
    """The first line of the optional line-layer parameter ``name`` as (x, y) vertices in
    ``crs`` (the tiles' metric CRS, pyproj); None when no layer is given."""
    source = alg.parameterAsSource(parameters, name, context)
    if source is None:
        return None
    feat = next(iter(source.getFeatures()), None)
    if feat is None or feat.geometry().isNull():
        raise QgsProcessingException("the track layer holds no line")
    geom = feat.geometry()
    target = qgs_crs(crs)
    if source.sourceCrs().isValid() and target.isValid() and source.sourceCrs() != target:
        geom.transform(QgsCoordinateTransform(source.sourceCrs(), target,
                                              context.transformContext()))
    line = geom.asMultiPolyline()[0] if geom.isMultipart() else geom.asPolyline()
    return [(p.x(), p.y()) for p in line]
