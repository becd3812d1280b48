"""Truth per footprint from the weighted airborne points (seed 002 section 2.2).

Definitions (all heights in metres, in the point cloud's vertical datum):

* **Pseudo-waveform**: the footprint's points weighted by ``exp(-2 r^2/R^2)``, as a
  height density broadened by the instrument point-spread (Gaussian, sigma = PSF):
  ``f(z) = sum_j w_j N(z; z_j, PSF) / sum_j w_j``.  It is the PDF the photons are
  drawn from.
* **Ground**: the lowest peak of ``f``.  Peaks are found on ``f`` sampled in bins of
  ``TruthParams.bin_size`` (0.1 m, on a fixed grid of multiples of the bin size, so
  the result does not depend on which shots are processed together): a bin is a peak when it is higher than the bin below,
  not lower than the bin above, and at least ``peak_fraction`` (5 %) of the highest bin.
  The lowest such peak (refined by a parabola through three bins) is then climbed to
  the exact mode of ``f`` by Newton/mean-shift iterations on the Gaussian mixture
  (each footprint until its step is below 2e-4 m, leaving an error below ~1e-6 m), so
  the result does not depend on the bin grid: flat ground at ``z0`` gives ``z0``.
* **Top of canopy**: the highest point in the footprint (any point within R has a
  weight > 0).
* **RH50/60/75/90/95**: weighted percentiles of ``z - ground`` over the points more than
  ``rh_floor`` (default 2 x PSF = 0.5 m) above the ground: the smallest canopy height
  whose cumulative weight reaches n % of the canopy weight (inverse CDF, no
  interpolation).  0 when the footprint has no such point.
* **Canopy cover**: the number of points more than ``cover_threshold`` (2 m) above the
  ground divided by the number of points in the footprint (unweighted, as the seed
  defines it from return counts).

Footprints without points get NaN truth and ``n_points = 0``; no photon is drawn there.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..errors import InputError
from .footprints import FootprintPairs, _ranges
from .params import TruthParams

__all__ = ["RH_LEVELS", "footprint_truth", "MAX_BINS"]

#: RH percentiles reported per footprint.
RH_LEVELS: tuple[int, ...] = (50, 60, 75, 90, 95)

#: Refuse a pseudo-waveform grid longer than this (points 1 km apart in height).
MAX_BINS = 20_000

_MEANSHIFT_ITER = 30


def footprint_truth(pairs: FootprintPairs, psf: float, tp: TruthParams,
                    rh_floor: float) -> dict[str, np.ndarray]:
    """Truth of every footprint of a run of shots.

    Parameters
    ----------
    pairs : FootprintPairs
        Points per footprint with weights (sorted by height within each shot here
        unless ``pairs.height_sorted``).
    psf : float
        Point-spread sigma, metres.
    tp : TruthParams
        Bin size, peak threshold, cover threshold.
    rh_floor : float
        Metres above ground from which points count for RH metrics.

    Returns
    -------
    dict of ndarray (length ``pairs.n_shots``)
        ``ground``, ``top``, ``rh50`` ... ``rh95``, ``cover`` (0..1), ``n_points``,
        ``weight_sum``.
    """
    pairs = pairs.sorted_by_height()
    n = pairs.n_shots
    counts = pairs.counts
    out: dict[str, np.ndarray] = {
        "ground": np.full(n, np.nan), "top": np.full(n, np.nan),
        **{f"rh{q}": np.full(n, np.nan) for q in RH_LEVELS},
        "cover": np.full(n, np.nan), "n_points": counts.astype(np.int64),
        "weight_sum": np.zeros(n),
    }
    has = counts > 0
    if not has.any():
        return out
    shot, z, w = pairs.shot, pairs.z, pairs.weight
    ids = np.flatnonzero(has)
    starts, ends = pairs.indptr[:-1][has], pairs.indptr[1:][has]
    find = _HeightSearch(z, shot, n, ids, starts, ends)
    out["weight_sum"][has] = np.add.reduceat(w, starts)
    # ---- top: highest point per footprint (pairs are sorted by height in a shot)
    out["top"][has] = z[ends - 1]
    # ---- ground: lowest peak of the broadened weighted histogram, then mean-shift
    ground = _lowest_peak(shot, z, w, pairs.indptr, has, psf, tp)
    g = _mean_shift(find, z, w, ground[has], psf)
    ground[~has] = np.nan
    ground[has] = g
    out["ground"] = ground
    # heights above ground z - ground increase within each shot: the points above a
    # threshold are the last ones of each shot
    # ---- canopy cover: unweighted share of points above ground + threshold
    out["cover"][has] = (ends - find.first(g, tp.cover_threshold, True)) / counts[has]
    # ---- RH: weighted inverse-CDF percentiles of canopy heights
    c0 = find.first(g, rh_floor, True)
    cw = pairs.cumulative_weight
    cbefore = np.where(c0 > 0, cw[np.maximum(c0 - 1, 0)], 0.0)
    ctot = cw[ends - 1] - cbefore
    can = c0 < ends
    for q in RH_LEVELS:
        idx = np.searchsorted(cw, cbefore + ctot * (q / 100.0 * (1 - 1e-12)), side="left")
        idx = np.clip(idx, c0, ends - 1)
        col = np.full(n, np.nan)
        col[has] = np.where(can, z[idx] - g, 0.0)
        out[f"rh{q}"] = col
    return out


class _HeightSearch:
    """Exact per-shot searches in pairs sorted by (shot, height).

    ``first(g, t, strict)`` is, for each shot with points, the first pair with
    ``z - g > t`` (``>=`` when not strict), or the shot's end: a binary search on a
    key increasing over all pairs, then corrected by the exact comparison.
    """

    def __init__(self, z: np.ndarray, shot: np.ndarray, n: int, ids: np.ndarray,
                 starts: np.ndarray, ends: np.ndarray) -> None:
        zlo = float(z.min())
        span = 2.0 * (float(z.max()) - zlo) + 2.0
        base = np.arange(n, dtype=np.float64) * span - zlo
        self.key = z + base[shot]  # increasing: shot, then height
        self.base = base[ids]
        self.z, self.ids, self.starts, self.ends = z, ids, starts, ends

    def first(self, g: np.ndarray, t: float, strict: bool) -> np.ndarray:
        z, starts, ends = self.z, self.starts, self.ends
        i = np.searchsorted(self.key, (g + t) + self.base, side="right" if strict else "left")
        i = np.minimum(np.maximum(i, starts), ends)
        last = z.size - 1
        for _ in range(64):
            prev = z[np.maximum(i - 1, 0)] - g
            cur = z[np.minimum(i, last)] - g
            if strict:
                left = (i > starts) & (prev > t)
                right = (i < ends) & ~(cur > t)
            else:
                left = (i > starts) & (prev >= t)
                right = (i < ends) & ~(cur >= t)
            if not (left.any() or right.any()):
                return i
            i = i - left + right
        raise AssertionError("height search did not converge")  # pragma: no cover


def _lowest_peak(shot: np.ndarray, z: np.ndarray, w: np.ndarray, indptr: np.ndarray,
                 has: np.ndarray, psf: float, tp: TruthParams) -> np.ndarray:
    """Start of the ground climb: the lowest peak of each shot's binned waveform.

    Bins are ``[i b, (i + 1) b)`` for integer ``i`` (a fixed grid); each shot's
    histogram covers its own height range plus the filter's reach.
    """
    n = has.size
    b = tp.bin_size
    pad = int(math.ceil((4.0 * psf + 2.0 * b) / b))
    ab = np.floor(z / b).astype(np.int64)
    lo = np.zeros(n, np.int64)
    hi = np.zeros(n, np.int64)
    lo[has] = ab[indptr[:-1][has]] - pad
    hi[has] = ab[indptr[1:][has] - 1] + pad
    nb = int((hi - lo).max()) + 1
    if nb > MAX_BINS:
        raise InputError(
            f"airborne point heights span {(nb - 2 * pad) * b:.0f} m inside one footprint; "
            "the cloud holds outliers (birds, noise): drop them (ASPRS classes 7/18 are "
            "excluded by default) or crop the cloud")
    base = np.arange(n, dtype=np.int64) * nb - lo
    hist = np.bincount(base[shot] + ab, weights=w, minlength=n * nb).reshape(n, nb)
    wave = gaussian_filter1d(hist, psf / b, axis=1, mode="constant", truncate=4.0)
    mid = wave[:, 1:-1]
    peak = (mid > wave[:, :-2]) & (mid >= wave[:, 2:]) & (
        mid >= tp.peak_fraction * wave.max(axis=1, keepdims=True)) & (mid > 0)
    first = np.argmax(peak, axis=1) + 1  # bin of the lowest peak (1 when none: empty)
    # parabolic vertex through the peak bin and its neighbours: the mean-shift start
    rows = np.arange(n)
    y0, y1, y2 = wave[rows, first - 1], wave[rows, first], wave[rows, first + 1]
    den = y0 - 2.0 * y1 + y2
    off = np.where(den < 0, 0.5 * (y0 - y2) / np.where(den < 0, den, -1.0), 0.0)
    return (lo + first + 0.5 + np.clip(off, -0.5, 0.5)) * b


def _mean_shift(find: _HeightSearch, z: np.ndarray, w: np.ndarray, start: np.ndarray,
                psf: float) -> np.ndarray:
    """Climb from ``start`` to the nearest mode of each footprint's Gaussian mixture.

    ``start`` holds one value per shot with points (``find.ids``).  Newton steps on
    the mixture's derivative where it is concave, mean-shift steps elsewhere; steps are
    limited to 0.5 PSF so the climb stays on the starting peak.  The mixture is summed
    over the points with ``|z - start| <= 5 PSF``.  A footprint stops after a step below
    2e-4 m (Newton converges quadratically: the remaining error is ~(2e-4)^2 / PSF, far
    below a millimetre).
    """
    m = start.size
    g = start.copy()
    reach = 5.0 * psf
    lo = find.first(g, -reach, False)
    cnt = find.first(g, reach, True) - lo
    live = np.flatnonzero(cnt > 0)  # shots still climbing (index into start)
    lo, cnt = lo[live], cnt[live]
    sel = _ranges(lo, cnt)
    zz, ww = z[sel], w[sel]
    s = np.repeat(np.arange(live.size), cnt)
    inv = -0.5 / (psf * psf)
    inv_var = 1.0 / (psf * psf)
    limit = 0.5 * psf
    for _ in range(_MEANSHIFT_ITER):
        if not live.size:
            break
        first = np.cumsum(cnt) - cnt
        d = zz - g[live][s]
        k = ww * np.exp(inv * d * d)
        kd = k * d
        den = np.add.reduceat(k, first)
        d1 = np.add.reduceat(kd, first)
        d2 = np.add.reduceat(kd * d, first)
        curv = den - d2 * inv_var
        safe_den = np.where(den > 0, den, 1.0)
        step = np.where(curv > 1e-12 * safe_den, d1 / np.where(curv > 0, curv, 1.0),
                        d1 / safe_den)
        step = np.where(den > 0, np.clip(step, -limit, limit), 0.0)
        g[live] += step
        done = np.abs(step) < 2e-4
        if done.all():
            break
        if done.any():
            keep = ~done[s]
            zz, ww = zz[keep], ww[keep]
            live, cnt = live[~done], cnt[~done]
            s = np.repeat(np.arange(live.size), cnt)
    return g
