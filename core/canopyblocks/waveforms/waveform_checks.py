"""The checks at the door of the waveform processing: argument types, elevations in metres
and a waveform's orientation (the general checks are canopyblocks.arguments)."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from ..arguments import check_instance, check_optional
from ..errors import CanopyBlocksWarning, InputError
from .batch import WaveformBatch
from .settings import WaveformParams

__all__ = ["check_waveform_args", "UpsideDownWaveformWarning"]


class UpsideDownWaveformWarning(CanopyBlocksWarning):
    """Some shots have their first sample below their last (elevations swapped)."""


#: GEDI's 1 ns sample, 0.1499 m of range, written in international feet (0.4918 ft).
_FEET_SPACING = 0.299792458 / 2.0 / 0.3048
#: Elevations (m) no Earth surface reaches: below the Dead Sea shore's -430 m by far, or
#: above Everest.
_ELEVATIONS = (-1000.0, 10000.0)


def _check_metres(batch: WaveformBatch, two: np.ndarray, name: str) -> None:
    """Refuse elevations in feet (the sample spacing of GEDI's 1 ns sample in feet, 0.492
    per sample, where metres give 0.150) or outside any Earth surface."""
    b0 = np.asarray(batch.elev_bin0, float)
    b1 = np.asarray(batch.elev_lastbin, float)
    fin = two & np.isfinite(b0) & np.isfinite(b1)
    if not fin.any():
        return
    spacing = float(np.median((b0[fin] - b1[fin]) / (batch.n_samples[fin] - 1)))
    if abs(spacing / _FEET_SPACING - 1.0) < 0.015:
        raise InputError(
            f"{name}: the elevations of {batch.beam} step {spacing:.4f} per sample: GEDI's "
            f"1 ns sample (0.1499 m) in feet; give elevations in metres (multiply "
            f"elev_bin0/elev_lastbin by 0.3048)")
    mid = float(np.median(0.5 * (b0[fin] + b1[fin])))
    if not _ELEVATIONS[0] <= mid <= _ELEVATIONS[1]:
        raise InputError(
            f"{name}: the elevations of {batch.beam} lie around {mid:.6g}, outside any Earth "
            f"surface ({_ELEVATIONS[0]:g} to {_ELEVATIONS[1]:g} m); give elevations in "
            "metres above the ellipsoid")


def check_waveform_args(batch: Any, params: Any, name: str) -> None:
    """``batch`` a :class:`WaveformBatch` whose shots run downwards (sample 0 the highest,
    as received), ``params`` a :class:`WaveformParams` or None.

    Raises
    ------
    InputError
        Wrong types, or every shot with samples upside down (``elev_bin0`` below
        ``elev_lastbin``). Some shots upside down: :class:`UpsideDownWaveformWarning`.
    """
    check_instance(batch, WaveformBatch, f"{name}: batch",
                   "a WaveformBatch (read_gedi_l1b, or the simulator)")
    check_optional(params, WaveformParams, f"{name}: params",
                   "a WaveformParams (e.g. WaveformParams(setting='a1')) or None")
    two = batch.n_samples >= 2
    flagged = batch.extra.get("invalid_shot")   # the reader's own flag and warning
    if flagged is not None:
        two &= np.asarray(flagged) == 0
    _check_metres(batch, two, name)
    with np.errstate(invalid="ignore"):
        up = two & (np.asarray(batch.elev_bin0) < np.asarray(batch.elev_lastbin))
    if not up.any():
        return
    i = int(np.flatnonzero(up)[0])
    what = (f"elev_bin0 {float(batch.elev_bin0[i]):.2f} m lies below elev_lastbin "
            f"{float(batch.elev_lastbin[i]):.2f} m (shot {int(batch.shot_number[i])})")
    if int(up.sum()) == int(two.sum()):
        raise InputError(f"{name}: every shot of {batch.beam} is upside down: {what}; sample "
                         "0 is the first received, the highest -- swap elev_bin0 and "
                         "elev_lastbin (and the lat/lon pairs) or reverse the waveforms")
    warnings.warn(f"{name}: {int(up.sum())} of {len(batch)} shots of {batch.beam} are upside "
                  f"down ({what}); their heights are wrong", UpsideDownWaveformWarning,
                  stacklevel=3)
