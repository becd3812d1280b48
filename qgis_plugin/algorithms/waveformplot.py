"""``canopyblocks:waveformplot``: plots of chosen GEDI shots (PNG files and an HTML view)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from qgis.core import (
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterString,
)

from ..core_bridge import import_core
from .base import CanopyBlocksAlgorithm
from .gedifootprints import SETTINGS, add_l1b_parameters

__all__ = ["WaveformPlotAlgorithm"]


class WaveformPlotAlgorithm(CanopyBlocksAlgorithm):
    """The waveform of chosen shots with noise, thresholds, modes, ground and RH."""

    ALG_ID = "waveformplot"
    DISPLAY = "Plot GEDI waveforms"
    GROUP = "Full-waveform lidar"
    GROUP_ID = "waveforms"
    HELP = (
        "Draws the received waveform of each chosen shot (shot numbers from the footprints "
        "layer's shot_number field) against elevation, with the noise mean, the front and "
        "back thresholds, the smoothed waveform, the modes, the ground (lowest mode), the "
        "signal top and bottom and RH25/50/75/98, as processed with the chosen L2A setting "
        "group. Writes one HTML page with every plot and its numbers, and a PNG per shot "
        "beside it."
    )

    INPUT = "INPUT"
    SHOTS = "SHOTS"
    SETTING = "SETTING"
    OUTPUT = "OUTPUT"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        add_l1b_parameters(self, self.INPUT, self.SETTING)
        self.addParameter(QgsProcessingParameterString(
            self.SHOTS, "Shot numbers (comma separated)"))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.OUTPUT, "Waveform view (HTML)", fileFilter="HTML (*.html)"))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        gedi = import_core("canopyblocks.readers.gedi")
        process = import_core("canopyblocks.waveforms.process")
        settings = import_core("canopyblocks.waveforms.settings")
        plots = import_core("canopyblocks.outputs.waveform_plot")
        path = self.parameterAsFile(parameters, self.INPUT, context)
        text = self.parameterAsString(parameters, self.SHOTS, context)
        try:
            wanted = {int(s) for s in text.replace(";", ",").split(",") if s.strip()}
        except ValueError:
            raise QgsProcessingException(
                f"shot numbers must be integers separated by commas; got {text!r}") from None
        if not wanted:
            raise QgsProcessingException("give at least one shot number")
        params = settings.WaveformParams(
            setting=SETTINGS[self.parameterAsEnum(parameters, self.SETTING, context)])
        details = []
        for batch in gedi.iter_gedi_l1b(path, progress=progress.sub(0.0, 0.8)):
            sn = batch.shot_number.astype("int64")
            for i in [k for k, s in enumerate(sn) if int(s) in wanted]:
                details.append(process.shot_details(batch, i, params))
        missing = wanted - {d.shot_number for d in details}
        if missing:
            raise QgsProcessingException(
                f"shot(s) {', '.join(map(str, sorted(missing)))} are not in {path}")
        out = Path(self.parameterAsFileOutput(parameters, self.OUTPUT, context))
        for d in details:
            plots.plot_waveform(d, out.with_name(f"{out.stem}_{d.shot_number}.png"))
        plots.waveform_html(details, out)
        feedback.pushInfo(f"{len(details)} waveform(s) -> {out}")
        return {self.OUTPUT: str(out)}
