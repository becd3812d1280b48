"""The solar background rate of an ATL03 beam (``gtXX/bckgrd_atlas``).

ATL03 records, every 50 shots (~35 m), the background photon rate the onboard
algorithm measured in the telemetry band: ``bckgrd_atlas/delta_time`` (s, the photons'
clock) and ``bckgrd_atlas/bckgrd_rate`` (photons per second; ~0.1-0.3 MHz at night,
1-5 MHz by day).  Only the records spanning the photons read are kept.  Fill values
(3.4028235e38), negative and non-finite rates are dropped.

The photons say what the background is too (:func:`photon_rates`): per along-track
stretch, the photons of the telemetry window far from the surface are background alone,
and their count is Poisson.  A beam without a usable ``bckgrd_atlas`` (subsetters drop
it) gets its rate from the photons of the *whole* track, with a warning naming the
missing group; a beam read in part (a ``bbox``) keeps the file's rate of the whole track
(or, without one, the rate counted from the photons of the whole track), never one counted
from the part's photons (:func:`whole_track_background`).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..errors import CanopyBlocksWarning, FileFormatError
from ..photons import SPEED_OF_LIGHT, BackgroundRate
from ._h5 import H5File

__all__ = ["read_background_rate", "RATE_LIMIT_HZ", "RateCheck", "photon_rates",
           "settle_rate", "disagreement_message", "whole_track_background",
           "poisson_quantile", "STRETCH_M"]

log = logging.getLogger(__name__)

RATE_LIMIT_HZ = 1.0e9
"""Rates at or above this (photons/s) are fill values or damage, never a measurement
(the brightest daytime scenes give ~10 MHz)."""

_MARGIN_S = 0.05  # one record (50 shots = 5 ms) is enough; keep a few more
_NEAREST_S = 1.0  # a record further than this (7 km of track) from the photons is not theirs
_GROUND_SPEED = 7000.0  # m/s: 0.7 m between shots at 10 kHz (ICESat-2)

STRETCH_M = 200.0
"""Along-track length (m) of a stretch with its own photon estimate."""
MARGIN_M = 10.0
"""Height (m) kept clear above and below the bins where signal stands out."""
MIN_FREE_M = 30.0
"""Least height (m) of window away from the signal for a stretch to give a verdict."""
Z_LIMIT = 5.0
"""Poisson standard deviations beyond which file and photons disagree."""
RATIO_LIMIT = 2.0
"""... and the factor by which they must differ as well."""
BRIGHT_HZ = 20.0e6
"""Brighter than any sunlit scene ICESat-2 measures (1-10 MHz)."""
_BIN_M = 3.0


@dataclass(frozen=True)
class RateCheck:
    """The photons' background per stretch (arrays, one value per stretch).

    Attributes
    ----------
    t0, t1 : ndarray
        First and last photon time of the stretch (s, the track's clock).
    photons_hz : ndarray
        The photons' background rate (photons/s); NaN where the stretch gives no verdict
        (interpolated from its neighbours when a neighbour disagrees with the file).
    file_hz : ndarray
        The file's rate averaged over the stretch's photons (photons/s); NaN without one.
    disagree : ndarray bool
        File and photons differ by more than the noise allows.
    """

    t0: np.ndarray
    t1: np.ndarray
    photons_hz: np.ndarray
    file_hz: np.ndarray
    disagree: np.ndarray


def _hz_per_density(shot_spacing: float) -> float:
    """Photons/s per (photon per m along-track per m of height)."""
    return shot_spacing * SPEED_OF_LIGHT / 2.0


def photon_rates(s: np.ndarray, h: np.ndarray, time: np.ndarray,
                 background: BackgroundRate | None, shot_spacing: float = 0.7,
                 stretch: float = STRETCH_M) -> RateCheck:
    """The photons' own background rate per along-track stretch, beside the file's.

    Parameters
    ----------
    s, h, time : ndarray
        Along-track distance (m), height (m) and time (s, ``delta_time``) per photon.
    background : BackgroundRate or None
        The file's rate (None: the photons' alone, no verdict on disagreement).
    shot_spacing : float
        Metres between shots (0.7 m for ICESat-2).
    stretch : float
        Along-track length of a stretch (m).

    Returns
    -------
    RateCheck
    """
    s = np.asarray(s, float)
    z = np.asarray(h, float)
    t = np.asarray(time, float)
    ok = np.flatnonzero(np.isfinite(s) & np.isfinite(z) & np.isfinite(t))
    empty = np.zeros(0)
    if ok.size == 0:
        return RateCheck(empty, empty, empty, empty, np.zeros(0, bool))
    order = ok[np.argsort(s[ok], kind="stable")]
    ss, zs, ts = s[order], z[order], t[order]
    seg = np.floor((ss - ss[0]) / stretch).astype(np.int64)
    if seg[-1] > 0 and ss[-1] - ss[0] - seg[-1] * stretch < 0.5 * stretch:
        seg[seg == seg[-1]] -= 1  # a short end piece joins the stretch before it
    starts = np.concatenate([[0], np.flatnonzero(np.diff(seg)) + 1])
    ends = np.concatenate([starts[1:], [ss.size]])
    file_rate = None if background is None else background.at(ts)
    k = _hz_per_density(shot_spacing)
    n = starts.size
    t0, t1 = np.empty(n), np.empty(n)
    ph, fh = np.full(n, np.nan), np.full(n, np.nan)
    dis = np.zeros(n, bool)
    for i, (a, b) in enumerate(zip(starts.tolist(), ends.tolist())):
        # one histogram per stretch (a few hundred per granule): not a loop over photons
        t0[i], t1[i] = float(ts[a:b].min()), float(ts[a:b].max())
        if file_rate is not None:
            fh[i] = float(np.mean(file_rate[a:b]))
        length = float(ss[b - 1] - ss[a])
        zz = zs[a:b]
        if length > 0:  # the window slides with the terrain: heights about the trend
            zz = zz - np.polyval(np.polyfit(ss[a:b] - ss[a], zz, 1), ss[a:b] - ss[a])
        lo, hi = float(zz.min()), float(zz.max())
        if length < 0.5 * stretch or hi - lo < MIN_FREE_M + 2 * MARGIN_M:
            continue  # a short end piece, or a window cut to the surface: no verdict
        nb = int(np.ceil((hi - lo) / _BIN_M))
        idx = np.minimum(((zz - lo) / _BIN_M).astype(np.int64), nb - 1)
        counts = np.bincount(idx, minlength=nb)
        base = float(np.median(counts))
        loud = np.flatnonzero(counts > max(poisson_quantile(0.999, base), 2.0))
        if loud.size:
            clear_lo = lo + loud[0] * _BIN_M - MARGIN_M
            clear_hi = lo + (loud[-1] + 1) * _BIN_M + MARGIN_M
            free_h = max(clear_lo - lo, 0.0) + max(hi - clear_hi, 0.0)
            n_bg = int(np.count_nonzero((zz < clear_lo) | (zz > clear_hi)))
        else:
            free_h, n_bg = hi - lo, b - a
        if free_h < MIN_FREE_M:
            continue
        area = length * free_h
        ph[i] = n_bg / area * k
        if file_rate is not None:
            expect = fh[i] / k * area
            z_score = abs(n_bg - expect) / np.sqrt(max(expect, 1.0))
            ratio = (max(n_bg, 1.0) / max(expect, 1.0))
            dis[i] = z_score > Z_LIMIT and (ratio > RATIO_LIMIT or ratio < 1.0 / RATIO_LIMIT)
    seen = np.flatnonzero(np.isfinite(ph))
    if seen.size and seen.size < n and dis.any():
        # a stretch without a verdict (window cut to the surface) follows its nearest
        # neighbours that have one: their verdict, and their photons' rate between them
        idx = np.arange(n)
        near = seen[np.clip(np.searchsorted(seen, idx), 0, seen.size - 1)]
        before = seen[np.clip(np.searchsorted(seen, idx) - 1, 0, seen.size - 1)]
        near = np.where(np.abs(before - idx) <= np.abs(near - idx), before, near)
        blind = ~np.isfinite(ph)
        dis[blind] = dis[near[blind]]
        ph[blind] = np.interp(idx[blind], seen, ph[seen])
    return RateCheck(t0, t1, ph, fh, dis)




def read_background_rate(f: H5File, beam: str, t_min: float, t_max: float
                         ) -> BackgroundRate | None:
    """The beam's background rate between ``t_min`` and ``t_max`` (``delta_time``, s).

    Returns
    -------
    BackgroundRate or None
        None when the file has no usable ``bckgrd_atlas`` for this beam.
    """
    g = f"{beam}/bckgrd_atlas"
    if not (f.is_dataset(f"{g}/delta_time") and f.is_dataset(f"{g}/bckgrd_rate")):
        return None
    try:
        shape_t, shape_r = f.shape(f"{g}/delta_time"), f.shape(f"{g}/bckgrd_rate")
    except FileFormatError as exc:
        log.warning("%s: %s cannot be read (%s); the background rate is estimated from "
                    "the photons instead", f.path, g, str(exc).splitlines()[0])
        return None
    if len(shape_t) != 1 or shape_t != shape_r or shape_t[0] == 0:
        log.warning("%s: %s/delta_time and bckgrd_rate differ in shape (%s, %s); the "
                    "background rate is estimated from the photons instead",
                    f.path, g, shape_t, shape_r)
        return None
    try:
        t = f.read(f"{g}/delta_time", dtype=np.float64)
        r = f.read(f"{g}/bckgrd_rate", dtype=np.float64)
    except FileFormatError as exc:  # damage here must not cost the photons
        log.warning("%s: %s cannot be read (%s); the background rate is estimated from "
                    "the photons instead", f.path, g, str(exc).splitlines()[0])
        return None
    ok = np.isfinite(t) & np.isfinite(r) & (r >= 0) & (r < RATE_LIMIT_HZ)
    if np.isfinite(t_min) and np.isfinite(t_max):
        near = ok & (t >= t_min - _MARGIN_S) & (t <= t_max + _MARGIN_S)
        if not near.any() and ok.any():  # photons between two records: the nearest one
            i = np.flatnonzero(ok)
            j = i[np.argmin(np.abs(t[i] - 0.5 * (t_min + t_max)))]
            near = np.zeros_like(ok)
            near[j] = abs(t[j] - 0.5 * (t_min + t_max)) <= _NEAREST_S + 0.5 * (t_max - t_min)
        ok = near
    if not ok.any():
        log.warning("%s: %s/bckgrd_rate holds no valid rate for these photons; the "
                    "background rate is estimated from the photons instead", f.path, g)
        return None
    return BackgroundRate(t[ok], r[ok])


_QUANTILES: dict[tuple[float, float], float] = {}


def poisson_quantile(q: float, mu: float) -> float:
    """The ``q`` quantile of a Poisson distribution of mean ``mu``: the smallest count k with
    P(X <= k) >= q (scipy.stats.poisson.ppf, without importing scipy.stats, which costs the
    command line 0.5-0.7 s at start-up)."""
    key = (float(q), float(mu))
    t = _QUANTILES.get(key)
    if t is None:  # (rates repeat from track to track: remembered, a few thousand at most)
        t = _poisson_quantile(*key)
        if len(_QUANTILES) < 100_000:
            _QUANTILES[key] = t
    return t


def _poisson_quantile(q: float, mu: float) -> float:
    if not mu > 0:
        return 0.0
    kmax = int(mu + 12.0 * np.sqrt(mu) + 40.0)
    k = np.arange(kmax + 1, dtype=np.float64)
    log_fact = np.concatenate([[0.0], np.cumsum(np.log(k[1:]))])
    log_pmf = k * np.log(mu) - mu - log_fact
    cdf = np.cumsum(np.exp(log_pmf))
    hit = np.flatnonzero(cdf >= q * (1.0 - 1e-12))
    return float(hit[0]) if hit.size else float(kmax)


def _mhz(hz: float) -> str:
    return f"{hz / 1e6:.3g} MHz"


def disagreement_message(name: str, chk: RateCheck) -> str:
    """The warning for stretches where the file's rate and the photons' disagree."""
    d = chk.disagree
    f_hz, p_hz = float(np.median(chk.file_hz[d])), float(np.median(chk.photons_hz[d]))
    return (f"{name}: the file's background rate (bckgrd_atlas/bckgrd_rate, median "
            f"{_mhz(f_hz)}) disagrees with the photons' own ({_mhz(p_hz)}, counted in the "
            f"telemetry window away from the surface) in {int(d.sum())} of {d.size} "
            f"stretches of ~{STRETCH_M:.0f} m, beyond Poisson noise; the photons' rate is "
            "used there")


def settle_rate(bg: BackgroundRate, chk: RateCheck, *, settled: bool = False
                ) -> BackgroundRate:
    """``bg`` with the photons' rate in the stretches where ``chk`` finds disagreement."""
    d = chk.disagree
    inside = np.zeros(bg.time.size, bool)
    for a, b in zip(chk.t0[d].tolist(), chk.t1[d].tolist()):  # one per stretch
        inside |= (bg.time >= a) & (bg.time <= b)
    times = np.concatenate([bg.time[~inside], chk.t0[d], chk.t1[d]])
    rates = np.concatenate([bg.rate[~inside], chk.photons_hz[d], chk.photons_hz[d]])
    return BackgroundRate(times, rates, settled=settled)


