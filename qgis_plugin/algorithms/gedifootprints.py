"""``canopyblocks:gedifootprints``: GEDI L1B waveforms -> footprints layer (DESIGN 4)."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingFeedback,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFile,
    QgsProcessingParameterString,
)

from ..core_bridge import import_core
from ..layers import write_frame
from ..styles import style_on_load
from .base import CanopyBlocksAlgorithm

__all__ = ["GediFootprintsAlgorithm", "SETTINGS", "GEDI_FILTER", "add_l1b_parameters"]

SETTINGS = ("a1", "a2", "a3", "a4", "a5", "a6")
GEDI_FILTER = "GEDI HDF5 (*.h5 *.hdf5);;All files (*.*)"


def add_l1b_parameters(alg: Any, file_name: str, setting_name: str) -> None:
    """The GEDI L1B file and L2A setting-group parameters (shared by the algorithms)."""
    alg.addParameter(QgsProcessingParameterFile(
        file_name, "GEDI L1B file", behavior=QgsProcessingParameterFile.File,
        fileFilter=GEDI_FILTER))
    alg.addParameter(QgsProcessingParameterEnum(
        setting_name, "L2A setting group", options=list(SETTINGS), defaultValue=0))


class GediFootprintsAlgorithm(CanopyBlocksAlgorithm):
    """Ground, canopy top, RH metrics and cover per GEDI footprint from L1B waveforms."""

    ALG_ID = "gedifootprints"
    DISPLAY = "GEDI footprints from L1B waveforms"
    GROUP = "Full-waveform lidar"
    GROUP_ID = "waveforms"
    HELP = (
        "Reads the received waveforms of a GEDI L1B file (every beam, or the beams named) "
        "and processes them with GEDI L2A's algorithm (setting group a1-a6): signal top and "
        "bottom, modes, ground = lowest mode, RH25-RH100 from the cumulative energy, canopy "
        "cover and penetration, and the seed-003 terrain filter. On the bundled real shots "
        "it reproduces L2A a1 ground and RH98 to about 0.01 m RMSE. Elevations are heights "
        "above the WGS84 ellipsoid; the layer is PointZ at the ground in the UTM zone of "
        "the footprints, styled by RH98. With an L2A file of the same shots, its values and "
        "the differences are added (joined by shot number)."
    )

    INPUT = "INPUT"
    BEAMS = "BEAMS"
    SETTING = "SETTING"
    DECOMPOSE = "DECOMPOSE"
    L2A = "L2A"
    OUTPUT = "OUTPUT"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        add_l1b_parameters(self, self.INPUT, self.SETTING)
        self.addParameter(QgsProcessingParameterString(
            self.BEAMS, "Beams (e.g. BEAM0101, BEAM0110; empty = all)", defaultValue="",
            optional=True))
        self.addParameter(QgsProcessingParameterBoolean(
            self.DECOMPOSE, "Also fit Gaussians (ground_gauss; much slower)",
            defaultValue=False))
        self.addParameter(QgsProcessingParameterFile(
            self.L2A, "GEDI L2A of the same shots (optional, for comparison)",
            behavior=QgsProcessingParameterFile.File, fileFilter=GEDI_FILTER, optional=True))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "GEDI footprints", type=QgsProcessing.TypeVectorPoint))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        wf = import_core("canopyblocks.waveform_footprints")
        settings = import_core("canopyblocks.waveforms.settings")
        path = self.parameterAsFile(parameters, self.INPUT, context)
        text = self.parameterAsString(parameters, self.BEAMS, context)
        beams = [b.strip() for b in text.replace(";", ",").split(",") if b.strip()] or None
        setting = SETTINGS[self.parameterAsEnum(parameters, self.SETTING, context)]
        params = settings.WaveformParams(
            setting=setting, decompose=self.parameterAsBool(parameters, self.DECOMPOSE,
                                                            context))
        footprints, _ = wf.footprints_from_l1b(path, beams=beams, params=params,
                                               progress=progress.sub(0.0, 0.9))
        l2a = self.parameterAsFile(parameters, self.L2A, context)
        if l2a:
            footprints, comparison = wf.compare_with_l2a(footprints, l2a, setting=setting)
            for row in comparison[comparison["beam"] == "all"].itertuples():
                feedback.pushInfo(f"vs L2A {row.metric}: n={row.n} bias={row.bias:+.3f} m "
                                  f"RMSE={row.rmse:.3f} m")
        dest = write_frame(self, parameters, self.OUTPUT, context, footprints, feedback)
        style_on_load(context, dest, "height", "rh98")
        return {self.OUTPUT: dest}
