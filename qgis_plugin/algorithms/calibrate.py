"""``canopyblocks:calibrate``: fit the expansion-window cut-offs to reference rasters."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingFeedback,
    QgsProcessingOutputFile,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFileDestination,
)

from ..core_bridge import import_core
from ..layers import write_frame
from .base import SEED_001, CanopyBlocksAlgorithm, optional_number, parse_lengths
from .blockheights import parse_track, preset_options
from .validate import raster_path

__all__ = ["CalibrateAlgorithm"]


class CalibrateAlgorithm(CanopyBlocksAlgorithm):
    """Cut-off fractions that best reproduce the reference top and ground, per length."""

    ALG_ID = "calibrate"
    DISPLAY = "Calibrate cut-offs against reference rasters"
    GROUP = "Validation"
    GROUP_ID = "validation"
    HELP = (
        "Computes the blocks of one photon track with the paper's cut-offs, takes each "
        "block's reference top (maximum of the DSM) and ground (mean of the DTM) inside its "
        "corridor, and searches the canopy-top and ground fractions (2.5 % to 50 %) that "
        "reproduce them best, per block length. The table's RMSE columns are held out: "
        "cut-offs fitted on the even blocks are scored on the odd blocks and vice versa. "
        "Use the fitted fractions in <i>Block canopy heights</i> with the paper's method. "
        "The bias method instead fits a correction of Hmax and H90 for the chosen estimators "
        "(default atl08, the recommended ones). The corridor width defaults to the footprint "
        "of the photons' sensor (ICESat-2 13 m, MABEL 2 m).<br><br>"
        "Method: " + SEED_001 + " (the authors chose their cut-offs by matching clear "
        "blocks to the airborne lidar). Photon and reference heights must share a vertical "
        "datum: give the offset N = h_photon - H_reference when they do not."
    )

    INPUT = "INPUT"
    TRACK = "TRACK"
    LENGTHS = "LENGTHS"
    MIN_SIGNAL_CONF = "MIN_SIGNAL_CONF"
    DTM = "DTM"
    DSM_MAX = "DSM_MAX"
    DSM_P90 = "DSM_P90"
    WIDTH = "WIDTH"
    OFFSET = "OFFSET"
    OUTPUT = "OUTPUT"
    METHOD = "METHOD"
    PRESET = "PRESET"
    CALIBRATION = "CALIBRATION"
    CALIBRATION_TABLE = "CALIBRATION_TABLE"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.add_photon_parameters(default_lengths="10, 25, 50")
        self.add_signal_conf_parameter()
        self.add_reference_parameters()
        self.addParameter(QgsProcessingParameterEnum(
            self.METHOD, "Method", options=[
                "cut-offs: the paper's top/ground cut-offs per length",
                "bias: a correction of Hmax and H90 per length and beam strength for the "
                "chosen estimators (applied by Block canopy heights)"], defaultValue=0))
        self.addParameter(QgsProcessingParameterEnum(
            self.PRESET, "Estimators (bias method)",
            options=[label for label, _ in preset_options()[0]],
            defaultValue=preset_options()[1]))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Calibration table", type=QgsProcessing.TypeVector))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.CALIBRATION, "Bias calibration file (bias method)",
            fileFilter="Calibration (*.json)", optional=True, createByDefault=False))
        self.addOutput(QgsProcessingOutputFile(
            self.CALIBRATION_TABLE, "Bias calibration summary (CSV beside the file)"))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        blocks_mod = import_core("canopyblocks.workflows.params")
        calibration = import_core("canopyblocks.workflows.calibrate")
        params = blocks_mod.BlockParams(
            lengths=parse_lengths(self.parameterAsString(parameters, self.LENGTHS, context)),
            min_signal_conf=self.min_signal_conf(parameters, context))
        track = parse_track(self.parameterAsString(parameters, self.TRACK, context))
        offset = optional_number(self, parameters, self.OFFSET, context)
        if self.parameterAsEnum(parameters, self.METHOD, context) == 1:
            return self._bias(parameters, context, feedback, progress, params, track, offset)
        cal = calibration.calibrate_reference_rasters(
            self.parameterAsFile(parameters, self.INPUT, context), params,
            dtm=raster_path(self, parameters, self.DTM, context),
            dsm_max=raster_path(self, parameters, self.DSM_MAX, context),
            dsm_p90=raster_path(self, parameters, self.DSM_P90, context),
            width=optional_number(self, parameters, self.WIDTH, context),
            beam=track.get("beam"), channel=track.get("channel"), offset=offset,
            progress=progress.sub(0.0, 0.95))
        for row in cal.table.itertuples():
            feedback.pushInfo(
                f"{row.length:g} m: top {row.top_cutoff:.3f}, ground {row.ground_cutoff:.3f}; "
                f"held-out Hmax RMSE {row.rmse_hmax_default:.2f} -> "
                f"{row.rmse_hmax_calibrated:.2f} m")
        dest = write_frame(self, parameters, self.OUTPUT, context, cal.table, feedback)
        return {self.OUTPUT: dest}

    def _bias(self, parameters: dict[str, Any], context: QgsProcessingContext,
              feedback: QgsProcessingFeedback, progress: Any, params: Any,
              track: dict[str, Any], offset: float | None) -> dict[str, Any]:
        """The bias method: one core call, the table as a layer, the JSON as a file."""
        files = import_core("canopyblocks.workflows.calibrate")
        est_mod = import_core("canopyblocks.workflows.params")
        name = preset_options()[0][self.parameterAsEnum(parameters, self.PRESET, context)][1]
        cal = files.calibrate_bias_file(
            self.parameterAsFile(parameters, self.INPUT, context), params,
            est_mod.preset(name),
            dtm=raster_path(self, parameters, self.DTM, context),
            dsm_max=raster_path(self, parameters, self.DSM_MAX, context),
            dsm_p90=raster_path(self, parameters, self.DSM_P90, context),
            width=optional_number(self, parameters, self.WIDTH, context),
            beams=[track["beam"]] if track.get("beam") else (),
            channel=track.get("channel"), offset=offset, progress=progress.sub(0.0, 0.95))
        table = cal.table()
        for row in table.itertuples():
            feedback.pushInfo(
                f"{row.metric} {row.length:g} m {row.strength}: {row.slope:.3f} x + "
                f"{row.intercept:+.2f} m; held-out RMSE {row.holdout_rmse_before:.2f} -> "
                f"{row.holdout_rmse_after:.2f} m (n={row.n})")
        results: dict[str, Any] = {
            self.OUTPUT: write_frame(self, parameters, self.OUTPUT, context, table, feedback)}
        if parameters.get(self.CALIBRATION) not in (None, ""):
            path = self.parameterAsFileOutput(parameters, self.CALIBRATION, context)
            files.write_bias_calibration(cal, path)
            results[self.CALIBRATION] = path
            # the summary table written beside the JSON
            results[self.CALIBRATION_TABLE] = str(Path(path).with_suffix(".csv"))
        return results

