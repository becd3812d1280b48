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
from .gauss_trf import trf_many

__all__ = ["decompose_waveforms", "fit_gaussians"]

log = logging.getLogger(__name__)

_SMOOTH = 3.0         # samples, the smoothing of the initial-peak search
_MARGIN = 15          # samples added on both sides of the signal window
_MIN_SIGMA = 2.0      # samples (GEDI's pulse sd is about 6.6 ns = 6.6 samples)
_MAX_SIGMA = 60.0
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


def _fit_all(problems: list[_Problem | None]) -> list[np.ndarray]:
    """Gaussians (g, 3) of every problem, sorted by centre; the shots with the same
    number of Gaussians are fitted together (:func:`.gauss_lm.fit_many`)."""
    out: list[np.ndarray] = [np.zeros((0, 3)) for _ in problems]
    by_count: dict[int, list[int]] = {}
    for i, prob in enumerate(problems):
        if prob is not None:
            by_count.setdefault(len(prob.p0), []).append(i)
    for n_par, idx in by_count.items():
        for a in range(0, len(idx), _FIT_ROWS):
            rows = idx[a:a + _FIT_ROWS]
            probs = [problems[i] for i in rows]
            width = max(pr.hi - pr.lo for pr in probs if pr is not None)
            x = np.zeros((len(rows), width))
            y = np.zeros((len(rows), width))
            wt = np.zeros((len(rows), width))
            p0 = np.empty((len(rows), n_par))
            lower = np.empty_like(p0)
            upper = np.empty_like(p0)
            for k, pr in enumerate(probs):
                assert pr is not None
                length = pr.hi - pr.lo
                x[k] = pr.lo + np.arange(width)
                y[k, :length] = pr.y
                wt[k, :length] = 1.0
                p0[k], lower[k], upper[k] = pr.p0, pr.lower, pr.upper
            if n_par > 3:
                # Several Gaussians: several local minima, the path decides which one is
                # reached: scipy's reflective trust region, step for step, on the batch
                # (a plain Levenberg-Marquardt reached another minimum in 6 of the 64
                # such bundled shots)
                params = trf_many(x, y, wt, p0, lower, upper, 200 * (n_par // 3))
                settled = np.isfinite(params).all(axis=1)
            else:
                params, settled = fit_many(x, y, wt, p0, lower, upper)
            for k, i in enumerate(rows):
                pr = problems[i]
                assert pr is not None
                p = params[k] if settled[k] else _fit_one(pr)
                g = p.reshape(-1, 3)
                out[i] = g[np.argsort(g[:, 1])]
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
    y = np.asarray(y, dtype=np.float64)
    s = gaussian_filter1d(y, smooth, mode="nearest")
    return _fit_all([_problem(y, s, threshold, max_gaussians)])[0]


def _lowest_peak(g: np.ndarray, m: int) -> float:
    """Position (samples) of the lowest local maximum of the fitted model made by one of
    the Gaussians ``g``: a Gaussian fitted to the trailing edge of a return (GEDI's pulse
    is not symmetric) adds no peak of its own and so is not a ground."""
    if not g.size:
        return float("nan")
    # only the grid points within reach of a centre (and one either side) can be such a
    # peak: the model there, on the same grid, is the whole model's
    reach = np.maximum(g[:, 2], 1.0)
    n_grid = len(np.arange(0.0, m, 0.25))
    i0 = max(0, int(np.floor(float((g[:, 1] - reach).min()) / 0.25)) - 1)
    i1 = min(n_grid, int(np.ceil(float((g[:, 1] + reach).max()) / 0.25)) + 2)
    x = np.arange(i0, max(i0, i1), dtype=np.float64) * 0.25
    if x.size < 3:
        return float("nan")
    y = _model(x, g.reshape(-1))
    peaks = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:])) + 1
    if peaks.size == 0:
        return float("nan")
    xp = x[peaks]
    near = np.abs(xp[:, None] - g[None, :, 1]) <= np.maximum(g[None, :, 2], 1.0)
    made = xp[near.any(axis=1)]
    return float(made.max()) if made.size else float("nan")


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
    count = np.zeros(n, dtype=np.int64)
    gaussians: list[np.ndarray] = []
    resid = batch.waveforms.astype(np.float64) - batch.noise_mean[:, None]
    resid[~batch.sample_mask()] = 0.0
    thr = k * np.asarray(batch.noise_sd, dtype=np.float64)
    step = np.where(batch.n_samples > 1, (batch.elev_lastbin - batch.elev_bin0)
                    / np.maximum(batch.n_samples - 1, 1), np.nan)
    usable = (batch.n_samples >= 3) & np.isfinite(thr) & (thr > 0)
    smoothed = _smooth_by_length(resid, batch.n_samples, usable, "nearest")
    problems = [_problem(resid[i, :int(batch.n_samples[i])],
                         smoothed[i, :int(batch.n_samples[i])], float(thr[i]), max_gaussians)
                if usable[i] else None for i in range(n)]
    prog.update(0.1, f"decomposition {batch.beam}: fitting {n} shots")
    fits = _fit_all(problems)
    prog.update(0.9, f"decomposition {batch.beam}: {n} shots fitted")
    top_smooth = _smooth_by_length(resid, batch.n_samples, usable, "reflect")
    for i in range(n):   # per shot: a few Gaussians each
        m = int(batch.n_samples[i])
        g = fits[i]
        if g.size:
            energy = g[:, 0] * g[:, 2]
            share = energy / energy.sum() if energy.sum() > 0 else np.zeros(len(g))
            good = (g[:, 0] >= thr[i]) & (share >= min_share)
            count[i] = len(g)
            pos = _lowest_peak(g[good], m)
            if np.isfinite(pos):
                ground[i] = batch.elev_bin0[i] + pos * step[i]
            first = np.flatnonzero(top_smooth[i, :m] > thr[i])
            if first.size:
                top[i] = batch.elev_bin0[i] + first[0] * step[i]
        gaussians.append(np.column_stack([g[:, 0], batch.elev_bin0[i] + g[:, 1] * step[i],
                                          np.abs(g[:, 2] * step[i])]) if g.size else g)
    prog.update(1.0, f"decomposition {batch.beam}: {n} shots")
    out = pd.DataFrame({"shot_number": np.asarray(batch.shot_number).astype(np.int64),
                        "ground_gauss": ground, "top_gauss": top,
                        "height_gauss": top - ground, "n_gaussians": count})
    out.attrs["gaussians"] = gaussians
    return out
