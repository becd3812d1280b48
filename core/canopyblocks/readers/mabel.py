"""MABEL L2A geolocated photons, one detector channel at a time.

Layout (as in real granules, e.g. ``mabel_l2a_20110322T165030_005_1.h5``):
``photon/channelNNN/{delta_time (f8, s since the first data point of the granule),
elev (f4, m above the WGS84 ellipsoid), flag (u1), latitude (f8), longitude (f8),
photon_id (u2), shot_num (i4)}``.  MABEL has no along-track coordinate, so ``s``
is the distance along a straight line fitted to the whole channel's photons
(:func:`canopyblocks.photons.along_track_distance`); a subset keeps the ``s`` of
the full channel, so blocks line up between subsets.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Sequence

import numpy as np
import pyproj

from ..errors import FileFormatError, InputError, NoUsableDataError
from ..geo import to_metric
from ..photons import PhotonTrack, along_track_distance
from ..progress import Progress, as_progress
from ._common import bbox_mask, check_bbox, check_s_range, s_mask
from ._h5 import H5File, open_h5

__all__ = ["mabel_channels", "read_mabel", "channel_name", "EXTRA_GROUP"]

log = logging.getLogger(__name__)

EXTRA_GROUP = "canopyblocks_truth"
"""Top-level group ``canopyblocks_truth/channelNNN/<name>`` with extra per-photon
columns written by the simulator (not part of the real product)."""

_CHANNEL_RE = re.compile(r"^channel(\d{1,3})$")


def channel_name(channel: int) -> str:
    """``49 -> "channel049"``."""
    return f"channel{int(channel):03d}"


def _channels(f: H5File) -> dict[int, int]:
    out: dict[int, int] = {}
    for name in f.keys("photon"):
        m = _CHANNEL_RE.match(name)
        if m and f.is_group(f"photon/{name}"):
            n = f.shape(f"photon/{name}/elev")[0] if f.is_dataset(f"photon/{name}/elev") else 0
            out[int(m.group(1))] = int(n)
    return dict(sorted(out.items()))


def _require_mabel(f: H5File) -> dict[int, int]:
    chans = _channels(f)
    if not chans:
        raise FileFormatError(
            f"{f.path}: not a MABEL L2A file: no photon/channelNNN groups; pass a MABEL L2A "
            "granule (mabel_l2a_*.h5)"
        )
    return chans


def mabel_channels(path: str | os.PathLike[str]) -> dict[int, int]:
    """Channel number -> photon count of a MABEL L2A file (sorted by channel).

    Raises
    ------
    FileFormatError
        Not HDF5, unreadable, or no ``photon/channelNNN`` group.
    """
    with open_h5(path, "MABEL L2A") as f:
        return _require_mabel(f)


def _pick_channel(f: H5File, chans: dict[int, int], channel: int | str) -> int:
    allowed = ", ".join(f"{c} ({n} photons)" for c, n in chans.items())
    if isinstance(channel, str):
        text = channel.strip().lower()
        if text == "most":
            return max(chans, key=lambda c: (chans[c], -c))
        m = _CHANNEL_RE.match(text)
        text = m.group(1) if m else text
        if not text.isdigit():
            raise InputError(f"channel {channel!r} is not a channel number or 'most'; "
                             f"{f.path} has channels {allowed}")
        channel = int(text)
    if isinstance(channel, bool) or not isinstance(channel, (int, np.integer)):
        raise InputError(f"channel {channel!r} must be an integer or 'most'")
    if int(channel) not in chans:
        raise InputError(f"{f.path}: channel {int(channel)} is not in this file; it has "
                         f"channels {allowed} (or use 'most')")
    return int(channel)


def read_mabel(
    path: str | os.PathLike[str],
    channel: int | str = "most",
    *,
    bbox: Sequence[float] | None = None,
    s_range: Sequence[float] | None = None,
    crs: pyproj.CRS | str | int | None = None,
    extra_group: str | None = EXTRA_GROUP,
    progress: Progress | None = None,
) -> PhotonTrack:
    """Read the photons of one MABEL L2A channel.

    Parameters
    ----------
    path : path-like
        MABEL L2A granule (HDF5).
    channel : int or "most"
        Channel number (e.g. 49, or ``"channel049"``); ``"most"`` picks the channel
        with the most photons.
    bbox : (lon_min, lat_min, lon_max, lat_max), optional
        WGS84 degrees.  Latitude/longitude are read first; the other columns only
        for the rows spanning the selected photons.
    s_range : (s_min, s_max), optional
        Metres along the line fitted to the whole channel (0 at its first photon).
    crs : CRS-like, optional
        Metric CRS for ``x``/``y`` (default: UTM zone of the channel centre).
    extra_group : str or None
        Group ``<extra_group>/channelNNN`` with extra per-photon columns (simulator
        truth) to load into ``track.extra``; None skips it.
    progress : Progress, optional

    Returns
    -------
    PhotonTrack
        ``track="channelNNN"``, ``h`` = ``elev`` (m, WGS84 ellipsoid,
        ``vertical_datum="EPSG:4979"``), ``time`` = ``delta_time`` (s), sorted by ``s``.

    Raises
    ------
    FileFormatError
        Not HDF5/MABEL, truncated, or a dataset missing.
    InputError
        Channel not in the file (the message lists the channels), bad bbox/s_range.
    NoUsableDataError
        No photon (with finite position) in the channel or subset.
    """
    prog = as_progress(progress)
    bb = check_bbox(bbox)
    sr = check_s_range(s_range)
    with open_h5(path, "MABEL L2A") as f:
        chans = _require_mabel(f)
        ch = _pick_channel(f, chans, channel)
        name = channel_name(ch)
        g = f"photon/{name}"
        n_all = chans[ch]
        prog.update(0.0, f"reading {name} positions")
        lat = f.read(f"{g}/latitude", dtype=np.float64)
        lon = f.read(f"{g}/longitude", dtype=np.float64)
        time = f.read(f"{g}/delta_time", dtype=np.float64)
        if not (lat.shape == lon.shape == time.shape == (n_all,)):
            raise FileFormatError(
                f"{f.path}: {g}: latitude {lat.shape}, longitude {lon.shape}, delta_time "
                f"{time.shape} and elev ({n_all},) differ in length; the file is corrupt"
            )
        valid = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(time) & \
            (np.abs(lat) <= 90.0) & (np.abs(lon) <= 360.0)
        if not valid.any():
            raise NoUsableDataError(f"{f.path}: {name} has no photon with a valid position")
        if not valid.all():
            log.info("%s %s: %d photons without a valid position skipped",
                     f.path, name, int((~valid).sum()))
        prog.update(0.3, "fitting the along-track line")
        # s over the whole channel, so a subset keeps the same s as the full read
        x, y, used_crs = to_metric(lon[valid], lat[valid],
                                   None if crs is None else _as_crs(crs))
        s_valid, _ = along_track_distance(x, y, time[valid])
        s = np.full(n_all, np.nan)
        s[valid] = s_valid
        keep = valid & bbox_mask(lon, lat, bb) & s_mask(s, sr)
        if not keep.any():
            raise NoUsableDataError(
                f"{f.path}: no photons of {name} inside bbox={bb} s_range={sr}; the channel "
                f"covers lon {lon[valid].min():.5f}..{lon[valid].max():.5f}, lat "
                f"{lat[valid].min():.5f}..{lat[valid].max():.5f}, s 0..{s_valid.max():.1f} m"
            )
        idx = np.flatnonzero(keep)
        lo, hi = int(idx[0]), int(idx[-1]) + 1
        take = idx - lo
        prog.update(0.6, f"reading {idx.size} photons of {name}")
        h = f.read(f"{g}/elev", np.s_[lo:hi], dtype=np.float64)[take]
        extra: dict[str, np.ndarray] = {}
        eg = f"{extra_group}/{name}" if extra_group else ""
        if eg and f.is_group(eg):
            for col in f.keys(eg):
                if f.is_dataset(f"{eg}/{col}") and f.shape(f"{eg}/{col}") == (n_all,):
                    extra[col] = f.read(f"{eg}/{col}", np.s_[lo:hi])[take]
        src = str(f.path)
    track = PhotonTrack.from_lonlat(
        time[idx], lat[idx], lon[idx], h, track=name, s=s[idx], crs=used_crs,
        extra=extra, source=src, vertical_datum="EPSG:4979",
    )
    prog.update(1.0, f"{name}: {len(track)} photons")
    log.info("read %d photons of %s from %s", len(track), name, src)
    return track


def _as_crs(crs: object) -> pyproj.CRS:
    from ..geo import as_crs

    return as_crs(crs, "track CRS")
