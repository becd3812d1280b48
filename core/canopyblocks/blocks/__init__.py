"""Block engine: canopy top, mean ground, Hmax and H90 per along-track block (DESIGN.md 1)."""

from __future__ import annotations

from .calibration import CalibrationResult, calibrate_cutoffs
from .engine import LABEL_OUTSIDE, compute_blocks
from .params import DEFAULT_CUTOFFS, BlockParams, default_cutoffs

__all__ = [
    "BlockParams",
    "DEFAULT_CUTOFFS",
    "default_cutoffs",
    "compute_blocks",
    "LABEL_OUTSIDE",
    "calibrate_cutoffs",
    "CalibrationResult",
]
