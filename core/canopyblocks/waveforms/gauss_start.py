"""Where the decomposition's fits start, for a whole batch of shots at once (DESIGN 4.4).

For every shot (a row of the batch, ``n_samples`` samples) the initial peaks are the
local maxima of the smoothed samples above the threshold, the ``max_gaussians`` highest
kept, each with a sigma from the neighbouring inflection points (sign changes of the
second difference, which lie between samples); the fit window is the span of smoothed
samples above the threshold plus a margin; the start is clipped strictly inside the
bounds. These are the numbers :func:`.decompose._problem` gives shot by shot -- the same
operations on the same values, so bit for bit -- with array operations over the batch
instead of a Python call per shot.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import numpy.typing as npt

__all__ = ["FitStarts", "fit_starts"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

MARGIN = 15          # samples added on both sides of the signal window
MIN_SIGMA = 2.0      # samples (GEDI's pulse sd is about 6.6 ns = 6.6 samples)
MAX_SIGMA = 60.0
#: Shots whose starts are found together at most (temporaries of ~8 bytes x samples each).
ROWS = 4096


@dataclass(frozen=True)
class FitStarts:
    """The fits of a batch: shot ``i`` has ``count[i]`` Gaussians (0: nothing above the
    threshold), window ``lo[i] .. hi[i] - 1`` (samples); ``p0``, ``lower`` and ``upper``
    (n, 3 * max_gaussians) hold ``(a, c, s)`` per Gaussian in centre order, the first
    ``3 * count[i]`` of a row used (amplitude in counts, centre and sigma in samples)."""

    count: IntArray
    lo: IntArray
    hi: IntArray
    p0: FloatArray
    lower: FloatArray
    upper: FloatArray


def fit_starts(resid: FloatArray, smoothed: FloatArray, n_samples: IntArray,
               thr: FloatArray, usable: npt.NDArray[np.bool_], max_gaussians: int
               ) -> FitStarts:
    """Initial peaks, windows, starts and bounds of every shot.

    Parameters
    ----------
    resid, smoothed : ndarray (n, width)
        Samples minus the noise mean (counts) and their smoothed copy; row ``i`` valid
        in its first ``n_samples[i]`` columns.
    n_samples : ndarray (n,)
    thr : ndarray (n,)
        Detection threshold above the noise mean (counts).
    usable : ndarray of bool (n,)
        Shots to decompose at all (at least 3 samples, a finite positive threshold).
    max_gaussians : int

    Returns
    -------
    FitStarts
    """
    n = smoothed.shape[0]
    if n > ROWS:   # a block of rows at a time: the temporaries stay ~ROWS rows wide
        parts = [fit_starts(resid[a:a + ROWS], smoothed[a:a + ROWS], n_samples[a:a + ROWS],
                            thr[a:a + ROWS], usable[a:a + ROWS], max_gaussians)
                 for a in range(0, n, ROWS)]
        return FitStarts(*(np.concatenate([getattr(p, f.name) for p in parts])
                           for f in fields(FitStarts)))
    return _fit_starts(resid, smoothed, n_samples, thr, usable, max_gaussians)


def _fit_starts(resid: FloatArray, smoothed: FloatArray, n_samples: IntArray,
                thr: FloatArray, usable: npt.NDArray[np.bool_], max_gaussians: int
                ) -> FitStarts:
    """:func:`fit_starts` of at most :data:`ROWS` shots."""
    n, width = smoothed.shape
    m = np.where(usable, n_samples, 0).astype(np.int64)
    if width < 3:
        m[:] = 0
        width = 3
        resid = np.zeros((n, width))
        smoothed = np.zeros((n, width))
    cols = np.arange(width)
    t = thr[:, None]
    s = smoothed
    mid = s[:, 1:-1]
    peak = (mid > s[:, :-2]) & (mid >= s[:, 2:]) & (mid > t) \
        & (cols[1:-1][None, :] < (m - 1)[:, None])
    row, pos = np.nonzero(peak)
    pos = pos + 1
    amp = s[row, pos]
    # inflection j + 1.5 between d2[j] and d2[j + 1] (j < m - 3); a peak p's neighbours:
    # the last with j <= p - 2 and the first with j >= p - 1
    d2 = np.diff(s, 2, axis=1)
    sign = np.sign(d2)
    infl = (sign[:, :-1] != sign[:, 1:]) & (cols[:-3][None, :] < (m - 3)[:, None])
    # found in the flat (row-major) indices of the inflections by binary search
    k = infl.shape[1]
    flat = np.flatnonzero(infl)
    base = row * k
    ib = np.searchsorted(flat, base + pos - 2, side="right") - 1
    jb = flat[np.maximum(ib, 0)] - base if len(flat) else np.full(len(pos), -1)
    jb = np.where((pos >= 2) & (ib >= 0) & (jb >= 0), jb, -1)
    ia = np.searchsorted(flat, base + pos - 1, side="left")
    ja = flat[np.minimum(ia, len(flat) - 1)] - base if len(flat) else np.full(len(pos), k)
    ja = np.where((ia < len(flat)) & (ja < k), ja, k)
    lo_i = np.where(jb >= 0, jb + 1.5, pos - MIN_SIGMA)
    hi_i = np.where(ja < k, ja + 1.5, pos + MIN_SIGMA)
    sigma = np.clip((hi_i - lo_i) / 2.0, MIN_SIGMA, MAX_SIGMA)
    # the max_gaussians highest of each shot (ties: the earlier), kept in centre order
    order = np.lexsort((pos, -amp, row))
    first = np.searchsorted(row[order], row[order], side="left")
    keep = np.zeros(len(row), dtype=bool)
    keep[order] = (np.arange(len(order)) - first) < max_gaussians
    row, pos, amp, sigma = row[keep], pos[keep], amp[keep], sigma[keep]
    count = np.bincount(row, minlength=n).astype(np.int64)
    slot = np.arange(len(row)) - np.searchsorted(row, row, side="left")
    # the window: smoothed samples above the threshold, plus the margin
    above = (s > t) & (cols[None, :] < m[:, None])
    has = count > 0
    a_first = np.argmax(above, axis=1)
    a_last = width - 1 - np.argmax(above[:, ::-1], axis=1)
    lo = np.where(has, np.maximum(0, a_first - MARGIN), 0).astype(np.int64)
    hi = np.where(has, np.minimum(m, a_last + MARGIN + 1), 0).astype(np.int64)
    in_win = (cols[None, :] >= lo[:, None]) & (cols[None, :] < hi[:, None])
    y_max = np.where(in_win, resid, -np.inf).max(axis=1) if width else np.full(n, -np.inf)
    amax = np.maximum(y_max, thr) * 2.0
    n_par = 3 * max_gaussians
    p0 = np.zeros((n, n_par))
    lower = np.zeros((n, n_par))
    upper = np.zeros((n, n_par))
    lower[:, 1::3] = lo[:, None]
    lower[:, 2::3] = MIN_SIGMA
    upper[:, 0::3] = amax[:, None]
    upper[:, 1::3] = (hi - 1.0)[:, None]
    upper[:, 2::3] = MAX_SIGMA
    p0[row, 3 * slot] = amp
    p0[row, 3 * slot + 1] = pos.astype(np.float64)
    p0[row, 3 * slot + 2] = sigma
    p0 = np.clip(p0, lower + 1e-9, upper - 1e-9)
    return FitStarts(count, lo, hi, p0, lower, upper)
