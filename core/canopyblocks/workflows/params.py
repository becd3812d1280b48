"""The parameter sets the workflows take, for the front doors.

The command line and the QGIS algorithms build these frozen dataclasses from what the
user gave and pass them to one workflow call; they import them from here (the front
doors import ``workflows/`` and the foundation only: tests/test_import_contract.py).
Each name is the very class of the room that owns it, loaded on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..blocks import BlockParams
    from ..blocks.estimators import Estimators, preset
    from ..reference.footprint_params import FootprintReferenceParams
    from ..simulate import SimParams, SimTrack
    from ..simulate.flash_cubes import FlashSimParams
    from ..simulate.gedi_waveforms import GediSimParams
    from ..simulate.params import BACKGROUND_PRESETS_MHZ
    from ..simulate.sensor_files import DualAlsParams
    from ..validation.coregistration import CoregParams
    from ..waveforms.settings import WaveformParams

__all__ = ["BlockParams", "Estimators", "preset", "FootprintReferenceParams", "SimParams",
           "SimTrack", "FlashSimParams", "GediSimParams", "DualAlsParams", "CoregParams",
           "WaveformParams", "BACKGROUND_PRESETS_MHZ"]

_OWNER = {
    "BlockParams": "..blocks.params",
    "Estimators": "..blocks.estimators",
    "preset": "..blocks.estimators",
    "FootprintReferenceParams": "..reference.footprint_params",
    "SimParams": "..simulate.params",
    "SimTrack": "..simulate.tracks",
    "FlashSimParams": "..simulate.flash_cubes",
    "GediSimParams": "..simulate.gedi_waveforms",
    "DualAlsParams": "..simulate.sensor_files",
    "CoregParams": "..validation.coregistration",
    "WaveformParams": "..waveforms.settings",
    "BACKGROUND_PRESETS_MHZ": "..simulate.params",
}


def __getattr__(name: str) -> Any:
    if name in _OWNER:
        return getattr(importlib.import_module(_OWNER[name], __package__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
