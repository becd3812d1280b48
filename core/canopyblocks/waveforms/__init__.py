"""Full-waveform lidar: GEDI L2A-style processing, Gaussian decomposition, cover,
the seed-003 terrain filter, flash-array and dual-wavelength methods (DESIGN section 4).

Every step works on a :class:`~canopyblocks.waveforms.batch.WaveformBatch` (shots x
samples), vectorised over shots.
"""

from __future__ import annotations

import importlib
from typing import Any

from .batch import WaveformBatch
from .details import ShotDetails
from .process import process_waveforms, shot_details
from .settings import SETTINGS, WaveformParams
from .terrain_filter import terrain_outliers

__all__ = [
    "WaveformBatch",
    "ShotDetails",
    "WaveformParams",
    "SETTINGS",
    "process_waveforms",
    "shot_details",
    "terrain_outliers",
]

# Steps in their own modules, imported on first use (they may pull in scipy.optimize).
_LAZY = {
    "decompose_waveforms": ".decompose",
    "estimate_noise": ".noise",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        module = importlib.import_module(_LAZY[name], __name__)
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
