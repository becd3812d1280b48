"""canopyblocks.validation: residuals photon minus reference, statistics, co-registration,
bias calibration and the file-level orchestration of validation."""

from __future__ import annotations

from .bias_calibration import (
    BiasCalibration,
    BiasModel,
    apply_bias_calibration,
    fit_bias_calibration,
    read_bias_calibration,
    write_bias_calibration,
)
from .bias_calibration_files import calibrate_bias_file
from .block_validation import ValidationResult, validate_atl08, validate_blocks
from .coregistration import CoregOffset, CoregParams, CoregResult, coregister
from .coregistration_files import coregister_file, write_offsets
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
    validate_footprints_file,
)
from .residuals import compute_residuals
from .stats import block_stats, error_stats
from .validation_files import FileValidation, validate_file

__all__ = [
    "ValidationResult",
    "validate_blocks",
    "validate_atl08",
    "compute_residuals",
    "block_stats",
    "error_stats",
    "FileValidation",
    "validate_file",
    "FootprintValidation",
    "FootprintOutsideWarning",
    "validate_footprints",
    "validate_footprints_file",
    "validate_blocks_footprint",
    "CoregParams",
    "CoregOffset",
    "CoregResult",
    "CoregTargets",
    "coregister",
    "coregister_file",
    "write_offsets",
    "apply_offset",
    "targets_from_photons",
    "targets_from_table",
    "BiasModel",
    "BiasCalibration",
    "fit_bias_calibration",
    "apply_bias_calibration",
    "read_bias_calibration",
    "write_bias_calibration",
    "calibrate_bias_file",
]
