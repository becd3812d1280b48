"""Truth per footprint from the weighted airborne points (seed 002 section 2.2).

Definitions (all heights in metres, in the point cloud's vertical datum):

* **Pseudo-waveform**: the footprint's points weighted by ``exp(-2 r^2/R^2)``, as a
  height density broadened by the instrument point-spread (Gaussian, sigma = PSF):
  ``f(z) = sum_j w_j N(z; z_j, PSF) / sum_j w_j``.  It is the PDF the photons are
  drawn from.
* **Ground**: the lowest peak of ``f``.  Peaks are found on ``f`` sampled in bins of
  ``TruthParams.bin_size`` (0.1 m): a bin is a peak when it is higher than the bin below,
  not lower than the bin above, and at least ``peak_fraction`` (5 %) of the highest bin.
  The lowest such peak (refined by a parabola through three bins) is then climbed to
  the exact mode of ``f`` by Newton/mean-shift iterations on the Gaussian mixture
  (to ~1e-6 m), so the result does not depend on the bin grid: flat ground at
  ``z0`` gives exactly ``z0``.
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
from .footprints import FootprintPairs
from .params import TruthParams

__all__ = ["RH_LEVELS", "footprint_truth", "MAX_BINS"]

#: RH percentiles reported per footprint.
RH_LEVELS: tuple[int, ...] = (50, 60, 75, 90, 95)

#: Refuse a pseudo-waveform grid longer than this (points 1 km apart in height).
MAX_BINS = 20_000

_MEANSHIFT_ITER = 30


def footprint_truth(pairs: FootprintPairs, psf: float, tp: TruthParams,
                    rh_floor: float) -> dict[str, np.ndarray]:
    """Truth of every footprint of a chunk.

    Parameters
    ----------
    pairs : FootprintPairs
        Points per footprint with weights.
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
    n = pairs.n_shots
    counts = pairs.counts
    out: dict[str, np.ndarray] = {
        "ground": np.full(n, np.nan), "top": np.full(n, np.nan),
        **{f"rh{q}": np.full(n, np.nan) for q in RH_LEVELS},
        "cover": np.full(n, np.nan), "n_points": counts.astype(np.int64),
        "weight_sum": np.bincount(pairs.shot, weights=pairs.weight, minlength=n),
    }
    has = counts > 0
    if not has.any():
        return out
    shot, z, w = pairs.shot, pairs.z, pairs.weight
    # ---- top: highest point per footprint (pairs are sorted by shot)
    starts = pairs.indptr[:-1][has]
    out["top"][has] = np.maximum.reduceat(z, starts)
    # ---- ground: lowest peak of the broadened weighted histogram, then mean-shift
    ground = _lowest_peak(shot, z, w, n, psf, tp)
    ground = _mean_shift(shot, z, w, ground, psf)
    ground[~has] = np.nan
    out["ground"] = ground
    hag = z - ground[shot]
    # ---- canopy cover: unweighted share of points above ground + threshold
    above = hag > tp.cover_threshold
    out["cover"][has] = (np.bincount(shot, weights=above.astype(np.float64), minlength=n)[has]
                         / counts[has])
    # ---- RH: weighted inverse-CDF percentiles of canopy heights
    rh = _weighted_percentiles(shot, hag, w, n, rh_floor, np.asarray(RH_LEVELS) / 100.0)
    for i, q in enumerate(RH_LEVELS):
        col = rh[:, i]
        col[~has] = np.nan
        out[f"rh{q}"] = col
    return out


def _lowest_peak(shot: np.ndarray, z: np.ndarray, w: np.ndarray, n: int, psf: float,
                 tp: TruthParams) -> np.ndarray:
    b = tp.bin_size
    pad = 4.0 * psf + 2.0 * b
    zlo = float(z.min()) - pad
    nb = int(math.ceil((float(z.max()) + pad - zlo) / b)) + 1
    if nb > MAX_BINS:
        raise InputError(
            f"airborne point heights span {z.max() - z.min():.0f} m inside a few footprints; "
            "the cloud holds outliers (birds, noise): drop them (ASPRS classes 7/18 are "
            "excluded by default) or crop the cloud")
    bi = np.minimum(((z - zlo) / b).astype(np.int64), nb - 1)
    hist = np.bincount(shot * nb + bi, weights=w, minlength=n * nb).reshape(n, nb)
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
    return zlo + (first + 0.5 + np.clip(off, -0.5, 0.5)) * b


def _mean_shift(shot: np.ndarray, z: np.ndarray, w: np.ndarray, start: np.ndarray,
                psf: float) -> np.ndarray:
    """Climb from ``start`` to the nearest mode of each footprint's Gaussian mixture.

    Newton steps on the mixture's derivative where it is concave, mean-shift steps
    elsewhere; steps are limited to 0.5 PSF so the climb stays on the starting peak.
    """
    n = start.size
    g = start.copy()
    reach = 5.0 * psf
    near = np.abs(z - g[shot]) <= reach
    s, zz, ww = shot[near], z[near], w[near]
    inv = -0.5 / (psf * psf)
    inv_var = 1.0 / (psf * psf)
    limit = 0.5 * psf
    for _ in range(_MEANSHIFT_ITER):
        d = zz - g[s]
        k = ww * np.exp(inv * d * d)
        den = np.bincount(s, weights=k, minlength=n)
        d1 = np.bincount(s, weights=k * d, minlength=n)
        d2 = np.bincount(s, weights=k * d * d, minlength=n)
        curv = den - d2 * inv_var
        safe_den = np.where(den > 0, den, 1.0)
        step = np.where(curv > 1e-12 * safe_den, d1 / np.where(curv > 0, curv, 1.0),
                        d1 / safe_den)
        step = np.where(den > 0, np.clip(step, -limit, limit), 0.0)
        g = g + step
        # Newton converges quadratically: after a step below 2e-4 m the remaining
        # error is ~(2e-4)^2 / PSF, far below a millimetre
        if not n or float(np.max(np.abs(step))) < 2e-4:
            break
    return g


def _weighted_percentiles(shot: np.ndarray, hag: np.ndarray, w: np.ndarray, n: int,
                          floor: float, qs: np.ndarray) -> np.ndarray:
    """Per shot, the smallest ``hag`` whose cumulative weight share reaches each ``q``."""
    out = np.zeros((n, qs.size))
    sel = hag > floor
    if not sel.any():
        return out
    s, h, ww = shot[sel], hag[sel], w[sel]
    span = float(h.max()) + 1.0
    order = np.argsort(s * span + h, kind="stable")
    s, h, ww = s[order], h[order], ww[order]
    tot = np.bincount(s, weights=ww, minlength=n)
    cnt = np.bincount(s, minlength=n)
    first = np.cumsum(cnt) - cnt
    csum = np.cumsum(ww)
    before = np.concatenate([[0.0], csum])[first]  # cumulative weight before each shot
    frac = (csum - before[s]) / tot[s]
    key = s + np.minimum(frac, 1.0)
    present = np.flatnonzero(cnt > 0)
    for i, q in enumerate(qs):
        idx = np.searchsorted(key, present + q * (1 - 1e-12), side="left")
        idx = np.minimum(idx, first[present] + cnt[present] - 1)
        out[present, i] = h[idx]
    return out
