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

The counting itself lives with the reader (:mod:`canopyblocks.readers.atl03_background`),
which settles the rate on the photons of the whole track when it reads only a part of it
(a ``bbox``) or the file has no rate; such a rate (``settled``) is left as it is here.
:func:`canopyblocks.blocks.atl08_classify.classify_photons` runs this check first.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import replace

import numpy as np

from ..errors import CanopyBlocksWarning, InputError
from ..photons import BackgroundRate, PhotonTrack
from ..readers.atl03_background import (
    BRIGHT_HZ,
    STRETCH_M,
    RateCheck,
    disagreement_message,
    photon_rates,
    settle_rate,
)

__all__ = ["RateCheck", "photon_background", "checked_background", "STRETCH_M", "BRIGHT_HZ"]

log = logging.getLogger(__name__)


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
    return photon_rates(track.s, track.h, track.time, track.background, shot_spacing, stretch)


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
        ``track`` itself when it has no file rate, a rate already settled on the whole
        track, or the photons agree with it; otherwise a copy whose ``background`` holds
        the photons' rate in the stretches that disagree (and the file's elsewhere), with
        a :class:`~canopyblocks.errors.CanopyBlocksWarning` naming both rates.
    """
    if not isinstance(track, PhotonTrack):
        raise InputError(f"checked_background needs a PhotonTrack; got {type(track).__name__}")
    if track.background is not None and not isinstance(track.background, BackgroundRate):
        raise InputError(f"track {track.track}: background must be a BackgroundRate (times "
                         f"and rates in photons/s) or None; got "
                         f"{type(track.background).__name__}")
    if track.background is None or len(track) == 0 or track.background.settled:
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
    warnings.warn(disagreement_message(name, chk), CanopyBlocksWarning, stacklevel=2)
    log.info("%s: background rate from the photons in %d stretches", name,
             int(chk.disagree.sum()))
    return replace(track, background=settle_rate(track.background, chk))
