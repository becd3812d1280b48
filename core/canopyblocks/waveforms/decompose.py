"""Gaussian decomposition of received waveforms (seed 003, after Hofton et al. 2000;
DESIGN 4.4).

Per shot: the waveform minus its noise mean is smoothed (Gaussian, 3 samples); the
initial peaks are its local maxima above the threshold, each with a width from the
neighbouring inflection points (zero crossings of the second derivative); a sum of at
most ``max_gaussians`` Gaussians is fitted to the unsmoothed samples of the signal window
by bounded least squares. Ground = the lowest Gaussian whose amplitude reaches the
threshold and that holds at least ``min_share`` of the fitted energy; top = the first
sample above the threshold.

The smoothing (one call per shot length), thresholds, windows and initial peaks are
done for the whole batch, and the fits too, the shots with the same number of Gaussians
together: one Gaussian (~75 % of GEDI shots) by a batched Levenberg-Marquardt
(:mod:`.gauss_lm`: the same minimum), several by scipy's bounded trust-region
reflective method taken step for step on the whole batch (:mod:`.gauss_trf`: such fits
have several local minima and the path decides which one is reached; the batch follows
scipy's path, to 2e-12 on the bundled shots), both with an analytic Jacobian. A shot
the batch cannot settle is fitted alone by scipy. Against the per-shot fits with a
numerical Jacobian this replaces: the same Gaussians, ground and top on the bundled
shots, parameters within 1e-4 relative -- inside the reach of scipy's default stopping
tolerances, which leave them up to 8e-4 from the least-squares minimum on those shots.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pandas as pd
from scipy.ndimage import gaussian_filter1d
from scipy.optimize import least_squares

from ..errors import InputError
from ..progress import Progress, as_progress
from .batch import WaveformBatch
from .gauss_lm import _model_and_jacobian, fit_many
from .gauss_start import MARGIN as _MARGIN
from .gauss_start import MAX_SIGMA as _MAX_SIGMA
from .gauss_start import MIN_SIGMA as _MIN_SIGMA
from .gauss_start import FitStarts, fit_starts
from .gauss_trf import trf_many

__all__ = ["decompose_waveforms", "fit_gaussians"]

log = logging.getLogger(__name__)

_SMOOTH = 3.0         # samples, the smoothing of the initial-peak search
_FIT_ROWS = 2048     # shots fitted together at most


def _initial_peaks(s: np.ndarray, thr: float, max_n: int) -> list[tuple[float, float, float]]:
    """(amplitude, centre, sigma) in samples of the local maxima of ``s`` above ``thr``."""
    if s.size < 3:
        return []
    peak = np.flatnonzero((s[1:-1] > s[:-2]) & (s[1:-1] >= s[2:]) & (s[1:-1] > thr)) + 1
    if peak.size == 0:
        return []
    d2 = np.diff(s, 2)
    sign = np.sign(d2)
    infl = np.flatnonzero(sign[:-1] != sign[1:]) + 1.5    # zero crossings, sample units
    # the inflection points either side of each peak (they lie between samples)
    k = np.searchsorted(infl, peak)
    lo = np.where(k > 0, infl[np.maximum(k - 1, 0)] if infl.size else 0.0, peak - _MIN_SIGMA)
    hi = np.where(k < infl.size, infl[np.minimum(k, max(infl.size - 1, 0))] if infl.size
                  else 0.0, peak + _MIN_SIGMA)
    sigma = np.clip((hi - lo) / 2.0, _MIN_SIGMA, _MAX_SIGMA)
    out = list(zip(s[peak].tolist(), peak.astype(np.float64).tolist(), sigma.tolist()))
    out.sort(key=lambda t: -t[0])
    return sorted(out[:max_n], key=lambda t: t[1])


def _model(x: np.ndarray, p: np.ndarray) -> np.ndarray:
    a, c, w = p[0::3], p[1::3], p[2::3]
    return (a[:, None] * np.exp(-0.5 * ((x[None, :] - c[:, None]) / w[:, None]) ** 2)).sum(0)


@dataclass(frozen=True)
class _Problem:
    """One shot's fit: window ``lo .. hi - 1`` (samples), start and bounds."""

    y: np.ndarray
    lo: int
    hi: int
    p0: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


