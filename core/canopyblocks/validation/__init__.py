"""canopyblocks.validation: residuals photon minus reference, statistics, orchestration."""

from __future__ import annotations

from .block_validation import ValidationResult, validate_atl08, validate_blocks
from .residuals import compute_residuals
from .stats import block_stats, error_stats

__all__ = [
    "ValidationResult",
    "validate_blocks",
    "validate_atl08",
    "compute_residuals",
    "block_stats",
    "error_stats",
]
