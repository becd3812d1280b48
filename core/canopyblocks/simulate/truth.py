"""Truth per footprint from the weighted airborne points (seed 002 section 2.2).

Definitions (all heights in metres, in the point cloud's vertical datum):

* **Pseudo-waveform**: the footprint's points weighted by ``exp(-2 r^2/R^2)``, as a
  height density broadened by the instrument point-spread (Gaussian, sigma = PSF):
  ``f(z) = sum_j w_j N(z; z_j, PSF) / sum_j w_j``.  It is the PDF the photons are
  drawn from.
* **Ground**: the lowest peak of ``f``.  Peaks are found on ``f`` sampled in bins of
  ``TruthParams.bin_size`` (0.1 m; bins ``[i b, (i + 1) b)`` for integer ``i``, so the
  result does not depend on which shots are processed together): a bin is a peak when
  it is higher than the bin below, not lower than the bin above, and at least
  ``peak_fraction`` (5 %) of the highest bin.
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
from ..reference.footprint_index import FootprintPairs, _ranges
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
    z, w = pairs.z, pairs.weight
    ids = np.flatnonzero(has)
    starts, ends = pairs.indptr[:-1][has], pairs.indptr[1:][has]
    find = _HeightSearch(z, counts, ids, starts, ends)
    out["weight_sum"][has] = np.add.reduceat(w, starts)
    # ---- top: highest point per footprint (pairs are sorted by height in a shot)
    out["top"][has] = z[ends - 1]
    # ---- ground: lowest peak of the broadened weighted histogram, then mean-shift
    ground = _lowest_peak(z, w, pairs.indptr, has, psf, tp)
    g = _mean_shift(find, z, w, ground[has], psf)
    ground[~has] = np.nan
    ground[has] = g
    out["ground"] = ground
    # heights above ground z - ground increase within each shot: the points above a
    # threshold are the last ones of each shot
    c_cover, c0 = find.first(g, (tp.cover_threshold, rh_floor), True)
    # ---- canopy cover: unweighted share of points above ground + threshold
    out["cover"][has] = (ends - c_cover) / counts[has]
    # ---- RH: weighted inverse-CDF percentiles of canopy heights
    qs = np.asarray(RH_LEVELS, dtype=np.float64) / 100.0 * (1 - 1e-12)
    cw = pairs.prefix((2 + qs.size) * c0.size)
    cbefore, clast = cw.at(np.concatenate([c0 - 1, ends - 1])).reshape(2, -1)
    ctot = clast - cbefore
    idx = cw.search(cbefore + ctot * qs[:, None], right=False)
    idx = np.minimum(np.maximum(idx, c0), ends - 1)
    rh = np.where(c0 < ends, z[idx] - g, 0.0)
    for i, q in enumerate(RH_LEVELS):
        col = np.full(n, np.nan)
        col[has] = rh[i]
        out[f"rh{q}"] = col
    return out


class _HeightSearch:
    """Exact per-shot searches in pairs sorted by (shot, height).

    ``first(g, t, strict)`` is, for each shot with points, the first pair with
    ``z - g > t`` (``>=`` when not strict), or the shot's end: a binary search on a
    key increasing over all pairs, then corrected by the exact comparison.
    """

    def __init__(self, z: np.ndarray, counts: np.ndarray, ids: np.ndarray,
                 starts: np.ndarray, ends: np.ndarray) -> None:
        n = counts.size
        zlo = float(z[starts].min())  # pairs are sorted by height within each shot
        span = 2.0 * (float(z[ends - 1].max()) - zlo) + 2.0
        base = np.arange(n, dtype=np.float64) * span - zlo
        self.key = z + np.repeat(base, counts)  # increasing: shot, then height
        self.base = base[ids]
        self.z, self.ids, self.starts, self.ends = z, ids, starts, ends

    def first(self, g: np.ndarray, t: float | tuple[float, ...],
              strict: bool) -> np.ndarray:
        """First pair of each shot with ``z - g > t`` (``>=``); one row per ``t`` of a tuple."""
        z = self.z
        ts = np.asarray(t, dtype=np.float64).ravel()
        r = ts.size
        if r == 1:
            starts, ends, gg, base, tt = self.starts, self.ends, g, self.base, ts
        else:
            starts, ends, gg, base = (np.tile(a, r) for a in (self.starts, self.ends, g,
                                                               self.base))
            tt = np.repeat(ts, g.size)
        i = np.searchsorted(self.key, (gg + tt) + base, side="right" if strict else "left")
        i = np.minimum(np.maximum(i, starts), ends)
        last = z.size - 1
        for _ in range(64):
            prev = z[np.maximum(i - 1, 0)] - gg
            cur = z[np.minimum(i, last)] - gg
            if strict:
                left = (i > starts) & (prev > tt)
                right = (i < ends) & ~(cur > tt)
            else:
                left = (i > starts) & (prev >= tt)
                right = (i < ends) & ~(cur >= tt)
            if not (left.any() or right.any()):
                return i.reshape(r, -1) if isinstance(t, tuple) else i
            i = i - left + right
        raise AssertionError("height search did not converge")  # pragma: no cover


def _lowest_peak(z: np.ndarray, w: np.ndarray, indptr: np.ndarray,
                 has: np.ndarray, psf: float, tp: TruthParams) -> np.ndarray:
    """Start of the ground climb: the lowest peak of each shot's binned waveform.

    Bins are ``[i b, (i + 1) b)`` for integer ``i`` (a fixed grid); each shot's
    histogram covers its own height range plus more than the filter's reach, so the
    histograms of all shots are laid end to end and smoothed at once without mixing.
    NaN for shots without points.
    """
    n = has.size
    b = tp.bin_size
    pad = int(math.ceil((4.0 * psf + 2.0 * b) / b))  # > the filter's radius of 4 PSF
    ab = np.floor(z / b).astype(np.int64)
    starts, ends = indptr[:-1][has], indptr[1:][has]
    lo = ab[starts] - pad
    size = ab[ends - 1] + pad + 1 - lo
    if int(size.max()) > MAX_BINS:
        raise InputError(
            f"airborne point heights span {(int(size.max()) - 2 * pad) * b:.0f} m inside "
            "one footprint; the cloud holds outliers (birds, noise): drop them (ASPRS "
            "classes 7/18 are excluded by default) or crop the cloud")
    first_bin = np.cumsum(size) - size  # each shot's first bin in the flat histogram
    ab += np.repeat(first_bin - lo, ends - starts)
    hist = np.bincount(ab, weights=w, minlength=int(size.sum()))
    wave = gaussian_filter1d(hist, psf / b, mode="constant", truncate=4.0)
    top = np.maximum.reduceat(wave, first_bin)
    # a bin is a peak when higher than the bin below, not lower than the bin above and
    # at least peak_fraction of its shot's highest bin; the shots' edge bins are zero
    mid = wave[1:-1]
    peak = (mid > wave[:-2]) & (mid >= wave[2:]) & (mid > 0)
    peak &= mid >= tp.peak_fraction * np.repeat(top, size)[1:-1]
    pos = np.flatnonzero(peak) + 1
    at = pos[np.minimum(np.searchsorted(pos, first_bin), pos.size - 1)]
    # parabolic vertex through the peak bin and its neighbours: the mean-shift start
    y0, y1, y2 = wave[at - 1], wave[at], wave[at + 1]
    den = y0 - 2.0 * y1 + y2
    off = np.where(den < 0, 0.5 * (y0 - y2) / np.where(den < 0, den, -1.0), 0.0)
    out = np.full(n, np.nan)
    out[has] = (lo + (at - first_bin) + 0.5 + np.clip(off, -0.5, 0.5)) * b
    return out


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
    g = start.copy()
    reach = 5.0 * psf
    lo = find.first(g, -reach, False)
    cnt = find.first(g, reach, True) - lo
    live = np.flatnonzero(cnt > 0)  # shots still climbing (index into start)
    lo, cnt = lo[live], cnt[live]
    sel = _ranges(lo, cnt)
    zz, ww = np.take(z, sel, mode="clip"), np.take(w, sel, mode="clip")
    inv = -0.5 / (psf * psf)
    inv_var = 1.0 / (psf * psf)
    limit = 0.5 * psf
    for _ in range(_MEANSHIFT_ITER):
        if not live.size:
            break
        first = np.cumsum(cnt) - cnt
        d = zz - np.repeat(g[live], cnt)
        k = d * d
        k *= inv
        np.exp(k, out=k)
        k *= ww
        den = np.add.reduceat(k, first)
        k *= d
        d1 = np.add.reduceat(k, first)
        k *= d
        d2 = np.add.reduceat(k, first)
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
            keep = np.repeat(~done, cnt)
            zz, ww = zz[keep], ww[keep]
            live, cnt = live[~done], cnt[~done]
    return g
