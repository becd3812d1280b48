"""Each shot's signal, bottom first, out of a chunk's smoothed waveforms (DESIGN 4.3).

The modes, energies, RH, cover and penetration need the mode-search smoothing between
the signal top and bottom only, about a quarter of the search window on GEDI shots.
:func:`bottom_first` copies it out, one sub-sample either side, in the order the
energy is accumulated (from the bottom up), so every later step runs along contiguous
rows and finds the lowest mode or an RH level with a first-True search.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["bottom_first"]


def bottom_first(smoothed: npt.NDArray[np.float64], bottom: npt.NDArray[np.int64],
                 width: int) -> npt.NDArray[np.float64]:
    """``out[i, j] = smoothed[i, bottom[i] + 1 - j]`` for ``j < width``.

    Indices outside the row are clipped to it (those columns lie outside the signal and
    are never read as such).

    Parameters
    ----------
    smoothed : ndarray, shape (n, k)
        Smoothed residual waveforms on the sub-sample grid (counts); may be a view.
    bottom : ndarray of int64, shape (n,)
        Signal bottom, column of ``smoothed``.
    width : int
        Columns wanted (at least ``bottom - top + 3``).
    """
    n, k = smoothed.shape
    if n == 0 or k == 0:
        return np.zeros((n, width))
    cols = (bottom + 1)[:, None] - np.arange(width)[None, :]
    if int(bottom.min()) + 2 < width or int(bottom.max()) + 1 > k - 1:
        np.clip(cols, 0, k - 1, out=cols)
    if smoothed.strides[1] == smoothed.itemsize and smoothed.strides[0] % smoothed.itemsize == 0:
        row_step = smoothed.strides[0] // smoothed.itemsize
        base = np.lib.stride_tricks.as_strided(smoothed, shape=(n * row_step,),
                                               strides=(smoothed.itemsize,))
        flat = cols + (np.arange(n) * row_step)[:, None]
        return base.take(flat)
    return np.take_along_axis(smoothed, cols, axis=1)
