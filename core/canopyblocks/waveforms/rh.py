"""Relative-height positions from the cumulative energy of many waveforms (DESIGN 4.3).

The energy is the mode-search smoothing of the residual waveform (counts above the
noise mean) between the signal top and bottom, accumulated from the bottom upwards.
The position of RH_k is one sub-sample below the first sub-sample (going up) where the
accumulated energy reaches k % of the total -- the convention that reproduces L2A's
``rx_cumulative`` -- with RH0 at the signal bottom and RH100 at the signal top.

Vectorised without a loop over shots or percentiles: the running maximum of the
accumulated energy (from the bottom) is monotone, so every row is searched at once with
one ``numpy.searchsorted`` over the rows laid end to end.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["signal_energy", "energy_positions", "truncate_cm"]

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]


def signal_energy(smoothed: FloatArray, top: IntArray, bottom: IntArray
                  ) -> tuple[FloatArray, FloatArray]:
    """Energy accumulated from the bottom up, and the total, per shot.

    Returns
    -------
    from_bottom : ndarray, shape (n, k)
        ``from_bottom[i, j]`` = sum of the residual over sub-samples ``j .. bottom``
        restricted to ``top .. bottom`` (counts x sub-samples); 0 below the bottom.
    total : ndarray, shape (n,)
        Energy between top and bottom.
    """
    n, k = smoothed.shape
    cols = np.arange(k)
    inside = (cols[None, :] >= top[:, None]) & (cols[None, :] <= bottom[:, None])
    energy = np.where(inside, smoothed, 0.0)
    from_bottom = np.cumsum(energy[:, ::-1], axis=1)[:, ::-1]
    total = from_bottom[np.arange(n), np.clip(top, 0, max(k - 1, 0))] if k else np.zeros(n)
    return from_bottom, np.asarray(total, dtype=np.float64)


def energy_positions(from_bottom: FloatArray, total: FloatArray, top: IntArray,
                     bottom: IntArray, percents: npt.ArrayLike) -> IntArray:
    """Sub-sample position of each RH percentile, shape (n, len(percents)).

    Rows whose total energy is not positive get -1.
    """
    pct = np.asarray(percents, dtype=np.float64)
    n, k = from_bottom.shape
    out = np.full((n, len(pct)), -1, dtype=np.int64)
    good = total > 0
    if not good.any() or k == 0:
        return out
    fb = from_bottom[good]
    tot = total[good]
    # Running maximum from the bottom: the largest j with from_bottom[j] >= v equals
    # the largest j with running_max[j] >= v, and running_max is non-increasing in j.
    running = np.maximum.accumulate(fb[:, ::-1], axis=1)[:, ::-1] / tot[:, None]
    rows = np.arange(len(tot))
    offset = float(np.max(running)) + 2.0
    keys = (rows * offset)[:, None] - running          # non-decreasing when flattened
    queries = (rows * offset)[:, None] - pct[None, :] / 100.0
    idx = np.searchsorted(keys.ravel(), queries.ravel(), side="right").reshape(queries.shape)
    counts = idx - (rows * k)[:, None]                  # sub-samples with energy >= k %
    pos = counts.astype(np.int64)                       # one below the last of them
    pos = np.where(pct[None, :] <= 0, bottom[good][:, None], pos)
    pos = np.where(pct[None, :] >= 100, top[good][:, None], pos)
    out[good] = pos
    return out


def truncate_cm(metres: FloatArray) -> FloatArray:
    """Truncate towards zero to whole centimetres, as L2A stores ``rh`` (int cm).

    A guard of 1e-6 cm keeps values such as 0.29 m (0.28999... in floating point) at
    29 cm.
    """
    cm = np.asarray(metres, dtype=np.float64) * 100.0
    return np.trunc(cm + np.sign(cm) * 1e-6) / 100.0
