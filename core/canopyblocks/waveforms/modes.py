"""Modes of many waveforms: local maxima of the mode-search smoothing (DESIGN 4.3).

A mode is a sub-sample ``i`` where the smoothed waveform rises into it and does not
rise out of it (``s[i] - s[i-1] > 0`` and ``s[i+1] - s[i] <= 0``; L2A's zero crossing
of the first derivative), lies above the back threshold, and lies between the signal
top (inclusive) and the signal bottom (exclusive). The ground is the lowest mode
(the largest index), L2A's ``elev_lowestmode``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["mode_mask", "lowest_mode", "energetic_modes"]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


def mode_mask(smoothed: npt.NDArray[np.float64], top: IntArray, bottom: IntArray,
              back: npt.NDArray[np.float64]) -> BoolArray:
    """Boolean (n, k): True at each mode.

    Parameters
    ----------
    smoothed : ndarray, shape (n, k)
        Mode-search smoothing of the residual waveform, sub-sample grid (counts).
    top, bottom : ndarray of int64, shape (n,)
        Signal top and bottom (sub-sample indices).
    back : ndarray, shape (n,)
        Back threshold as a residual (counts).
    """
    n, k = smoothed.shape
    mask = np.zeros((n, k), dtype=bool)
    if k < 3:
        return mask
    d = np.diff(smoothed, axis=1)
    inner = (d[:, :-1] > 0) & (d[:, 1:] <= 0) & (smoothed[:, 1:-1] > back[:, None])
    cols = np.arange(1, k - 1)
    inner &= (cols[None, :] >= top[:, None]) & (cols[None, :] < bottom[:, None])
    mask[:, 1:-1] = inner
    return mask


def lowest_mode(mask: BoolArray) -> tuple[IntArray, IntArray]:
    """Index of the lowest mode (-1 where none) and the number of modes, per shot."""
    count = mask.sum(axis=1).astype(np.int64)
    idx = mask.shape[1] - 1 - np.argmax(mask[:, ::-1], axis=1)
    return np.where(count > 0, idx, -1).astype(np.int64), count


def energetic_modes(mask: BoolArray, from_bottom: npt.NDArray[np.float64],
                    total: npt.NDArray[np.float64], min_percent: float) -> BoolArray:
    """The modes with at least ``min_percent`` % of the energy between them and the bottom.

    L2A's mode selection (setting group a2): a weak last mode -- a noise bump near the
    signal bottom -- is not taken as the ground. ``from_bottom`` and ``total`` come from
    :func:`canopyblocks.waveforms.rh.signal_energy`.
    """
    return mask & (from_bottom >= (min_percent / 100.0) * total[:, None])