def whole_track_background(f: H5File, beam: str, background: BackgroundRate | None, *,
                           cut: bool, photons: tuple[np.ndarray, np.ndarray, np.ndarray]
                           ) -> BackgroundRate | None:
    """The rate of a beam settled on its whole track, never on a part of it.

    Parameters
    ----------
    f : H5File
        The open ATL03 file (local or remote).
    beam : str
    background : BackgroundRate or None
        What :func:`read_background_rate` found (None: no usable ``bckgrd_atlas``).
    cut : bool
        The photons read are a part of the track (a ``bbox`` or along-track range).
    photons : (s, h, time)
        The photons read (m, m, s).

    Returns
    -------
    BackgroundRate or None
        ``background`` as it is for a whole track (the classifier checks it on those
        photons); the file's rate marked ``settled`` for a part (it was measured on the
        whole track, the part's photons may be too few to judge it); without a file rate,
        the rate counted from the photons of the whole track (for a part, only its
        ``heights/delta_time`` and ``heights/h_ph`` are read, 16 bytes a photon), marked
        ``settled``, or None when they give no count (a window cut to the surface).
    """
    if background is not None:
        return replace(background, settled=True) if cut else background
    s, h, t = photons
    if cut:
        hg = f"{beam}/heights"
        try:
            t = f.read(f"{hg}/delta_time", dtype=np.float64)
            h = f.read(f"{hg}/h_ph", dtype=np.float64)
        except FileFormatError as exc:
            log.warning("%s: the whole track's photons cannot be read (%s); the background "
                        "rate is estimated from the photons read", f.path,
                        str(exc).splitlines()[0])
            return None
        ok = np.isfinite(t) & np.isfinite(h) & (np.abs(h) < 1e5) & (np.abs(t) < 1e10)
        t, h = t[ok], h[ok]
        s = (t - t.min()) * _GROUND_SPEED if t.size else t
    name = f"{f.path} {beam}"
    chk = photon_rates(s, h, t, None)
    seen = np.isfinite(chk.photons_hz)
    if not seen.any():
        warnings.warn(f"{name}: the file has no usable bckgrd_atlas/bckgrd_rate and the "
                      "photons of the track give no background count (a window cut to the "
                      "surface); the classifier estimates it from the photons near them",
                      CanopyBlocksWarning, stacklevel=3)
        return None
    mid = 0.5 * (chk.t0[seen] + chk.t1[seen])
    rate = BackgroundRate(mid, chk.photons_hz[seen], settled=True)
    warnings.warn(f"{name}: the file has no usable bckgrd_atlas/bckgrd_rate (subsetting "
                  f"tools often drop it); the background rate is counted from the photons "
                  f"of the whole track instead (median {_mhz(float(np.median(rate.rate)))})",
                  CanopyBlocksWarning, stacklevel=3)
    return rate
