"""Dual-wavelength ground finding (seed 004, DESIGN 4.8).

Leaves reflect far more in the near infrared than in the visible; soil reflects both
alike. So the ratio visible / near-infrared of a waveform pair is low through the canopy
and jumps where the ground return starts, even when topography or understory blurs the
ground into the canopy in either band alone.

Per shot (all shots of a batch at once; samples ordered from the highest elevation, as
in :class:`~canopyblocks.waveforms.batch.WaveformBatch`):

1. both bands de-noised with one Gaussian (``denoise`` samples; one filter keeps their
   ratio), then a common above-noise mask: samples where both exceed their thresholds;
2. the ratio visible / near-infrared inside the mask;
3. the ratio smoothed with Gaussians of decreasing width (normalised convolution, so
   the mask's edges do not leak); for each width, the zero crossings of the third
   derivative bound a window that avoids the large gradients of the signal start and
   end; inside it, the zero crossings of the second derivative are the maximum-gradient
   candidates. The narrowest width that leaves a single such crossing is kept (the best
   localised edge);
4. that crossing is the ground start; the last sample above noise is the ground end;
   their mean is the ground centre;
5. tree height: from the first sample above noise (the first signal return) to the
   ground start (the first ground return), as the paper takes it.

That is the whole paper method (``method="paper"``, the default). ``method="refined"``
adds three steps of this project's that the paper does not have, measured against it in
``bench/bench_esfl_dual_study.py``: the search confined to the lowest above-noise run;
where that run is separated from the canopy by a gap and its ratio is clearly the soil's,
the run's first sample taken as the start (``width`` 0); and maxima of the gradient
weaker than a fifth of the steepest rise ignored.

Shots where no width leaves a single crossing get NaN and ``found = False``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..errors import InputError

__all__ = ["DualParams", "DualGround", "dual_wavelength_ground"]

log = logging.getLogger(__name__)

#: A gradient of the smoothed ratio counts as a rise only above this share of the shot's
#: largest ratio (far below any rise in a waveform with noise; far above float rounding).
RISE_FLOOR = 1e-6


@dataclass(frozen=True)
class DualParams:
    """Parameters of :func:`dual_wavelength_ground`.

    Attributes
    ----------
    widths : tuple of float
        Gaussian smoothing sigmas tried, in samples, from wide to narrow.
    k : float
        Noise threshold = noise mean + k * noise sd, per band (seed 003: 4).
    denoise : float
        Gaussian sigma (samples) applied to both bands before the ratio (0: none).
    method : str
        ``"paper"`` (the published steps only) or ``"refined"`` (module docstring).
    gap_ratio : float
        ``"refined"`` only: the lowest above-noise run counts as ground separated from
        the canopy by a gap when its mean ratio exceeds the canopy's by this factor.
    """

    widths: tuple[float, ...] = (32.0, 24.0, 16.0, 12.0, 8.0, 6.0, 4.0, 3.0, 2.0, 1.5, 1.0)
    k: float = 4.0
    gap_ratio: float = 1.5
    denoise: float = 2.0
    method: str = "paper"

    def __post_init__(self) -> None:
        from ..arguments import check_fields
        check_fields(self)   # every field against its annotation, at the door
        if isinstance(self.widths, (str, bytes)) or np.ndim(self.widths) != 1:
            raise InputError(f"DualParams: widths must be a sequence of smoothing widths "
                             f"(samples), wide to narrow; got {self.widths!r}")
        if not self.widths or any(not (np.isfinite(w) and w > 0) for w in self.widths):
            raise InputError(f"smoothing widths must be positive numbers of samples, got "
                             f"{self.widths!r}")
        if list(self.widths) != sorted(self.widths, reverse=True):
            raise InputError("smoothing widths must be given from wide to narrow")
        if not (np.isfinite(self.k) and self.k > 0):
            raise InputError(f"k must be positive, got {self.k!r}")
        if self.method not in ("paper", "refined"):
            raise InputError(f"method must be 'paper' or 'refined'; got {self.method!r}")


@dataclass(frozen=True)
class DualGround:
    """Per shot: fractional sample positions of the first signal return, the ground
    start, end and centre, the smoothing width kept (samples), and whether a single edge
    was found."""

    start: np.ndarray
    end: np.ndarray
    centre: np.ndarray
    width: np.ndarray
    found: np.ndarray
    first: np.ndarray | None = None

    def tree_height(self, bin_size: float) -> np.ndarray:
        """Tree height (m): first signal return to the ground start, ``bin_size`` m per
        sample; NaN where no ground was found."""
        if not bin_size > 0:
            raise InputError(f"bin_size must be > 0 m; got {bin_size!r}")
        first = self.first if self.first is not None else np.full_like(self.start, np.nan)
        return (np.asarray(self.start, float) - np.asarray(first, float)) * float(bin_size)


def _crossings(d: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Boolean (n, m-1): a sign change of ``d`` between samples j and j+1 inside ``valid``."""
    s = np.sign(d)
    both = valid[:, :-1] & valid[:, 1:]
    return both & (s[:, :-1] * s[:, 1:] < 0)


