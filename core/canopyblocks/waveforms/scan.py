"""One pass over the raw samples of many shots: usability, search window and the part of
the window a signal can lie in (DESIGN 4.3).

Per shot:

- unusable: non-finite or non-positive noise statistics, or a non-finite sample;
- search window: L2A's ``search_start`` / ``search_end`` (:func:`.extent.search_window`):
  ``search_size`` samples either side of the first / last raw sample above
  ``noise_mean + k_pre * noise_sd``;
- the *signal bounds*: the samples of the window in which the signal top and bottom can
  lie at all. Interpolation and Gaussian smoothing are weighted means with non-negative
  weights, so the smoothed waveform exceeds a threshold only within the kernel's reach
  of a raw sample that exceeds it. A window's start before the first raw sample above
  the lower of the front and back thresholds (less the reach), and its end after the
  last raw sample above the back threshold (plus the reach), can hold neither the top
  nor the bottom. Smoothing only the bounds gives the same top, bottom, modes and
  energies as smoothing the whole window, and is 2-3x narrower on GEDI shots.

The raw samples are compared in their own type (float32 for GEDI): for each shot the
threshold is turned into the smallest float32 ``x`` with
``float64(x) - noise_mean > threshold``, so the comparison gives exactly the result
of subtracting in float64 first, without making a float64 copy of every sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .batch import WaveformBatch

__all__ = ["Scan", "scan_shots", "float32_cut"]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
FloatArray = npt.NDArray[np.float64]

#: Rows scanned at once (a float32 block of 1,024 GEDI shots is ~4 MB).
SCAN_ROWS = 1024


@dataclass(frozen=True)
class Scan:
    """Result of :func:`scan_shots` (samples, 0-based, inclusive; one value per shot)."""

    unusable: BoolArray
    window_start: IntArray
    window_end: IntArray
    has_window: BoolArray
    #: the part of the window where a signal top or bottom can lie
    bound_start: IntArray
    bound_end: IntArray
    #: False where no raw sample near the window exceeds the thresholds (no signal)
    may_have_signal: BoolArray


def _above(x: npt.NDArray[np.float32], mean: FloatArray, t: FloatArray) -> BoolArray:
    """``float64(x) - mean > t`` elementwise."""
    return (x.astype(np.float64) - mean) > t


def float32_cut(mean: FloatArray, t: FloatArray) -> npt.NDArray[np.float32]:
    """Smallest float32 ``x`` per shot with ``float64(x) - mean > t`` (inf where none).

    ``x - mean`` rounded is non-decreasing in ``x``, so ``raw >= cut`` is exactly
    ``float64(raw) - mean > t`` for every float32 ``raw``. NaN where ``mean`` or ``t``
    is not finite (no sample compares true).
    """
    mean = np.asarray(mean, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        cut = (mean + t).astype(np.float32)
        up = np.float32(np.inf)
        down = np.float32(-np.inf)
        for _ in range(8):               # one or two steps in practice
            low = np.isfinite(cut) & ~_above(cut, mean, t)
            if not low.any():
                break
            cut = np.where(low, np.nextafter(cut, up), cut)
        for _ in range(8):
            prev = np.nextafter(cut, down)
            high = np.isfinite(prev) & _above(prev, mean, t)
            if not high.any():
                break
            cut = np.where(high, prev, cut)
        ok = np.isfinite(cut)
        exact = _above(cut, mean, t) & ~_above(np.nextafter(cut, down), mean, t)
    if not (exact | ~ok).all():  # pragma: no cover - rounding is monotone
        raise ArithmeticError("internal: float32 threshold search did not converge")
    return np.where(np.isfinite(mean) & np.isfinite(t), cut, np.float32(np.nan))


def _loose_cut(mean: FloatArray, t: FloatArray, tol: FloatArray) -> npt.NDArray[np.float32]:
    """A float32 value at or below ``mean + t - tol`` (raw >= it keeps every sample that
    could lift the smoothed waveform above ``t``)."""
    with np.errstate(over="ignore", invalid="ignore"):
        c = (mean + t - tol).astype(np.float32)
        return np.nextafter(c, np.float32(-np.inf))


def _row_first(idx: IntArray, lo: IntArray, hi: IntArray) -> tuple[IntArray, BoolArray]:
    """Smallest entry of the sorted flat indices ``idx`` in ``[lo, hi)`` per row."""
    pos = np.searchsorted(idx, lo, side="left")
    val = idx[np.minimum(pos, max(len(idx) - 1, 0))] if len(idx) else lo
    ok = (pos < len(idx)) & (val < hi)
    return np.where(ok, val, lo), ok


def _row_last(idx: IntArray, lo: IntArray, hi: IntArray) -> tuple[IntArray, BoolArray]:
    """Largest entry of the sorted flat indices ``idx`` in ``[lo, hi)`` per row."""
    pos = np.searchsorted(idx, hi, side="left") - 1
    val = idx[np.maximum(pos, 0)] if len(idx) else lo
    ok = (pos >= 0) & (val >= lo)
    return np.where(ok, val, lo), ok


def scan_shots(batch: WaveformBatch, k_pre: float, search_size: int, k_low: float,
               k_back: float, reach: int) -> Scan:
    """Usability, search window and signal bounds of every shot of ``batch``.

    Parameters
    ----------
    batch : WaveformBatch
    k_pre : float
        Preprocessor threshold (noise sd) of the search window.
    search_size : int
        Samples added on either side of the window.
    k_low, k_back : float
        The lower of the front and back thresholds, and the back threshold (noise sd).
    reach : int
        Samples of raw waveform the location smoothing (with the interpolation) reaches
        on either side of a sample.

    Notes
    -----
    The samples above the lowest of the three thresholds are found in one comparison
    pass (a few % of the samples on GEDI shots, the signal); the three thresholds are
    then compared on those alone, and each shot's first and last one found by a
    binary search of the flat indices.
    """
    n = len(batch)
    wf = batch.waveforms
    m = wf.shape[1]
    mean = np.asarray(batch.noise_mean, dtype=np.float64)
    sd = np.asarray(batch.noise_sd, dtype=np.float64)
    n_samples = np.asarray(batch.n_samples, dtype=np.int64)
    with np.errstate(invalid="ignore"):
        unusable = ~np.isfinite(mean) | ~np.isfinite(sd) | ~(sd > 0)
    start = np.zeros(n, dtype=np.int64)
    end = np.zeros(n, dtype=np.int64)
    found = np.zeros(n, dtype=bool)
    b_start = np.zeros(n, dtype=np.int64)
    b_end = np.full(n, -1, dtype=np.int64)
    f32 = wf.dtype == np.float32
    for a in range(0, n, SCAN_ROWS):
        sl = slice(a, min(a + SCAN_ROWS, n))
        x = wf[sl]
        mu, s, cnt = mean[sl], sd[sl], n_samples[sl]
        rows = len(mu)
        hi = float(x.max()) if x.size else 0.0
        lo = float(x.min()) if x.size else 0.0
        if not (np.isfinite(hi) and np.isfinite(lo)):   # rare: look at the real samples
            valid = np.arange(m)[None, :] < cnt[:, None]
            unusable[sl] |= (~np.isfinite(x) & valid).any(axis=1)
            finite = np.abs(x[np.isfinite(x)])
            hi = lo = float(finite.max()) if finite.size else 0.0
        with np.errstate(invalid="ignore", over="ignore"):
            t_pre = k_pre * s
            # signal bounds: generous tolerance for the smoothing's rounding
            scale = max(abs(hi), abs(lo)) + np.abs(mu)
            low_cut = _loose_cut(mu, k_low * s, 1e-6 * np.abs(k_low * s) + 1e-9 * scale)
            back_cut = _loose_cut(mu, k_back * s, 1e-6 * np.abs(k_back * s) + 1e-9 * scale)
            if f32:
                pre_cut = float32_cut(mu, t_pre)
                least = np.fmin(np.fmin(pre_cut, low_cut), back_cut)
                idx = np.flatnonzero(x >= least[:, None])
                row = idx // m
                v = x.ravel()[idx]
                is_pre = v >= pre_cut[row]
            else:
                pre_loose = _loose_cut(mu, t_pre, 1e-6 * np.abs(t_pre) + 1e-9 * scale)
                least = np.fmin(np.fmin(pre_loose, low_cut), back_cut)
                idx = np.flatnonzero(x >= least[:, None])
                row = idx // m
                v = x.ravel()[idx]
                is_pre = (v.astype(np.float64) - mu[row]) > t_pre[row]
            is_pre &= (idx - row * m) < cnt[row]
            base = np.arange(rows, dtype=np.int64) * m
            pre = idx[is_pre]
            first, has = _row_first(pre, base, base + m)
            last, _ = _row_last(pre, base, base + m)
            first -= base
            last -= base
            w0 = np.maximum(first - search_size, 0)
            w1 = np.minimum(last + search_size, np.maximum(cnt - 1, 0))
            near_lo = base + np.maximum(w0 - reach, 0)
            j0, any_low = _row_first(idx[v >= low_cut[row]], near_lo, base + m)
            back = idx[v >= back_cut[row]]
            j1, any_back = _row_last(back, base, base + np.minimum(w1 + reach + 1, m))
        start[sl], end[sl], found[sl] = w0, w1, has
        b_start[sl] = np.maximum(w0, j0 - base - reach)
        b_end[sl] = np.where(any_low & any_back, np.minimum(w1, j1 - base + reach), -1)
    found &= (n_samples >= 2) & ~unusable
    may = found & (b_end >= b_start)
    b_start = np.where(may, b_start, start)
    b_end = np.where(may, b_end, start)
    return Scan(unusable, start, end, found, b_start, b_end, may)
