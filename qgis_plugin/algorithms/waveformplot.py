"""``canopyblocks:waveformplot``: plots of chosen GEDI shots (PNG files and an HTML view)."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsFeatureRequest,
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
    QgsProcessingOutputMultipleLayers,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterString,
)

from ..core_bridge import import_core
from .base import CanopyBlocksAlgorithm
from .gedifootprints import SETTINGS, add_l1b_parameters, gedi_file

__all__ = ["WaveformPlotAlgorithm"]


class WaveformPlotAlgorithm(CanopyBlocksAlgorithm):
    """The waveform of chosen shots with noise, thresholds, modes, ground and RH."""

    ALG_ID = "waveformplot"
    DISPLAY = "Plot GEDI waveforms"
    GROUP = "Full-waveform lidar"
    GROUP_ID = "waveforms"
    HELP = (
        "Draws the received waveform of each chosen shot against elevation, with the noise mean, the front and "
        "back thresholds, the smoothed waveform, the modes, the ground (lowest mode), the "
        "signal top and bottom and RH25/50/75/98, as processed with the chosen L2A setting "
        "group. Writes one HTML page with every plot and its numbers, and a PNG per shot "
        "beside it.<br><br>"
        "<b>Footprints</b>: select the footprints on the map (a layer from 'GEDI footprints "
        "from L1B waveforms') and tick 'Selected features only'; their shot_number field "
        "says which shots to draw. Or type shot numbers instead."
    )

    INPUT = "INPUT"
    FOOTPRINTS = "FOOTPRINTS"
    SHOTS = "SHOTS"
    PLOTS = "PLOTS"
    ADVANCED = ("SHOTS",)
    SETTING = "SETTING"
    OUTPUT = "OUTPUT"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        add_l1b_parameters(self, self.INPUT, self.SETTING)
        self.addParameter(QgsProcessingParameterFeatureSource(
            self.FOOTPRINTS, "Footprints (their shot_number; selected features only)",
            [QgsProcessing.TypeVectorPoint], optional=True))
        self.addParameter(QgsProcessingParameterString(
            self.SHOTS, "Shot numbers, comma separated (instead of footprints)",
            optional=True))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.OUTPUT, "Waveform view (HTML)", fileFilter="HTML (*.html)"))
        self.addOutput(QgsProcessingOutputMultipleLayers(
            self.PLOTS, "Waveform plots (one PNG per shot)"))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        layers = import_core("canopyblocks.workflows.layers")
        path = gedi_file(self.parameterAsFile(parameters, self.INPUT, context))
        out, pngs = layers.waveform_views(
            path, self._shots(parameters, context),
            self.parameterAsFileOutput(parameters, self.OUTPUT, context),
            setting=SETTINGS[self.parameterAsEnum(parameters, self.SETTING, context)],
            progress=progress)
        feedback.pushInfo(f"{len(pngs)} waveform(s) -> {out} and {len(pngs)} PNG file(s)")
        return {self.OUTPUT: str(out), self.PLOTS: pngs}

    def _shots(self, parameters: dict[str, Any], context: QgsProcessingContext) -> set[int]:
        """The shot numbers of the (selected) footprints, else of the typed list."""
        wanted: set[int] = set()
        if parameters.get(self.FOOTPRINTS) not in (None, ""):
            source = self.parameterAsSource(parameters, self.FOOTPRINTS, context)
            if source is None:
                raise QgsProcessingException(
                    self.invalidSourceError(parameters, self.FOOTPRINTS))
            idx = source.fields().indexOf("shot_number")
            if idx < 0:
                raise QgsProcessingException(
                    f"the footprints layer {source.sourceName()} has no shot_number field; "
                    "use a layer from 'GEDI footprints from L1B waveforms'")
            request = QgsFeatureRequest().setSubsetOfAttributes([idx])
            request.setFlags(QgsFeatureRequest.NoGeometry)
            wanted = {int(f.attributes()[idx]) for f in source.getFeatures(request)
                      if f.attributes()[idx] is not None}
        text = self.parameterAsString(parameters, self.SHOTS, context) or ""
        try:
            wanted |= {int(s) for s in text.replace(";", ",").split(",") if s.strip()}
        except ValueError:
            raise QgsProcessingException(
                f"shot numbers must be integers separated by commas; got {text!r}") from None
        if not wanted:
            raise QgsProcessingException(
                "choose footprints (select them on the map and tick 'Selected features "
                "only') or type shot numbers")
        if len(wanted) > 200:
            raise QgsProcessingException(
                f"{len(wanted)} shots chosen; select at most 200 footprints to plot")
        return wanted