def dual_wavelength_ground(visible: np.ndarray, nir: np.ndarray, *,
                           noise_mean: tuple[np.ndarray, np.ndarray],
                           noise_sd: tuple[np.ndarray, np.ndarray],
                           params: DualParams | None = None) -> DualGround:
    """Ground start, end and centre of waveform pairs (seed 004).

    Parameters
    ----------
    visible, nir : ndarray, shape (n, m)
        The two bands' waveforms of ``n`` shots on one sample grid (sample 0 highest).
    noise_mean, noise_sd : (ndarray, ndarray)
        Per band (visible, nir), per shot noise mean and standard deviation.
    params : DualParams, optional

    Returns
    -------
    DualGround
        Fractional sample positions; convert with ``WaveformBatch.elevation``.
    """
    from ..arguments import check_array, check_instance, check_optional
    check_array(visible, "dual_wavelength_ground: visible", ndim=2)
    check_array(nir, "dual_wavelength_ground: nir", ndim=2)
    for k, v in (("noise_mean", noise_mean), ("noise_sd", noise_sd)):
        check_instance(v, (tuple, list), f"dual_wavelength_ground: {k}", "a (visible, nir) pair of per-shot arrays")
    check_optional(params, DualParams, "dual_wavelength_ground: params")
    p = params or DualParams()
    vis = np.asarray(visible, float)
    ir = np.asarray(nir, float)
    if vis.shape != ir.shape or vis.ndim != 2:
        raise InputError(f"visible and nir must be 2-D arrays of one shape; got {vis.shape} "
                         f"and {ir.shape}")
    n, m = vis.shape
    sd_scale = 1.0
    if p.denoise > 0:
        # de-noise both bands with one filter, which keeps their ratio where the signal
        # is smooth; white noise's sd shrinks by sqrt(2 sqrt(pi) sigma)
        vis = gaussian_filter1d(vis, p.denoise, axis=1, mode="nearest")
        ir = gaussian_filter1d(ir, p.denoise, axis=1, mode="nearest")
        sd_scale = 1.0 / np.sqrt(2.0 * np.sqrt(np.pi) * p.denoise)
    thr_v = np.asarray(noise_mean[0], float) + p.k * sd_scale * np.asarray(noise_sd[0], float)
    thr_n = np.asarray(noise_mean[1], float) + p.k * sd_scale * np.asarray(noise_sd[1], float)
    mask = (vis > np.reshape(thr_v, (-1, 1))) & (ir > np.reshape(thr_n, (-1, 1)))
    idx = np.arange(m)
    any_signal = mask.any(axis=1)
    first = np.where(any_signal, np.argmax(mask, axis=1), 0)
    last = np.where(any_signal, m - 1 - np.argmax(mask[:, ::-1], axis=1), -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(mask, vis / ir, 0.0)
    inside = (idx[None, :] >= first[:, None]) & (idx[None, :] <= last[:, None])
    w_mask = mask.astype(float)

    # the lowest contiguous above-noise run holds the ground; when the canopy above it is
    # separated by a gap (flat ground, gentle slopes) and the run's ratio is ground-like
    # (clearly above the canopy's), the edge is the run's first sample itself
    run_start = mask & ~np.concatenate([np.zeros((n, 1), bool), mask[:, :-1]], axis=1)
    lr = np.where(run_start, idx[None, :], -1).max(axis=1)
    lower = mask & (idx[None, :] >= lr[:, None])
    upper = mask & (idx[None, :] < lr[:, None])
    with np.errstate(invalid="ignore", divide="ignore"):
        r_low = np.where(lower, ratio, 0.0).sum(axis=1) / lower.sum(axis=1)
        r_up = np.where(upper, ratio, 0.0).sum(axis=1) / upper.sum(axis=1)
    has_up = upper.any(axis=1)
    # is the lowest run homogeneous (soil only), or canopy and ground merged (slopes)?
    num = gaussian_filter1d(np.where(lower, ratio, 0.0), 2.0, axis=1, mode="nearest")
    den = gaussian_filter1d(lower.astype(float), 2.0, axis=1, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        light = np.where(lower & (den > 0.5), num / den, np.nan)
    ok_rows = np.isfinite(light).any(axis=1)
    lo_r = np.full(n, np.nan)
    hi_r = np.full(n, np.nan)
    lo_r[ok_rows] = np.nanmin(light[ok_rows], axis=1)
    hi_r[ok_rows] = np.nanmax(light[ok_rows], axis=1)
    homogeneous = ok_rows & (hi_r <= p.gap_ratio * lo_r)
    # a soil-only run: below a gap under ratio-darker canopy, or with no canopy above noise
    gap_edge = any_signal & homogeneous & (~has_up | (r_low > p.gap_ratio * r_up))
    refined = p.method == "refined"
    if refined:
        inside &= idx[None, :] >= np.where(lr >= 0, lr, 0)[:, None]  # the ground's run
    else:
        gap_edge = np.zeros(n, bool)

    # a rise must stand above the rounding of the ratio: a canopy of one constant ratio
    # (a noise-free pair) has gradients of +-1e-17 whose sign is the rounding's
    rise_floor = RISE_FLOOR * np.abs(ratio).max(axis=1, initial=0.0)
    start = np.full(n, np.nan)
    width = np.full(n, np.nan)
    for sigma in p.widths:  # a handful of widths; each is vectorised over every shot
        num = gaussian_filter1d(ratio, sigma, axis=1, mode="nearest")
        den = gaussian_filter1d(w_mask, sigma, axis=1, mode="nearest")
        with np.errstate(invalid="ignore", divide="ignore"):
            sm = np.where(den > 1e-6, num / den, 0.0)
        d1 = np.gradient(sm, axis=1)
        d2 = np.gradient(d1, axis=1)
        d3 = np.gradient(d2, axis=1)
        c3 = _crossings(d3, inside)
        has3 = c3.any(axis=1)
        lo = np.where(has3, np.argmax(c3, axis=1) + 1, m)
        hi = np.where(has3, m - 2 - np.argmax(c3[:, ::-1], axis=1), -1)
        win = (idx[None, :-1] >= lo[:, None]) & (idx[None, :-1] < hi[:, None]) & inside[:, :-1]
        # maxima of the gradient of a rising ratio (visible/NIR grows into the ground):
        # d2 turns from + to - where d1 is positive and a real edge (at least a fifth of
        # the steepest rise in the window), not a ripple
        c2 = win & mask[:, :-1] & mask[:, 1:] & (d2[:, :-1] > 0) & (d2[:, 1:] <= 0)
        if refined:
            steep = np.where(win, d1[:, :-1], 0.0).max(axis=1, initial=0.0)
            c2 &= d1[:, :-1] > np.maximum(0.2 * steep, rise_floor)[:, None]
        else:
            c2 &= d1[:, :-1] > rise_floor[:, None]
        count = c2.sum(axis=1)
        single = count == 1
        j = np.argmax(c2, axis=1)
        # linear interpolation of the zero of d2 between samples j and j+1
        a = d2[np.arange(n), j]
        b = d2[np.arange(n), np.minimum(j + 1, m - 1)]
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(a != b, a / (a - b), 0.5)
        pos = j + np.clip(frac, 0.0, 1.0)
        start = np.where(single, pos, start)  # narrower widths overwrite wider ones
        width = np.where(single, sigma, width)
    start = np.where(gap_edge, lr.astype(float), start)
    width = np.where(gap_edge, 0.0, width)
    found = np.isfinite(start) & any_signal
    end = np.where(any_signal, last.astype(float), np.nan)
    start = np.where(found, start, np.nan)
    centre = 0.5 * (start + end)
    # the first signal return: the first sample above noise in either band (leaves are
    # dark in the visible, so the canopy top may be above noise in the near infrared only)
    either = (vis > np.reshape(thr_v, (-1, 1))) | (ir > np.reshape(thr_n, (-1, 1)))
    first_pos = np.where(either.any(axis=1), np.argmax(either, axis=1).astype(float), np.nan)
    return DualGround(start, end, centre, width, found, first_pos)
