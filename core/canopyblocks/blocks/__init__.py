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
    "Estimators",
    "PRESETS",
    "preset",
    "estimate_blocks",
]


# estimators pull in scipy.stats (the density filter): imported on first use
_LAZY = {"Estimators": ".estimators", "PRESETS": ".estimators", "preset": ".estimators",
         "estimate_blocks": ".estimators"}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
