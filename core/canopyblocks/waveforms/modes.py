"""Modes of many waveforms: local maxima of the mode-search smoothing (DESIGN 4.3).

A mode is a sub-sample ``i`` where the smoothed waveform rises into it and does not
rise out of it (``s[i] - s[i-1] > 0`` and ``s[i+1] - s[i] <= 0``; L2A's zero crossing
of the first derivative), lies above the back threshold, and lies between the signal
top (inclusive) and the signal bottom (exclusive). The ground is the lowest mode
(the largest index), L2A's ``elev_lowestmode``.

The arrays hold each shot's signal *bottom first* (see :mod:`.profile`): column ``j``
is sub-sample ``bottom + 1 - j``, so the signal bottom is column 1, the top column
``span + 1`` (``span = bottom - top``), and the lowest mode is the first one found.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["mode_mask", "lowest_mode", "energetic_modes"]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


def column_index(width: int) -> npt.NDArray[np.signedinteger]:
    """``0 .. width - 1`` in the narrowest integer type (cheap broadcast comparisons)."""
    dtype = np.int16 if width < 2**15 - 1 else np.int64
    return np.arange(width, dtype=dtype)


def mode_mask(profile: npt.NDArray[np.float64], span: IntArray,
              back: npt.NDArray[np.float64]) -> BoolArray:
    """Boolean (n, w): True at each mode.

    Parameters
    ----------
    profile : ndarray, shape (n, w)
        Mode-search smoothing of the residual waveform, bottom first (counts); ``w``
        at least ``span + 3``.
    span : ndarray of int64, shape (n,)
        ``bottom - top`` in sub-samples; -1 (or less) where there is no signal.
    back : ndarray, shape (n,)
        Back threshold as a residual (counts).
    """
    n, w = profile.shape
    mask = np.zeros((n, w), dtype=bool)
    if w < 3:
        return mask
    # s[i] - s[i-1] > 0 and s[i+1] - s[i] <= 0, with s[i] = r[j], s[i-1] = r[j+1] and
    # s[i+1] = r[j-1]: r[j+1] < r[j] and not r[j] < r[j-1] (a difference of two finite
    # floats has the sign of their comparison)
    falls = profile[:, 1:] < profile[:, :-1]
    inner = mask[:, 1:-1]
    np.greater(profile[:, 1:-1], back[:, None], out=inner)
    inner &= falls[:, 1:]
    inner &= ~falls[:, :-1]
    cols = column_index(w)[1:-1]
    inner &= (cols[None, :] >= 2) & (cols[None, :] <= (span + 1).astype(cols.dtype)[:, None])
    return mask


def lowest_mode(mask: BoolArray) -> tuple[IntArray, IntArray]:
    """Column of the lowest mode (-1 where none) and the number of modes, per shot."""
    count = np.count_nonzero(mask, axis=1).astype(np.int64)
    idx = np.argmax(mask, axis=1)
    return np.where(count > 0, idx, -1).astype(np.int64), count


def energetic_modes(mask: BoolArray, from_bottom: npt.NDArray[np.float64],
                    total: npt.NDArray[np.float64], min_percent: float) -> BoolArray:
    """The modes with at least ``min_percent`` % of the energy between them and the bottom.

    L2A's mode selection (setting group a2): a weak last mode -- a noise bump near the
    signal bottom -- is not taken as the ground. ``from_bottom`` and ``total`` come from
    :func:`canopyblocks.waveforms.rh.signal_energy`.
    """
    return mask & (from_bottom >= (min_percent / 100.0) * total[:, None])
