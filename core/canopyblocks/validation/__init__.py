"""canopyblocks.validation: residuals photon minus reference, statistics, co-registration,
bias calibration.

Reading tracks and writing result files is the workflows' job (:mod:`canopyblocks.workflows`)."""

from __future__ import annotations

from .bias_calibration import (
    BiasCalibration,
    BiasModel,
    apply_bias_calibration,
    fit_bias_calibration,
    read_bias_calibration,
    write_bias_calibration,
)
from .block_validation import ValidationResult, validate_atl08, validate_blocks
from .coregistration import CoregParams, CoregResult, coregister
from .coregistration_offset import CoregOffset
from .coregistration_targets import (
    CoregTargets,
    apply_offset,
    targets_from_photons,
    targets_from_table,
)
from .footprints import (
    FootprintOutsideWarning,
    FootprintValidation,
    validate_blocks_footprint,
    validate_footprints,
)
from .residuals import compute_residuals
from .stats import block_stats, error_stats

__all__ = [
    "ValidationResult",
    "validate_blocks",
    "validate_atl08",
    "compute_residuals",
    "block_stats",
    "error_stats",
    "FootprintValidation",
    "FootprintOutsideWarning",
    "validate_footprints",
    "validate_blocks_footprint",
    "CoregParams",
    "CoregOffset",
    "CoregResult",
    "CoregTargets",
    "coregister",
    "apply_offset",
    "targets_from_photons",
    "targets_from_table",
    "BiasModel",
    "BiasCalibration",
    "fit_bias_calibration",
    "apply_bias_calibration",
    "read_bias_calibration",
    "write_bias_calibration",
]


def __getattr__(name: str) -> object:
    """Names that moved up to a workflow keep working here (see canopyblocks._aliases)."""
    from .._aliases import moved_name

    return moved_name(__name__, name)