def _problem(y: np.ndarray, s: np.ndarray, threshold: float, max_gaussians: int
             ) -> _Problem | None:
    """The fit of one shot from its samples ``y`` and smoothed copy ``s`` (or None)."""
    init = _initial_peaks(s, threshold, max_gaussians)
    if not init:
        return None
    above = np.flatnonzero(s > threshold)
    lo = max(0, int(above[0]) - _MARGIN)
    hi = min(y.size, int(above[-1]) + _MARGIN + 1)
    yy = y[lo:hi]
    p0 = np.array([v for g in init for v in g])
    amax = max(float(yy.max()), threshold) * 2.0
    lb = np.empty(len(p0))
    ub = np.empty(len(p0))
    lb[0::3], lb[1::3], lb[2::3] = 0.0, lo, _MIN_SIGMA
    ub[0::3], ub[1::3], ub[2::3] = amax, hi - 1.0, _MAX_SIGMA
    p0 = np.clip(p0, lb + 1e-9, ub - 1e-9)
    return _Problem(yy, lo, hi, p0, lb, ub)


def _fit_one(prob: _Problem) -> np.ndarray:
    """Bounded trust-region fit of one shot (scipy), for the shots the batch leaves."""
    x = np.arange(prob.lo, prob.hi, dtype=np.float64)
    ones = np.ones((1, len(x)))

    def jac(p: np.ndarray) -> np.ndarray:
        return _model_and_jacobian(x[None, :], p[None, :], ones)[1][0]

    try:
        fit = least_squares(lambda p: _model(x, p) - prob.y, prob.p0, jac=jac,
                            bounds=(prob.lower, prob.upper), method="trf",
                            x_scale="jac", max_nfev=200 * (len(prob.p0) // 3))
        return np.asarray(fit.x)
    except (ValueError, np.linalg.LinAlgError):   # degenerate window: keep the guess
        return prob.p0


def _fit_group(resid: np.ndarray, st: FitStarts, rows: np.ndarray, n_gauss: int
               ) -> np.ndarray:
    """Gaussians (len(rows), n_gauss, 3) of the shots ``rows``, which all have
    ``n_gauss``, each sorted by centre; fitted together, ``_FIT_ROWS`` at a time."""
    n_par = 3 * n_gauss
    out = np.empty((len(rows), n_gauss, 3))
    for a in range(0, len(rows), _FIT_ROWS):
        r = rows[a:a + _FIT_ROWS]
        length = st.hi[r] - st.lo[r]
        k = np.arange(int(length.max()))
        x = (st.lo[r][:, None] + k).astype(np.float64)
        wt = (k[None, :] < length[:, None]).astype(np.float64)
        cols = np.minimum(st.lo[r][:, None] + k, resid.shape[1] - 1)
        y = np.where(wt > 0, resid[r[:, None], cols], 0.0)
        p0, lower, upper = st.p0[r, :n_par], st.lower[r, :n_par], st.upper[r, :n_par]
        if n_par > 3:
            # Several Gaussians: several local minima, the path decides which one is
            # reached: scipy's reflective trust region, step for step, on the batch
            # (a plain Levenberg-Marquardt reached another minimum in 6 of the 64
            # such bundled shots)
            params = trf_many(x, y, wt, p0, lower, upper, 200 * n_gauss)
            settled = np.isfinite(params).all(axis=1)
        else:
            params, settled = fit_many(x, y, wt, p0, lower, upper)
        for j in np.flatnonzero(~settled):
            n = int(length[j])
            params[j] = _fit_one(_Problem(y[j, :n], int(st.lo[r[j]]), int(st.hi[r[j]]),
                                          p0[j], lower[j], upper[j]))
        g = params.reshape(len(r), n_gauss, 3)
        order = np.argsort(g[:, :, 1], axis=1)
        out[a:a + len(r)] = np.take_along_axis(g, order[:, :, None], axis=1)
    return out


def fit_gaussians(y: npt.ArrayLike, threshold: float, *, max_gaussians: int = 10,
                  smooth: float = _SMOOTH) -> np.ndarray:
    """Gaussians fitted to one noise-free waveform ``y`` (waveform minus noise mean).

    Parameters
    ----------
    y : array (m,)
        Samples (counts above the noise mean).
    threshold : float
        Detection threshold above the noise mean (counts).
    max_gaussians : int
    smooth : float
        Smoothing sd (samples) of the initial-peak search.

    Returns
    -------
    ndarray (g, 3)
        Amplitude (counts), centre and sigma (samples), sorted by centre; empty when
        nothing exceeds the threshold.
    """
    y = np.asarray(y, dtype=np.float64).reshape(1, -1)
    s = gaussian_filter1d(y, smooth, axis=1, mode="nearest")
    thr = np.array([float(threshold)])
    st = fit_starts(y, s, np.array([y.shape[1]]), thr, np.array([y.shape[1] >= 3]),
                    max_gaussians)
    if not st.count[0]:
        return np.zeros((0, 3))
    return _fit_group(y, st, np.array([0]), int(st.count[0]))[0]


def _lowest_peaks(g: np.ndarray, good: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Per shot, the position (samples) of the lowest local maximum of the model of its
    ``good`` Gaussians ``g`` (R, k, 3) that one of them makes (NaN: none), on a grid of
    0.25 samples over ``0 .. m``: a Gaussian fitted to the trailing edge of a return
    (GEDI's pulse is not symmetric) adds no peak of its own and so is not a ground.

    Only the grid points within reach of a centre (and one either side) can be such a
    peak, and the model there, on the same grid, is the whole model's; the grids of all
    shots are laid end to end and the model summed Gaussian by Gaussian in centre order
    (the others weighted 0), as the per-shot sum."""
    n_rows, k = good.shape
    out = np.full(n_rows, np.nan)
    a = np.where(good, g[:, :, 0], 0.0)
    c, w = g[:, :, 1], g[:, :, 2]
    reach = np.maximum(w, 1.0)
    with np.errstate(invalid="ignore"):
        lo = np.floor(np.where(good, c - reach, np.inf).min(axis=1) / 0.25) - 1
        hi = np.ceil(np.where(good, c + reach, -np.inf).max(axis=1) / 0.25) + 2
    has = good.any(axis=1)
    i0 = np.where(has, np.maximum(0, lo), 0).astype(np.int64)
    i1 = np.where(has, np.minimum(4 * m, hi), 0).astype(np.int64)
    length = np.maximum(i1 - i0, 0)
    length[length < 3] = 0
    if not length.any():
        return out
    row = np.repeat(np.arange(n_rows), length)
    first = np.cumsum(length) - length
    step = np.arange(len(row)) - first[row]
    x = (i0[row] + step).astype(np.float64) * 0.25
    y = a[row, 0] * np.exp(-0.5 * ((x - c[row, 0]) / w[row, 0]) ** 2)
    for j in range(1, k):
        y = y + a[row, j] * np.exp(-0.5 * ((x - c[row, j]) / w[row, j]) ** 2)
    inner = np.flatnonzero((step >= 1) & (step <= length[row] - 2))
    pk = inner[(y[inner] > y[inner - 1]) & (y[inner] >= y[inner + 1])]
    rp, xp = row[pk], x[pk]
    made = ((np.abs(xp[:, None] - c[rp]) <= reach[rp]) & good[rp]).any(axis=1)
    rp, xp = rp[made], xp[made]
    if len(rp):   # the grid is ascending within a shot: its last peak is the highest
        last = np.append(rp[1:] != rp[:-1], True)
        out[rp[last]] = xp[last]
    return out


def _smooth_by_length(resid: np.ndarray, n_samples: np.ndarray, rows: np.ndarray,
                      mode: str) -> np.ndarray:
    """``gaussian_filter1d(resid[i, :m_i], _SMOOTH, mode=mode)`` of the ``rows``, the
    shots of one length at a time (one call per length, the same numbers)."""
    out = np.zeros_like(resid)
    lengths = np.where(rows, n_samples, 0)
    for m in np.unique(lengths[lengths > 0]):
        sel = np.nonzero(lengths == m)[0]
        out[sel, :m] = gaussian_filter1d(resid[sel, :m], _SMOOTH, axis=1, mode=mode)
    return out


def decompose_waveforms(batch: WaveformBatch, *, max_gaussians: int = 10,
                        k: float = 4.0, min_share: float = 0.05,
                        progress: Progress | None = None) -> pd.DataFrame:
    """Gaussian decomposition of every shot of a batch (DESIGN 4.4).

    Parameters
    ----------
    batch : WaveformBatch
    max_gaussians : int
        At most this many Gaussians per shot (seed 003: 10).
    k : float
        Threshold = noise mean + k * noise sd (the batch's noise statistics).
    min_share : float
        A ground Gaussian must hold at least this share of the fitted energy.

    Returns
    -------
    DataFrame
        One row per shot: ``shot_number``, ``ground_gauss`` and ``top_gauss`` (m, the
        batch's vertical datum), ``height_gauss`` (m), ``n_gaussians``; NaN where no
        Gaussian passes. ``attrs["gaussians"]``: per shot an array (g, 3) of amplitude
        (counts), centre elevation (m) and sigma (m).
    """
    if isinstance(max_gaussians, bool) or not isinstance(max_gaussians, int) \
            or max_gaussians < 1:
        raise InputError(f"max_gaussians must be a positive integer; got {max_gaussians!r}")
    if not (0 <= min_share < 1):
        raise InputError(f"min_share must be in [0, 1); got {min_share!r}")
    prog = as_progress(progress)
    n = len(batch)
    ground = np.full(n, np.nan)
    top = np.full(n, np.nan)
    resid = batch.waveforms.astype(np.float64) - batch.noise_mean[:, None]
    resid[~batch.sample_mask()] = 0.0
    thr = k * np.asarray(batch.noise_sd, dtype=np.float64)
    step = np.where(batch.n_samples > 1, (batch.elev_lastbin - batch.elev_bin0)
                    / np.maximum(batch.n_samples - 1, 1), np.nan)
    n_samples = np.asarray(batch.n_samples, dtype=np.int64)
    usable = (n_samples >= 3) & np.isfinite(thr) & (thr > 0)
    smoothed = _smooth_by_length(resid, n_samples, usable, "nearest")
    st = fit_starts(resid, smoothed, n_samples, thr, usable, max_gaussians)
    count = st.count
    prog.update(0.1, f"decomposition {batch.beam}: fitting {n} shots")
    # the top: the first sample of the (reflect-)smoothed waveform above the threshold
    top_smooth = _smooth_by_length(resid, n_samples, count > 0, "reflect")
    above = (top_smooth > thr[:, None]) & (np.arange(resid.shape[1]) < n_samples[:, None]) \
        & (count > 0)[:, None]
    first = np.argmax(above, axis=1)
    top = np.where(above.any(axis=1), batch.elev_bin0 + first * step, top)
    ends = np.cumsum(count)
    table = np.empty((int(ends[-1]) if n else 0, 3))
    for n_gauss in np.unique(count[count > 0]).tolist():
        rows = np.flatnonzero(count == n_gauss)
        g = _fit_group(resid, st, rows, n_gauss)
        energy = g[:, :, 0] * g[:, :, 2]
        total = energy.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(total[:, None] > 0, energy / total[:, None], 0.0)
        good = (g[:, :, 0] >= thr[rows, None]) & (share >= min_share)
        pos = np.concatenate([_lowest_peaks(g[a:a + _FIT_ROWS], good[a:a + _FIT_ROWS],
                                            n_samples[rows[a:a + _FIT_ROWS]])
                              for a in range(0, len(rows), _FIT_ROWS)])
        ground[rows] = np.where(np.isfinite(pos), batch.elev_bin0[rows] + pos * step[rows],
                                np.nan)
        at = (ends[rows] - n_gauss)[:, None] + np.arange(n_gauss)
        table[at, 0] = g[:, :, 0]
        table[at, 1] = batch.elev_bin0[rows, None] + g[:, :, 1] * step[rows, None]
        table[at, 2] = np.abs(g[:, :, 2] * step[rows, None])
    prog.update(1.0, f"decomposition {batch.beam}: {n} shots")
    out = pd.DataFrame({"shot_number": np.asarray(batch.shot_number).astype(np.int64),
                        "ground_gauss": ground, "top_gauss": top,
                        "height_gauss": top - ground, "n_gaussians": count})
    out.attrs["gaussians"] = np.split(table, ends[:-1]) if n else []
    return out
