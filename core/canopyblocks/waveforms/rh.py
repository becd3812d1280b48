"""Relative-height positions from the cumulative energy of many waveforms (DESIGN 4.3).

The energy is the mode-search smoothing of the residual waveform (counts above the
noise mean) between the signal top and bottom, accumulated from the bottom upwards.
The position of RH_k is one sub-sample below the first sub-sample (going up) where the
accumulated energy reaches k % of the total -- the convention that reproduces L2A's
``rx_cumulative`` -- with RH0 at the signal bottom and RH100 at the signal top.

The arrays hold each shot's signal bottom first (:mod:`.modes`, :mod:`.profile`):
column ``j`` is sub-sample ``bottom + 1 - j``, the top column ``span + 1``. The
accumulation runs along the row as stored, and the highest sub-sample whose share
reaches k % is the first column, counted from the bottom, that reaches it: one
comparison and a first-True search per percentile, exact, no loop over shots.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["signal_energy", "energy_positions", "truncate_cm"]

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]


def signal_energy(profile: FloatArray, span: IntArray) -> tuple[FloatArray, FloatArray]:
    """Energy accumulated from the bottom up, and the total, per shot.

    Parameters
    ----------
    profile : ndarray, shape (n, w)
        Residual (counts) bottom first; ``w`` at least ``span + 3``.
    span : ndarray of int64, shape (n,)
        ``bottom - top`` (sub-samples); negative where there is no signal.

    Returns
    -------
    from_bottom : ndarray, shape (n, w)
        ``from_bottom[i, j]`` = sum of the residual from the bottom (column 1) up to
        column ``j`` (counts x sub-samples); 0 in column 0. Columns above the top
        (``j > span + 1``) hold no meaning.
    total : ndarray, shape (n,)
        Energy between top and bottom (0 where there is no signal).
    """
    n, w = profile.shape
    from_bottom = np.zeros((n, w), dtype=np.float64)
    if w > 1:
        np.cumsum(profile[:, 1:], axis=1, out=from_bottom[:, 1:])
    ok = span >= 0
    total = np.zeros(n, dtype=np.float64)
    total[ok] = from_bottom[np.nonzero(ok)[0], span[ok] + 1]
    return from_bottom, total


def _first_reaching(share: FloatArray, level: float) -> IntArray:
    """First column per row with ``share >= level`` (``level`` <= 1: the top column's
    share is exactly 1, so there is one)."""
    return np.argmax(share >= level, axis=1)


def energy_positions(from_bottom: FloatArray, total: FloatArray, bottom: IntArray,
                     span: IntArray, percents: npt.ArrayLike) -> IntArray:
    """Sub-sample position (of the whole waveform) of each RH percentile.

    Parameters
    ----------
    from_bottom, total : ndarray
        From :func:`signal_energy`.
    bottom, span : ndarray of int64, shape (n,)
        Signal bottom (sub-sample of the whole waveform) and ``bottom - top``.
    percents : array_like
        RH percentiles (0 = bottom, 100 = top).

    Returns
    -------
    ndarray of int64, shape (n, len(percents))
        -1 in rows whose total energy is not positive.
    """
    pct = np.asarray(percents, dtype=np.float64)
    n, w = from_bottom.shape
    out = np.full((n, len(pct)), -1, dtype=np.int64)
    good = (total > 0) & (span >= 0)
    if not good.any() or w == 0:
        return out
    # every row divided (no copy of the good ones); the others' shares are not used
    with np.errstate(divide="ignore", invalid="ignore"):
        share = from_bottom / total[:, None]
    b = bottom[good]
    top = b - span[good]
    for k, p in enumerate(pct):
        if p <= 0:
            out[good, k] = b
        elif p >= 100:
            out[good, k] = top
        else:
            # the highest sub-sample reaching p % is bottom + 1 - j; RH is one below it
            out[good, k] = b + 2 - _first_reaching(share, p / 100.0)[good]
    return out


def truncate_cm(metres: FloatArray) -> FloatArray:
    """Truncate towards zero to whole centimetres, as L2A stores ``rh`` (int cm).

    A guard of 1e-6 cm keeps values such as 0.29 m (0.28999... in floating point) at
    29 cm.
    """
    cm = np.asarray(metres, dtype=np.float64) * 100.0
    return np.trunc(cm + np.sign(cm) * 1e-6) / 100.0
