"""Check a track's ATL03 background rate against the photons' own (before classifying).

ATL03's ``bckgrd_atlas/bckgrd_rate`` is what the ATL08-style classifier trusts for its
noise threshold; a rate the file gets wrong (0, divided by 1000, a bit flip to 1e8 Hz)
turns background into canopy, or canopy into background, without a word.  The photons
say what the background is: per along-track stretch (``STRETCH_M``), the photons of the
telemetry window far from the surface (more than ``MARGIN_M`` from the height bins where
signal stands out, heights taken about the stretch's linear trend, as the window follows
the terrain) are background alone, and their count is Poisson.

Where the file's rate (mean over the stretch) and the photons' count disagree by more
than Poisson noise allows (``Z_LIMIT`` standard deviations) *and* by more than a factor
``RATIO_LIMIT`` (the file's rate is measured on 50-shot histograms of a band that may
differ from the photons read), :func:`checked_background` warns naming both rates and
returns the track with the photons' rate in those stretches.  A stretch whose window
holds under ``MIN_FREE_M`` of height away from the signal gives no verdict (a track
cut to the surface, e.g. signal photons only, says nothing about its background).

A rate above ``BRIGHT_HZ`` that the photons confirm is named as such: the classifier then
finds nothing above the background and would otherwise ask whether the beam is in cloud.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..errors import CanopyBlocksWarning, InputError
from ..photons import SPEED_OF_LIGHT, BackgroundRate, PhotonTrack
from . import atl08_classify
from .atl08_classify import Atl08Classes, Atl08Params
from .density_filter import poisson_quantile

__all__ = ["RateCheck", "photon_background", "checked_background", "classify_photons",
           "STRETCH_M", "BRIGHT_HZ"]

log = logging.getLogger(__name__)

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


def photon_background(track: PhotonTrack, shot_spacing: float = 0.7,
                      stretch: float = STRETCH_M) -> RateCheck:
    """The photons' own background rate per along-track stretch, beside the file's.

    Parameters
    ----------
    track : PhotonTrack
        ``s``, ``h`` in metres, ``time`` in seconds.
    shot_spacing : float
        Metres between shots (0.7 m for ICESat-2).
    stretch : float
        Along-track length of a stretch (m).

    Returns
    -------
    RateCheck
    """
    s = np.asarray(track.s, float)
    z = np.asarray(track.h, float)
    t = np.asarray(track.time, float)
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
    file_rate = None if track.background is None else track.background.at(ts)
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


def _mhz(hz: float) -> str:
    return f"{hz / 1e6:.3g} MHz"


def checked_background(track: PhotonTrack, shot_spacing: float = 0.7) -> PhotonTrack:
    """The track with a background rate the photons agree with.

    Parameters
    ----------
    track : PhotonTrack
    shot_spacing : float
        Metres between shots (0.7 m for ICESat-2).

    Returns
    -------
    PhotonTrack
        ``track`` itself when it has no file rate or the photons agree with it;
        otherwise a copy whose ``background`` holds the photons' rate in the stretches
        that disagree (and the file's elsewhere), with a
        :class:`~canopyblocks.errors.CanopyBlocksWarning` naming both rates.
    """
    if not isinstance(track, PhotonTrack):
        raise InputError(f"checked_background needs a PhotonTrack; got {type(track).__name__}")
    if track.background is not None and not isinstance(track.background, BackgroundRate):
        raise InputError(f"track {track.track}: background must be a BackgroundRate (times "
                         f"and rates in photons/s) or None; got "
                         f"{type(track.background).__name__}")
    if track.background is None or len(track) == 0:
        return track
    chk = photon_background(track, shot_spacing)
    name = f"track {track.track} ({track.source or 'in memory'})"
    if not chk.disagree.any():
        seen = np.isfinite(chk.photons_hz)
        if seen.any() and float(np.nanmedian(chk.file_hz[seen])) > BRIGHT_HZ:
            warnings.warn(
                f"{name}: the background rate is {_mhz(float(np.nanmedian(chk.file_hz)))} "
                f"(the file's bckgrd_rate, and the photons agree), above any sunlit scene "
                f"(1-10 MHz): expect little or no signal above it", CanopyBlocksWarning,
                stacklevel=2)
        return track
    d = chk.disagree
    f_hz, p_hz = float(np.median(chk.file_hz[d])), float(np.median(chk.photons_hz[d]))
    warnings.warn(
        f"{name}: the file's background rate (bckgrd_atlas/bckgrd_rate, median "
        f"{_mhz(f_hz)}) disagrees with the photons' own ({_mhz(p_hz)}, counted in the "
        f"telemetry window away from the surface) in {int(d.sum())} of {d.size} stretches "
        f"of ~{STRETCH_M:.0f} m, beyond Poisson noise; the photons' rate is used there",
        CanopyBlocksWarning, stacklevel=2)
    bg = track.background
    inside = np.zeros(bg.time.size, bool)
    for a, b in zip(chk.t0[d].tolist(), chk.t1[d].tolist()):
        inside |= (bg.time >= a) & (bg.time <= b)
    times = np.concatenate([bg.time[~inside], chk.t0[d], chk.t1[d]])
    rates = np.concatenate([bg.rate[~inside], chk.photons_hz[d], chk.photons_hz[d]])
    log.info("%s: background rate from the photons in %d stretches", name, int(d.sum()))
    return replace(track, background=BackgroundRate(times, rates))


def classify_photons(track: PhotonTrack, params: Atl08Params | None = None) -> Atl08Classes:
    """Classify a track's photons as ATL08 does (0 noise, 1 ground, 2 canopy, 3 top),
    after checking the file's background rate against the photons' own.

    Parameters
    ----------
    track : PhotonTrack
        Photons in a metric CRS; ``s`` and ``h`` in metres.
    params : Atl08Params, optional

    Returns
    -------
    Atl08Classes
        As :func:`canopyblocks.blocks.atl08_classify.classify_photons`, with the
        background rate :func:`checked_background` settles on.
    """
    if not isinstance(track, PhotonTrack):
        raise InputError(f"classify_photons needs a PhotonTrack; got {type(track).__name__}")
    p = Atl08Params() if params is None else params
    if not isinstance(p, Atl08Params):
        raise InputError(f"params must be an Atl08Params; got {type(p).__name__}")
    return atl08_classify.classify_photons(checked_background(track, p.shot_spacing), p)
