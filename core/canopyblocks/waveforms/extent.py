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


def signal_extent(smoothed: npt.NDArray[np.float64], start: IntArray, end: IntArray,
                  front: npt.NDArray[np.float64], back: npt.NDArray[np.float64]
                  ) -> tuple[IntArray, IntArray, BoolArray]:
    """Signal top and bottom (sub-sample indices) of each shot.

    Parameters
    ----------
    smoothed : ndarray, shape (n, k)
        Location-smoothed residual waveform on the sub-sample grid (counts).
    start, end : ndarray of int64, shape (n,)
        Search window in sub-samples (inclusive).
    front, back : ndarray, shape (n,)
        Front and back thresholds as residuals (``k_f * sd``, ``k_b * sd``; counts).

    Returns
    -------
    top, bottom : ndarray of int64, shape (n,)
    found : ndarray of bool, shape (n,)
        False where no pair of sub-samples exceeds a threshold in the window.
    """
    n, k = smoothed.shape
    cols = np.arange(k - 1)
    in_window = (cols[None, :] >= start[:, None]) & (cols[None, :] < end[:, None])
    above_front = smoothed > front[:, None]
    pairs = above_front[:, :-1] & above_front[:, 1:] & in_window
    top, found_top = _first_true(pairs)
    above_back = smoothed > back[:, None]
    pairs = above_back[:, :-1] & above_back[:, 1:] & in_window
    last_pair, found_bottom = _last_true(pairs)
    return top, last_pair + 1, found_top & found_bottom
