"""``canopyblocks:calibrate``: fit the expansion-window cut-offs to reference rasters."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingFeedback,
    QgsProcessingParameterFeatureSink,
)

from ..core_bridge import import_core
from ..layers import write_frame
from .base import SEED_001, CanopyBlocksAlgorithm, optional_number, parse_lengths
from .blockheights import parse_track
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
        "Use the fitted fractions in <i>Block canopy heights</i>.<br><br>"
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

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.add_photon_parameters(default_lengths="10, 25, 50")
        self.add_signal_conf_parameter()
        self.add_reference_parameters()
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Calibrated cut-offs", type=QgsProcessing.TypeVector))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        blocks_mod = import_core("canopyblocks.blocks")
        calibration = import_core("canopyblocks.validation.calibration")
        params = blocks_mod.BlockParams(
            lengths=parse_lengths(self.parameterAsString(parameters, self.LENGTHS, context)),
            min_signal_conf=self.min_signal_conf(parameters, context))
        track = parse_track(self.parameterAsString(parameters, self.TRACK, context))
        offset = optional_number(self, parameters, self.OFFSET, context)
        cal = calibration.calibrate_reference_rasters(
            self.parameterAsFile(parameters, self.INPUT, context), params,
            dtm=raster_path(self, parameters, self.DTM, context),
            dsm_max=raster_path(self, parameters, self.DSM_MAX, context),
            dsm_p90=raster_path(self, parameters, self.DSM_P90, context),
            width=self.parameterAsDouble(parameters, self.WIDTH, context),
            beam=track.get("beam"), channel=track.get("channel"), offset=offset,
            progress=progress.sub(0.0, 0.95))
        for row in cal.table.itertuples():
            feedback.pushInfo(
                f"{row.length:g} m: top {row.top_cutoff:.3f}, ground {row.ground_cutoff:.3f}; "
                f"held-out Hmax RMSE {row.rmse_hmax_default:.2f} -> "
                f"{row.rmse_hmax_calibrated:.2f} m")
        dest = write_frame(self, parameters, self.OUTPUT, context, cal.table, feedback)
        return {self.OUTPUT: dest}
