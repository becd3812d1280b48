"""Signal extent of many waveforms: search window, signal top and bottom (DESIGN 4.3).

- Search window: from ``search_size`` samples before the first raw sample above
  ``noise_mean + k_pre * noise_sd`` to ``search_size`` samples after the last one
  (clipped to the shot), as L2A's ``search_start`` / ``search_end``.
- Signal top (L2A ``toploc``): the first sub-sample ``i`` in the window with ``i`` and
  ``i + 1`` both above the front threshold on the location smoothing.
- Signal bottom (L2A ``botloc``): the last such pair above the back threshold; the
  bottom is the lower sub-sample of the pair.

Positions are sub-sample indices (sample position x ``factor``), 0-based, increasing
downwards (sample 0 is the highest).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from .profile import bottom_first

__all__ = ["search_window", "signal_extent"]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


def _first_true(mask: BoolArray) -> tuple[IntArray, BoolArray]:
    """Index of the first True per row, and whether there is one."""
    found = mask.any(axis=1)
    return np.argmax(mask, axis=1).astype(np.int64), found


def _last_true(mask: BoolArray) -> tuple[IntArray, BoolArray]:
    """Index of the last True per row, and whether there is one."""
    found = mask.any(axis=1)
    idx = mask.shape[1] - 1 - np.argmax(mask[:, ::-1], axis=1)
    return idx.astype(np.int64), found


def search_window(resid: npt.NDArray[np.floating], valid: BoolArray,
                  noise_sd: npt.NDArray[np.float64], k_pre: float, search_size: int,
                  n_samples: IntArray) -> tuple[IntArray, IntArray, BoolArray]:
    """First and last sample (inclusive) of the search window of each shot.

    Parameters
    ----------
    resid : ndarray, shape (n, m)
        Raw waveform minus the noise mean (counts).
    valid : ndarray of bool, shape (n, m)
        Real samples (not padding).
    noise_sd : ndarray, shape (n,)
        Noise standard deviation (counts).
    k_pre : float
        Preprocessor threshold in noise sd.
    search_size : int
        Samples added on either side.
    n_samples : ndarray, shape (n,)

    Returns
    -------
    start, end : ndarray of int64, shape (n,)
        Window in samples (inclusive).
    found : ndarray of bool, shape (n,)
        False where no raw sample exceeds the preprocessor threshold.
    """
    above = (resid > (k_pre * noise_sd)[:, None]) & valid
    first, found = _first_true(above)
    last, _ = _last_true(above)
    start = np.maximum(first - search_size, 0)
    end = np.minimum(last + search_size, np.maximum(n_samples - 1, 0))
    return start, end, found


def _pairs_above(values: npt.NDArray[np.float64], level: npt.NDArray[np.float64]) -> BoolArray:
    """``values[:, i] > level`` and ``values[:, i + 1] > level``, shape (n, k - 1)."""
    above = values > level[:, None]
    return above[:, :-1] & above[:, 1:]


def _first_pair(smoothed: npt.NDArray[np.float64], start: IntArray, level:
                npt.NDArray[np.float64], band: int) -> tuple[IntArray, BoolArray]:
    """First ``i >= start`` with a pair above ``level``; a band after the earliest start
    first, the rest of the row only for the shots with none in it."""
    n, k = smoothed.shape
    s0 = int(start.min())
    same = bool((start == s0).all())
    first = np.zeros(n, dtype=np.int64)
    has = np.zeros(n, dtype=bool)
    todo = np.arange(n)
    for stop in (min(k, s0 + band + 1), k):
        if not len(todo) or stop - s0 < 2:
            continue
        pairs = _pairs_above(smoothed[todo, s0:stop] if len(todo) < n else
                             smoothed[:, s0:stop], level[todo])
        if not same:
            cols = np.arange(s0, stop - 1)
            pairs &= cols[None, :] >= start[todo][:, None]
        i = np.argmax(pairs, axis=1)
        hit = pairs[np.arange(len(todo)), i]
        first[todo] = i + s0
        has[todo] = hit
        todo = todo[~hit]
    return first, has


def _last_pair(smoothed: npt.NDArray[np.float64], start: IntArray, end: IntArray,
               level: npt.NDArray[np.float64], band: int) -> tuple[IntArray, BoolArray]:
    """Last ``i < end`` with a pair above ``level`` (and ``i >= start``); a band before
    ``end`` first, read backwards, the whole row only for the shots with none in it."""
    n, k = smoothed.shape
    # r[:, j] = smoothed[:, end - j]: a pair at i = end - 1 - j is r[j + 1] and r[j]
    r = bottom_first(smoothed, end - 1, band + 2)
    pairs = _pairs_above(r, level)
    j = np.argmax(pairs, axis=1)
    hit = pairs[np.arange(n), j] & (end - 1 - j >= 0)
    last = end - 1 - j
    has = hit & (last >= start)
    redo = np.nonzero(~hit & (end - 1 - band > start))[0]
    if len(redo):
        sub = _pairs_above(smoothed[redo], level[redo])
        cols = np.arange(k - 1)
        sub &= (cols[None, :] >= start[redo][:, None]) & (cols[None, :] < end[redo][:, None])
        i = k - 2 - np.argmax(sub[:, ::-1], axis=1)
        last[redo] = i
        has[redo] = sub[np.arange(len(redo)), i]
    return last, has


def signal_extent(smoothed: npt.NDArray[np.float64], start: IntArray, end: IntArray,
                  front: npt.NDArray[np.float64], back: npt.NDArray[np.float64],
                  band: int = 160) -> tuple[IntArray, IntArray, BoolArray]:
    """Signal top and bottom (sub-sample indices) of each shot.

    Parameters
    ----------
    smoothed : ndarray, shape (n, k)
        Location-smoothed residual waveform on the sub-sample grid (counts).
    start, end : ndarray of int64, shape (n,)
        Search window in sub-samples: pairs ``(i, i + 1)`` with ``start <= i < end``.
    front, back : ndarray, shape (n,)
        Front and back thresholds as residuals (``k_f * sd``, ``k_b * sd``; counts).
    band : int
        Sub-samples looked at first after ``start`` (top) and before ``end`` (bottom);
        the rest only where the band holds no pair (same result, less work).

    Returns
    -------
    top, bottom : ndarray of int64, shape (n,)
    found : ndarray of bool, shape (n,)
        False where no pair of sub-samples exceeds a threshold in the window.
    """
    n, k = smoothed.shape
    if n == 0 or k < 2:
        zeros = np.zeros(n, dtype=np.int64)
        return zeros, zeros.copy(), np.zeros(n, dtype=bool)
    start = np.asarray(start, dtype=np.int64)
    end = np.minimum(np.asarray(end, dtype=np.int64), k - 1)
    top, found_top = _first_pair(smoothed, start, front, band)
    found_top &= top < end
    last_pair, found_bottom = _last_pair(smoothed, start, end, back, band)
    return top, last_pair + 1, found_top & found_bottom
