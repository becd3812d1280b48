"""Write photons in the real ATL03 and MABEL L2A HDF5 layouts (for the simulator and tests).

The files are read by :func:`canopyblocks.readers.read_atl03` /
:func:`canopyblocks.readers.read_mabel` exactly like real granules, so every
reader and the whole chain downstream are exercised on simulated photons.

ATL03 layout written (names, dtypes and attributes as in v006 granules)::

    /orbit_info/{sc_orient (1,) i1, rgt (1,) i2, cycle_number (1,) i1}
    /ancillary_data/atlas_sdp_gps_epoch (1,) f8          (ancillary=True)
    /gtXX            attrs atlas_beam_type, atlas_spot_number, groundtrack_id, sc_orientation
    /gtXX/heights/{delta_time f8, lat_ph f8, lon_ph f8, h_ph f4, dist_ph_along f4,
                   dist_ph_across f4, signal_conf_ph (n, 5) i1, quality_ph i1}
    /gtXX/geolocation/{segment_id i4, segment_dist_x f8, segment_length f8,
                       ph_index_beg i8, segment_ph_cnt i4, reference_photon_index i4,
                       reference_photon_lat f8, reference_photon_lon f8, delta_time f8}
    /gtXX/bckgrd_atlas/{delta_time f8, bckgrd_rate f4, bckgrd_counts i4,
                        bckgrd_int_height f4, bckgrd_hist_top f4, tlm_top_band1 f4,
                        tlm_height_band1 f4}      (when the beam has a background)
    /gtXX/<extra_group>/<name>   per-photon extra columns (not in real granules)

``h_ph`` is described as WGS84 ellipsoidal height unless ``write_atl03`` is told the
heights' vertical CRS (``height_crs``); then its description and the file attribute
``canopyblocks_height_crs`` name it (simulated photons keep the airborne tiles' datum).

Segments are 20 m long; photon ``k`` with along-track distance ``s_k`` belongs to
segment ``floor(s_k / 20)`` and ``dist_ph_along = s_k - 20 * segment``; so the
reader's ``segment_dist_x + dist_ph_along`` returns ``segment_dist_x0 + s_k``.

MABEL L2A layout written (from the real granule's structure)::

    /photon/channelNNN/{delta_time f8, elev f4, flag u1, latitude f8, longitude f8,
                        photon_id u2, shot_num i4}
    /canopyblocks_truth/channelNNN/<name>   per-photon extra columns (not in real granules)
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import DTypeLike

from ..atomic import atomic_output
from ..errors import InputError

if TYPE_CHECKING:
    import h5py  # untyped: its classes are Any to mypy

__all__ = [
    "Atl03Background",
    "Atl03BeamData",
    "MabelChannelData",
    "write_atl03",
    "write_mabel",
    "SEGMENT_LENGTH",
    "ATLAS_SDP_GPS_EPOCH",
]

log = logging.getLogger(__name__)

SEGMENT_LENGTH = 20.0
"""Length of an ATL03 geolocation segment written here, metres."""

ATLAS_SDP_GPS_EPOCH = 1198800018.0
"""GPS seconds of the ATLAS SDP epoch (2018-01-01); ATL03 ``delta_time`` counts from it."""

_BEAMS = ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")


def _column(name: str, values: object, n: int | None,
            dtype: DTypeLike = np.float64) -> np.ndarray:
    arr = np.asarray(values, dtype=dtype)
    if arr.ndim != 1:
        raise InputError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if n is not None and arr.size != n:
        raise InputError(f"{name} has {arr.size} values, expected {n} (one per photon)")
    return arr


def _extras(extra: Mapping[str, object], n: int) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for k, v in extra.items():
        if not k or "/" in k:
            raise InputError(f"extra column name {k!r} must be non-empty without '/'")
        arr = np.asarray(v)
        if arr.ndim != 1 or arr.size != n:
            raise InputError(f"extra column {k!r} has shape {arr.shape}, expected ({n},)")
        out[k] = arr
    return out


def _set_finite(obj: object, cols: Mapping[str, np.ndarray]) -> None:
    """Set each column on the frozen ``obj`` in turn, refusing one holding NaN/inf."""
    for k, v in cols.items():
        if not np.all(np.isfinite(v)):
            raise InputError(f"{type(obj).__name__}.{k} holds NaN/inf; drop those photons "
                             "first")
        object.__setattr__(obj, k, v)


@dataclass(frozen=True, eq=False)
class Atl03Background:
    """A beam's ``bckgrd_atlas`` group: the background rate per 50-shot sum.

    Parameters
    ----------
    delta_time : array (m,)
        Start of each 50-shot sum, seconds (same time base as the photons').
    rate : array (m,)
        Background count rate, photons per second (``bckgrd_rate``).
    counts : array (m,), optional
        Background photons counted in each 50-shot span (``bckgrd_counts``).
    tlm_top, tlm_height : array (m,), optional
        Top and height of the telemetry band (metres, the photons' vertical CRS), also
        written as ``bckgrd_hist_top``/``bckgrd_int_height``.
    """

    delta_time: np.ndarray
    rate: np.ndarray
    counts: np.ndarray | None = None
    tlm_top: np.ndarray | None = None
    tlm_height: np.ndarray | None = None

    def __post_init__(self) -> None:
        t = _column("background delta_time", self.delta_time, None)
        m = t.size
        rate = _column("background rate", self.rate, m)
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(rate)) and np.all(rate >= 0)):
            raise InputError("Atl03Background.delta_time/rate must be finite, rate >= 0 "
                             "photons per second")
        object.__setattr__(self, "delta_time", t)
        object.__setattr__(self, "rate", rate)
        for name, dtype in (("counts", np.int32), ("tlm_top", np.float64),
                            ("tlm_height", np.float64)):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _column(f"background {name}", v, m, dtype))

    def __len__(self) -> int:
        return int(self.delta_time.size)


@dataclass(frozen=True, eq=False)
class Atl03BeamData:
    """Photons of one beam to write in the ATL03 layout.

    Parameters
    ----------
    delta_time : array (n,)
        Seconds since the ATLAS SDP epoch (ATL03 ``delta_time``).
    lat, lon : array (n,)
        WGS84 degrees.
    h : array (n,)
        Height above the WGS84 ellipsoid, metres (stored as float32, like ``h_ph``).
    s : array (n,)
        Along-track distance from the start of the track, metres, >= 0.
    signal_conf : array (n,) or (n, 5), optional
        Land ``signal_conf_ph`` (-2..4) or all five surface columns (land, ocean,
        sea ice, land ice, inland water).  A 1-D array fills the land column and
        sets the others to -1.  None: 4 (high confidence) for every photon.
    extra : mapping name -> array (n,), optional
        Further per-photon columns (e.g. the simulator's truth) written to
        ``gtXX/<extra_group>/<name>`` and loaded by ``read_atl03`` into ``track.extra``.
    strength : "strong", "weak" or None
        ``atlas_beam_type``; None derives it from ``sc_orient`` of :func:`write_atl03`.
    background : Atl03Background, optional
        Written to ``gtXX/bckgrd_atlas`` as in real granules.
    """

    delta_time: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    s: np.ndarray
    signal_conf: np.ndarray | None = None
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)
    strength: str | None = None
    background: Atl03Background | None = None

    def __post_init__(self) -> None:
        t = _column("delta_time", self.delta_time, None)
        n = t.size
        cols = {"delta_time": t, "lat": _column("lat", self.lat, n),
                "lon": _column("lon", self.lon, n), "h": _column("h", self.h, n),
                "s": _column("s", self.s, n)}
        _set_finite(self, cols)
        if n and cols["s"].min() < 0:
            raise InputError(f"Atl03BeamData.s must be >= 0 (metres from the track start), "
                             f"got minimum {cols['s'].min():.3f}")
        if np.any(np.abs(cols["lat"]) > 90) or np.any(np.abs(cols["lon"]) > 360):
            raise InputError("Atl03BeamData.lat/lon must be WGS84 degrees")
        conf = self.signal_conf
        if conf is None:
            full = np.full((n, 5), -1, dtype=np.int8)
            full[:, 0] = 4
        else:
            c = np.asarray(conf)
            if c.ndim == 1 and c.size == n:
                full = np.full((n, 5), -1, dtype=np.int8)
                full[:, 0] = c
            elif c.shape == (n, 5):
                full = c.astype(np.int8)
            else:
                raise InputError(f"signal_conf has shape {c.shape}, expected ({n},) or ({n}, 5)")
            if np.any((full < -2) | (full > 4)):
                raise InputError("signal_conf values must be in -2..4 (ATL03 signal_conf_ph)")
        object.__setattr__(self, "signal_conf", full)
        object.__setattr__(self, "extra", _extras(self.extra, n))
        if self.strength not in (None, "strong", "weak"):
            raise InputError(f"strength {self.strength!r} must be 'strong', 'weak' or None")
        if self.background is not None and not isinstance(self.background, Atl03Background):
            raise InputError(f"background must be an Atl03Background, got "
                             f"{type(self.background).__name__}")

    def __len__(self) -> int:
        return int(self.delta_time.size)


@dataclass(frozen=True, eq=False)
class MabelChannelData:
    """Photons of one MABEL channel to write in the MABEL L2A layout.

    Parameters
    ----------
    delta_time : array (n,)
        Seconds since the first data point of the granule.
    lat, lon : array (n,)
        WGS84 degrees.
    elev : array (n,)
        Height above the WGS84 ellipsoid, metres (stored as float32, like ``elev``).
    shot_num, photon_id : array (n,), optional
        Shot number and photon-per-shot counter; None numbers shots by distinct
        ``delta_time`` (1, 2, ...) and counts photons within each shot (1, 2, ...).
    flag : array (n,), optional
        The product's 1-byte flag; None writes 0.
    extra : mapping name -> array (n,), optional
        Written to ``canopyblocks_truth/channelNNN/<name>``; ``read_mabel`` loads them.
    """

    delta_time: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    elev: np.ndarray
    shot_num: np.ndarray | None = None
    photon_id: np.ndarray | None = None
    flag: np.ndarray | None = None
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _column("delta_time", self.delta_time, None)
        n = t.size
        _set_finite(self, {"delta_time": t, "lat": _column("lat", self.lat, n),
                           "lon": _column("lon", self.lon, n),
                           "elev": _column("elev", self.elev, n)})
        if self.shot_num is None or self.photon_id is None:
            _, inv = np.unique(t, return_inverse=True)
            order = np.argsort(inv, kind="stable")
            counts = np.bincount(inv)
            rank = np.empty(n, dtype=np.int64)
            rank[order] = np.arange(n) - np.repeat(np.cumsum(counts) - counts, counts)
            shot, pid = inv + 1, rank + 1
        else:
            shot, pid = self.shot_num, self.photon_id
        object.__setattr__(self, "shot_num", _column("shot_num", shot, n, np.int32))
        object.__setattr__(self, "photon_id", _column("photon_id", pid, n, np.uint16))
        flag = np.zeros(n, np.uint8) if self.flag is None else self.flag
        object.__setattr__(self, "flag", _column("flag", flag, n, np.uint8))
        object.__setattr__(self, "extra", _extras(self.extra, n))

    def __len__(self) -> int:
        return int(self.delta_time.size)


def _ds(group: h5py.Group, name: str, data: np.ndarray, units: str, long_name: str,
        **attrs: str) -> None:
    d = group.create_dataset(name, data=data)
    d.attrs["units"] = units
    d.attrs["long_name"] = long_name
    for k, v in attrs.items():
        d.attrs[k] = v


def _spot(beam: str, sc_orient: int) -> int | None:
    i = _BEAMS.index(beam)
    return {0: i + 1, 1: 6 - i}.get(sc_orient)


def write_atl03(
    path: str | os.PathLike[str],
    beams: Mapping[str, Atl03BeamData],
    *,
    sc_orient: int = 0,
    rgt: int = 0,
    cycle: int = 0,
    ancillary: bool = True,
    extra_group: str = "canopyblocks_truth",
    segment_dist_x0: float = 0.0,
    height_crs: str | None = None,
) -> Path:
    """Write beams of photons as an ATL03-layout HDF5 file (atomically).

    Parameters
    ----------
    path : path-like
        Output ``.h5`` file; replaced only when writing succeeded.
    beams : mapping beam name -> Atl03BeamData
        Beam names ``gt1l`` ... ``gt3r``.
    sc_orient : int
        ``orbit_info/sc_orient``: 0 backward (left beams strong), 1 forward (right
        beams strong), 2 transition.
    rgt, cycle : int
        Reference ground track and cycle number written to ``orbit_info``.
    ancillary : bool
        Write ``ancillary_data/atlas_sdp_gps_epoch`` (real granules have it; the
        shared Wyoming clip does not).
    extra_group : str
        Group name for each beam's extra per-photon columns.
    segment_dist_x0 : float
        ``segment_dist_x`` of the first segment (metres from the equator crossing);
        the reader's ``s`` is ``segment_dist_x0 + Atl03BeamData.s``.
    height_crs : str, optional
        The vertical CRS of the heights when they are not WGS84 ellipsoidal (e.g.
        ``"EPSG:5713"`` for simulated photons over CGVD28 tiles, or ``"unknown"``):
        stated in ``h_ph``'s description and in the file attribute
        ``canopyblocks_height_crs``. None: WGS84 ellipsoidal heights, as ATL03.

    Returns
    -------
    Path
        ``path``.
    """
    from ..arguments import check_mapping, check_path
    check_path(path, "write_atl03: path")
    check_mapping(
        beams, "write_atl03: beams", "a dict of beam name -> Atl03BeamData", Atl03BeamData
    )
    import h5py

    if not beams:
        raise InputError("write_atl03 needs at least one beam")
    for b, data in beams.items():
        if b not in _BEAMS:
            raise InputError(f"beam {b!r} is not an ATL03 beam; use one of {', '.join(_BEAMS)}")
        if not isinstance(data, Atl03BeamData):
            raise InputError(f"beam {b}: expected Atl03BeamData, got {type(data).__name__}")
    if sc_orient not in (0, 1, 2):
        raise InputError(f"sc_orient {sc_orient!r} must be 0 (backward), 1 (forward) or 2")
    if not extra_group or "/" in extra_group:
        raise InputError(f"extra_group {extra_group!r} must be a plain group name")
    out = Path(path)
    with atomic_output(out) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["short_name"] = "ATL03"
        f.attrs["identifier_product_type"] = "ATL03"
        f.attrs["description"] = ("ATL03-layout photons written by canopyblocks (simulated or "
                                  "converted); not a NASA product")
        f.attrs["Conventions"] = "CF-1.6"
        if height_crs is not None:
            f.attrs["canopyblocks_height_crs"] = str(height_crs)
        oi = f.create_group("orbit_info")
        _ds(oi, "sc_orient", np.array([sc_orient], np.int8), "1", "Spacecraft Orientation",
            flag_meanings="backward forward transition")
        _ds(oi, "rgt", np.array([rgt], np.int16), "1", "Reference Ground track")
        _ds(oi, "cycle_number", np.array([cycle], np.int8), "1", "Cycle Number")
        if ancillary:
            anc = f.create_group("ancillary_data")
            _ds(anc, "atlas_sdp_gps_epoch", np.array([ATLAS_SDP_GPS_EPOCH]),
                "seconds since 1980-01-06T00:00:00.000000Z", "ATLAS Epoch Offset")
        for beam, data in beams.items():
            _write_beam(f, beam, data, sc_orient, extra_group, float(segment_dist_x0),
                        height_crs)
    log.info("wrote ATL03-layout file %s (%s)", out, ", ".join(beams))
    return out


def _h_ph_text(height_crs: str | None) -> tuple[str, str]:
    """``long_name`` and ``description`` of ``h_ph`` for heights in ``height_crs``."""
    if height_crs is None:
        return "Photon WGS84 Height", "Height of each received photon, relative to the " \
            "WGS-84 ellipsoid."
    if height_crs.lower() in ("", "unknown"):
        return "Photon height (unknown vertical CRS)", (
            "Height of each received photon in the unstated vertical datum of the "
            "airborne lidar it was simulated from; not WGS-84 ellipsoidal height.")
    return f"Photon height ({height_crs})", (
        f"Height of each received photon in the vertical CRS {height_crs} (that of the "
        "airborne lidar it was simulated from); not WGS-84 ellipsoidal height.")


def _write_background(g: h5py.Group, b: Atl03Background) -> None:
    bg = g.create_group("bckgrd_atlas")
    _ds(bg, "delta_time", b.delta_time, "seconds since 2018-01-01",
        "Time at the start of ATLAS 50-shot sum",
        description="Time at the start of each 50-shot background sum.")
    _ds(bg, "bckgrd_rate", b.rate.astype(np.float32), "counts / second",
        "Background count rate based on the ATLAS 50-shot sum",
        description="The background count rate (photons per second) of each 50-shot span.")
    if b.counts is not None:
        _ds(bg, "bckgrd_counts", b.counts, "counts", "ATLAS 50-shot background count",
            description="Background photons counted in the telemetry band over the span.")
    for name, arr, long_name in (("tlm_top_band1", b.tlm_top, "Top of the telemetry band 1"),
                                 ("tlm_height_band1", b.tlm_height,
                                  "Height of the telemetry band 1"),
                                 ("bckgrd_hist_top", b.tlm_top,
                                  "Top of the altimetric range window"),
                                 ("bckgrd_int_height", b.tlm_height,
                                  "Altimetric range window width")):
        if arr is not None:
            _ds(bg, name, arr.astype(np.float32), "meters", long_name)


def _write_beam(f: h5py.File, beam: str, d: Atl03BeamData, sc_orient: int, extra_group: str,
                dist_x0: float, height_crs: str | None = None) -> None:
    n = len(d)
    seg = np.floor(d.s / SEGMENT_LENGTH).astype(np.int64)
    order = np.lexsort((d.delta_time, seg))  # photons grouped by segment, in time order
    seg = seg[order]
    n_seg = int(seg.max()) + 1 if n else 0
    cnt = np.bincount(seg, minlength=n_seg).astype(np.int64)
    first = np.cumsum(cnt) - cnt  # 0-based first row of each segment
    beg = np.where(cnt > 0, first + 1, 0)
    seg_start = np.arange(n_seg) * SEGMENT_LENGTH
    s_sorted = d.s[order]
    # reference position/time of each segment: photons interpolated at the segment start
    by_s = np.argsort(d.s, kind="stable")
    ref_lat = np.interp(seg_start, d.s[by_s], d.lat[by_s]) if n else np.empty(0)
    ref_lon = np.interp(seg_start, d.s[by_s], d.lon[by_s]) if n else np.empty(0)
    ref_t = np.interp(seg_start, d.s[by_s], d.delta_time[by_s]) if n else np.empty(0)

    strength = d.strength or {0: "strong" if beam.endswith("l") else "weak",
                              1: "strong" if beam.endswith("r") else "weak"}.get(sc_orient)
    g = f.create_group(beam)
    g.attrs["groundtrack_id"] = beam
    if strength:
        g.attrs["atlas_beam_type"] = strength
    spot = _spot(beam, sc_orient)
    if spot is not None:
        g.attrs["atlas_spot_number"] = str(spot)
    g.attrs["sc_orientation"] = {0: "Backward", 1: "Forward", 2: "Transition"}[sc_orient]

    hg = g.create_group("heights")
    _ds(hg, "delta_time", d.delta_time[order], "seconds since 2018-01-01",
        "Elapsed GPS seconds")
    _ds(hg, "lat_ph", d.lat[order], "degrees_north", "Latitude")
    _ds(hg, "lon_ph", d.lon[order], "degrees_east", "Longitude")
    long_name, description = _h_ph_text(height_crs)
    _ds(hg, "h_ph", d.h[order].astype(np.float32), "meters", long_name,
        description=description)
    if height_crs is not None:
        hg["h_ph"].attrs["vertical_crs"] = str(height_crs)
    _ds(hg, "dist_ph_along", (s_sorted - seg_start[seg]).astype(np.float32), "meters",
        "Distance from equator crossing.")
    _ds(hg, "dist_ph_across", np.zeros(n, np.float32), "meters", "Distance off RGT.")
    _ds(hg, "signal_conf_ph", np.asarray(d.signal_conf)[order], "1", "Photon Signal Confidence",
        flag_meanings="possible_tep not_considered noise buffer low medium high")
    _ds(hg, "quality_ph", np.zeros(n, np.int8), "1", "Photon Quality")

    gg = g.create_group("geolocation")
    _ds(gg, "segment_id", (np.arange(n_seg) + 1 + int(round(dist_x0 / SEGMENT_LENGTH))
                           ).astype(np.int32), "1", "along-track segment ID number.")
    _ds(gg, "segment_dist_x", dist_x0 + seg_start, "meters", "Segment Distance from EQC")
    _ds(gg, "segment_length", np.full(n_seg, SEGMENT_LENGTH), "meters",
        "along-track segment length")
    _ds(gg, "ph_index_beg", beg.astype(np.int64), "counts", "Photon Index Begin")
    _ds(gg, "segment_ph_cnt", cnt.astype(np.int32), "counts", "Number of photons")
    _ds(gg, "reference_photon_index", (cnt > 0).astype(np.int32), "counts",
        "Reference Photon Index")
    _ds(gg, "reference_photon_lat", ref_lat, "degrees_north", "Segment Latitude")
    _ds(gg, "reference_photon_lon", ref_lon, "degrees_east", "Segment Longitude")
    _ds(gg, "delta_time", ref_t, "seconds since 2018-01-01", "Delta Time")

    if d.background is not None:
        _write_background(g, d.background)
    if d.extra:
        eg = g.create_group(extra_group)
        eg.attrs["description"] = "per-photon columns added by canopyblocks (e.g. truth)"
        for name, arr in d.extra.items():
            eg.create_dataset(name, data=np.asarray(arr)[order])


# attributes of the real MABEL L2A photon datasets (from the granule's DMR)
_MABEL_ATTRS: dict[str, dict[str, str]] = {
    "delta_time": {"units": "seconds", "long_name": "delta_time", "standard_name": "time",
                   "description": "Elapsed seconds since first data point in granule",
                   "source": "Derived (gps_seconds-gps_second_offset)"},
    "elev": {"units": "meters", "long_name": "elev", "standard_name": "elevation",
             "description": "Height above the WGS84 ellipsoid",
             "source": "Derived (Geolocation ATBD)"},
    "flag": {"units": "NA", "long_name": "flag", "standard_name": "flag",
             "description": "Undefined 1-byte Flag", "source": "Derived (TBD)"},
    "latitude": {"units": "degrees_north", "long_name": "lat", "standard_name": "latitude",
                 "description": "Latitude, WGS84, North=+",
                 "source": "Derived (Geolocation ATBD)"},
    "longitude": {"units": "degrees_east", "long_name": "lon", "standard_name": "longitude",
                  "description": "Longitude, WGS84, East=+",
                  "source": "Derived (Geolocation ATBD)"},
    "photon_id": {"units": "NA", "long_name": "photon_id", "standard_name": "photon_id",
                  "description": "Photon-per-shot counter.  Increments for each photon "
                                 "detected within a shot.  Together with shot_num, forms a "
                                 "unique identifier for each photon. However, be aware of "
                                 "shot_num rollover.", "source": "Derived"},
    "shot_num": {"units": "counts", "long_name": "shot_number", "standard_name": "counter",
                 "description": "Shot Number, copied from the L1A shottag packet.",
                 "source": "L1A Shottag packet"},
}


def write_mabel(
    path: str | os.PathLike[str],
    channels: Mapping[int, MabelChannelData],
    *,
    extra_group: str = "canopyblocks_truth",
) -> Path:
    """Write channels of photons as a MABEL L2A-layout HDF5 file (atomically).

    Parameters
    ----------
    path : path-like
        Output ``.h5`` file.
    channels : mapping channel number (1..999) -> MabelChannelData
    extra_group : str
        Top-level group for extra per-photon columns (``<extra_group>/channelNNN``).

    Returns
    -------
    Path
        ``path``.
    """
    from ..arguments import check_mapping, check_path
    check_path(path, "write_mabel: path")
    check_mapping(
        channels,
        "write_mabel: channels",
        "a dict of channel number -> MabelChannelData",
        MabelChannelData,
    )
    import h5py

    if not channels:
        raise InputError("write_mabel needs at least one channel")
    for ch, data in channels.items():
        if isinstance(ch, bool) or not isinstance(ch, (int, np.integer)) or not 0 < ch < 1000:
            raise InputError(f"MABEL channel {ch!r} must be an integer in 1..999")
        if not isinstance(data, MabelChannelData):
            raise InputError(f"channel {ch}: expected MabelChannelData, "
                             f"got {type(data).__name__}")
    out = Path(path)
    with atomic_output(out) as tmp, h5py.File(tmp, "w") as f:
        photon = f.create_group("photon")
        photon.attrs["Description"] = ("This group contains subgroups of per-channel photon "
                                       "parameters (written by canopyblocks).")
        for ch, d in sorted(channels.items()):
            g = photon.create_group(f"channel{int(ch):03d}")
            cols = {"delta_time": d.delta_time, "elev": d.elev.astype(np.float32),
                    "flag": d.flag, "latitude": d.lat, "longitude": d.lon,
                    "photon_id": d.photon_id, "shot_num": d.shot_num}
            for name, arr in cols.items():
                ds = g.create_dataset(name, data=arr)
                ds.attrs["hertz"] = " per photon"
                for k, v in _MABEL_ATTRS[name].items():
                    ds.attrs[k] = v
            if d.extra:
                eg = f.require_group(f"{extra_group}/channel{int(ch):03d}")
                for name, arr in d.extra.items():
                    eg.create_dataset(name, data=arr)
    log.info("wrote MABEL-layout file %s (channels %s)", out, sorted(channels))
    return out
