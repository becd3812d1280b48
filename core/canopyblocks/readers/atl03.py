"""ICESat-2 ATL03 (v005/v006) geolocated photons, one ground-track beam at a time.

Layout used (as in real granules): ``gtXX/heights/{delta_time, lat_ph, lon_ph, h_ph,
dist_ph_along, signal_conf_ph}`` per photon and ``gtXX/geolocation/{segment_id,
segment_dist_x, segment_length, ph_index_beg, segment_ph_cnt, reference_photon_lat,
reference_photon_lon}`` per ~20 m geolocation segment.  Photons of segment ``i`` are
rows ``ph_index_beg[i] - 1 ... + segment_ph_cnt[i]`` (1-based; 0 marks an empty
segment).  A subset is found from the segments first, so only the needed photon rows
are read.

Speed (``bench/bench_blocks.py``): when the selected segments tile one run of rows
(a whole beam of a real granule), each column is read straight into its final array (HDF5
widens float32 to float64 on the fly), ``signal_conf_ph`` column 0 goes through a
small buffer, no per-photon index arrays are built, the UTM zone comes from the
coordinate ranges, only out-of-order tracks are sorted, and ``x``/``y`` come from
:func:`canopyblocks.geo.to_metric_local_affine` (within 0.1 mm of pyproj).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyproj
from numpy.typing import DTypeLike

from ..errors import FileFormatError, InputError, NoUsableDataError
from ..geo import as_crs, to_metric_local_affine
from ..photons import PhotonTrack, stable_order
from ..progress import Progress, as_progress
from ._common import bbox_mask, check_bbox, check_s_range, s_mask
from ._h5 import H5File, open_h5
from .atl03_background import read_background_rate, whole_track_background
from .atl03_geolocation import GEOLOCATION_SIGMA_COLUMN, segment_geolocation_sigma
from .atl08 import BEAMS, join_atl08, read_atl08_photons
from .photon_checks import (
    PHOTON_LIMITS,
    S_LIMIT,
    check_photon_datasets,
    drop_invalid_photons,
    valid_photon_mask,
)

__all__ = ["BeamInfo", "BEAMS", "atl03_beams", "atl03_track_start", "read_atl03",
           "beam_strength", "beam_spot", "EXTRA_GROUP"]

log = logging.getLogger(__name__)

EXTRA_GROUP = "canopyblocks_truth"
"""Per-beam group holding extra per-photon columns (the simulator's truth)."""

PHOTON_DATASETS = ("h_ph", "lat_ph", "lon_ph", "dist_ph_along", "delta_time")
"""Per-photon datasets of ``gtXX/heights`` every read needs."""
_SEG_MARGIN_M = 25.0  # photons lie up to ~1 m outside their 20 m segment; keep one more
_BBOX_MARGIN_M = 30.0  # plus one neighbouring segment each side


@dataclass(frozen=True)
class BeamInfo:
    """One ATL03 beam of a file.

    Attributes
    ----------
    name : str
        ``"gt1l"`` ... ``"gt3r"``.
    strength : str
        ``"strong"``, ``"weak"``, or ``"unknown"`` (spacecraft in transition).
    n_photons : int
        Photons in ``gtXX/heights``.
    spot : int or None
        ATLAS spot number 1-6 when known.
    """

    name: str
    strength: str
    n_photons: int
    spot: int | None = None


def beam_strength(beam: str, sc_orient: int | None) -> str:
    """Beam strength from ``orbit_info/sc_orient``.

    0 (backward): the left beams (``gtXl``) are strong; 1 (forward): the right
    beams (``gtXr``) are strong; 2 (transition) or unknown: ``"unknown"``.
    """
    if sc_orient == 0:
        return "strong" if beam.endswith("l") else "weak"
    if sc_orient == 1:
        return "strong" if beam.endswith("r") else "weak"
    return "unknown"


def beam_spot(beam: str, sc_orient: int | None) -> int | None:
    """ATLAS spot number (1, 3, 5 strong; 2, 4, 6 weak) of ``beam`` for ``sc_orient``."""
    if beam not in BEAMS or sc_orient not in (0, 1):
        return None
    i = BEAMS.index(beam)
    return i + 1 if sc_orient == 0 else 6 - i


def _sc_orient(f: H5File) -> int | None:
    v: Any = f.scalar("orbit_info/sc_orient")  # an untyped HDF5 value; int() may refuse it
    try:
        return None if v is None else int(v)
    except (TypeError, ValueError):
        return None


def _file_beams(f: H5File) -> list[str]:
    return [b for b in BEAMS if f.is_group(f"{b}/heights")]


def _require_atl03(f: H5File) -> list[str]:
    beams = _file_beams(f)
    if not beams:
        short = f.attr("/", "short_name")
        hint = f" (its short_name is {short!r})" if short else ""
        raise FileFormatError(
            f"{f.path}: not an ATL03 file{hint}: no gtXX/heights group (beams gt1l..gt3r); "
            "pass an ICESat-2 ATL03 granule"
        )
    return beams


def _beam_info(f: H5File, beam: str, sc_orient: int | None) -> BeamInfo:
    kind = f.attr(beam, "atlas_beam_type")
    strength = str(kind).lower() if kind in ("strong", "weak", b"strong", b"weak") else \
        beam_strength(beam, sc_orient)
    spot_attr: Any = f.attr(beam, "atlas_spot_number")  # untyped HDF5 attribute
    try:
        spot: int | None = int(spot_attr)
    except (TypeError, ValueError):
        spot = beam_spot(beam, sc_orient)
    if not f.is_dataset(f"{beam}/heights/h_ph") and f.keys(f"{beam}/heights"):
        raise FileFormatError(f"{f.path}: /{beam}/heights/h_ph is missing (the group holds "
                              f"{', '.join(f.keys(f'{beam}/heights')[:6])}); the file is damaged")
    shape = f.shape(f"{beam}/heights/h_ph") if f.is_dataset(f"{beam}/heights/h_ph") else ()
    return BeamInfo(beam, strength, int(shape[0]) if len(shape) == 1 else 0, spot)


def atl03_track_start(path: str | os.PathLike[str], beam: str) -> float | None:
    """Along-track distance (m, ``segment_dist_x``) of the first segment of ``beam``
    holding photons: the track's start, read from the head of the geolocation segments
    alone (None when no segment holds a photon)."""
    g = f"{beam}/geolocation"
    with open_h5(path, "ATL03") as f:
        shape = f.shape(f"{g}/segment_ph_cnt") if f.is_dataset(f"{g}/segment_ph_cnt") else ()
        n = int(shape[0]) if len(shape) == 1 else 0
        lo, step = 0, 1024
        while lo < n:  # slices growing fourfold: a few small reads, however long the beam
            sel = np.s_[lo:min(n, lo + step)]
            cnt = f.read(f"{g}/segment_ph_cnt", sel, dtype=np.int64)
            beg = f.read(f"{g}/ph_index_beg", sel, dtype=np.int64)
            hit = (cnt > 0) & (beg > 0)
            if hit.any():
                return float(np.min(f.read(f"{g}/segment_dist_x", sel, dtype=np.float64)[hit]))
            lo, step = lo + step, step * 4
    return None


def atl03_beams(path: str | os.PathLike[str]) -> list[BeamInfo]:
    """The beams of an ATL03 file, in the order gt1l, gt1r, ..., gt3r.

    Strength comes from the beam group's ``atlas_beam_type`` attribute when present,
    else from ``orbit_info/sc_orient``.

    Raises
    ------
    FileFormatError
        Not an ATL03 file (no ``gtXX/heights``), not HDF5, or unreadable.
    """
    with open_h5(path, "ATL03") as f:
        beams = _require_atl03(f)
        orient = _sc_orient(f)
        return [_beam_info(f, b, orient) for b in beams]


@dataclass(frozen=True, eq=False)
class _Segments:
    segment_id: np.ndarray  # int64
    start0: np.ndarray  # 0-based first photon row
    count: np.ndarray  # photons in the segment
    dist_x: np.ndarray  # metres from the equator crossing
    length: np.ndarray  # metres
    ref_lat: np.ndarray | None
    ref_lon: np.ndarray | None

    def take(self, mask: np.ndarray) -> _Segments:
        return _Segments(
            self.segment_id[mask], self.start0[mask], self.count[mask], self.dist_x[mask],
            self.length[mask],
            None if self.ref_lat is None else self.ref_lat[mask],
            None if self.ref_lon is None else self.ref_lon[mask],
        )


def _read_segments(f: H5File, beam: str, n_photons: int) -> _Segments:
    g = f"{beam}/geolocation"
    seg_id = f.read(f"{g}/segment_id", dtype=np.int64)
    beg = f.read(f"{g}/ph_index_beg", dtype=np.int64)
    cnt = f.read(f"{g}/segment_ph_cnt", dtype=np.int64)
    dist_x = f.read(f"{g}/segment_dist_x", dtype=np.float64)
    length = f.read(f"{g}/segment_length", dtype=np.float64) \
        if f.is_dataset(f"{g}/segment_length") else np.full(seg_id.shape, 20.0)
    ref_lat = ref_lon = None
    if f.is_dataset(f"{g}/reference_photon_lat") and f.is_dataset(f"{g}/reference_photon_lon"):
        ref_lat = f.read(f"{g}/reference_photon_lat", dtype=np.float64)
        ref_lon = f.read(f"{g}/reference_photon_lon", dtype=np.float64)
    shapes = {a.shape for a in (seg_id, beg, cnt, dist_x, length)}
    if len(shapes) != 1 or seg_id.ndim != 1:
        raise FileFormatError(
            f"{f.path}: {g}: segment_id, ph_index_beg, segment_ph_cnt, segment_dist_x and "
            "segment_length have different shapes; the geolocation group is corrupt"
        )
    if ref_lat is not None and ref_lon is not None and (
            ref_lat.shape != seg_id.shape or ref_lon.shape != seg_id.shape):
        ref_lat = ref_lon = None
    nonempty = (cnt > 0) & (beg > 0)
    end = beg + cnt - 1  # 1-based last photon row
    if np.any(cnt < 0) or np.any(end[nonempty] > n_photons):
        raise FileFormatError(
            f"{f.path}: {g}: ph_index_beg/segment_ph_cnt point past the {n_photons} photons "
            f"of {beam}/heights; the file is truncated or inconsistent"
        )
    segs = _Segments(seg_id, beg - 1, cnt, dist_x, length, ref_lat, ref_lon).take(nonempty)
    return _repair_index(f, beam, segs, n_photons)


_REPAIRED: set[tuple[str, str]] = set()  # (file, beam) already reported, to say it once


def _repair_index(f: H5File, beam: str, segs: _Segments, n_photons: int) -> _Segments:
    """Check that segments do not overlap; fix a known clipping-tool off-by-one.

    In real granules ``ph_index_beg[i+1] = ph_index_beg[i] + segment_ph_cnt[i]``
    over non-empty segments.  Some clipping tools rewrite ``ph_index_beg`` as the
    running count without the +1 (e.g. the ICESat2VegR sample clip), so the
    segments overlap by one photon.  When the counts tile the photon array exactly
    (sum = number of photons), the cumulative counts are used instead (checked on
    the shared Wyoming clip: every ATL08 photon then joins with identical
    ``delta_time``).  Other overlaps are a corrupt file.
    """
    if segs.count.size < 2:
        return segs
    next_start = segs.start0[:-1] + segs.count[:-1]
    if np.all(segs.start0[1:] >= next_start):
        return segs  # consistent (gaps are allowed)
    excl = np.cumsum(segs.count) - segs.count
    if int(segs.count.sum()) == n_photons and np.all(np.abs(segs.start0 - excl) <= 1):
        key = (str(f.path), beam)
        (log.info if key in _REPAIRED else log.warning)(
            "%s: %s/geolocation/ph_index_beg overlaps segment_ph_cnt (off by one, as written "
            "by some clipping tools); using the cumulative segment_ph_cnt instead",
            f.path, beam)
        _REPAIRED.add(key)
        return _Segments(segs.segment_id, excl, segs.count, segs.dist_x, segs.length,
                         segs.ref_lat, segs.ref_lon)
    raise FileFormatError(
        f"{f.path}: {beam}/geolocation: ph_index_beg and segment_ph_cnt make segments "
        "overlap; the geolocation group is corrupt"
    )


def _select_segments(segs: _Segments, bbox: tuple[float, float, float, float] | None,
                     s_range: tuple[float, float] | None) -> np.ndarray:
    """Segments that may hold photons inside ``bbox``/``s_range`` (a superset)."""
    keep = np.ones(segs.segment_id.size, dtype=bool)
    if s_range is not None:
        lo = segs.dist_x - _SEG_MARGIN_M
        hi = segs.dist_x + segs.length + _SEG_MARGIN_M
        keep &= (hi >= s_range[0]) & (lo <= s_range[1])
    if bbox is not None and segs.ref_lat is not None and segs.ref_lon is not None:
        lat, lon = segs.ref_lat, segs.ref_lon
        valid = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (np.abs(lon) <= 360)
        dlat = _BBOX_MARGIN_M / 111_000.0
        coslat = np.cos(np.radians(np.clip(np.where(valid, lat, 0.0), -89.9, 89.9)))
        dlon = np.minimum(dlat / coslat, 360.0)
        near = (lat >= bbox[1] - dlat) & (lat <= bbox[3] + dlat) & \
            (lon >= bbox[0] - dlon) & (lon <= bbox[2] + dlon)
        near |= ~valid  # cannot tell: keep, the photon filter decides
        # one segment more on each side (photons scatter around the reference photon)
        grown = near.copy()
        grown[1:] |= near[:-1]
        grown[:-1] |= near[1:]
        keep &= grown
    return keep


def _photon_rows(segs: _Segments) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per photon: 0-based row in heights, index of its segment, 1-based index within it."""
    total = int(segs.count.sum())
    excl = np.cumsum(segs.count) - segs.count  # photons before each segment
    seg_of_ph = np.repeat(np.arange(segs.count.size), segs.count)
    within0 = np.arange(total, dtype=np.int64) - excl[seg_of_ph]
    rows = segs.start0[seg_of_ph] + within0
    return rows, seg_of_ph, within0 + 1


def _signal_conf_message(beam: str, path: object, conf: np.ndarray, minimum: int) -> str:
    vals = np.unique(conf)
    if vals.size and np.all(vals == -1):
        why = ("all -1: not a land surface type in this part of the granule (e.g. sea ice or "
               "ocean); drop min_signal_conf to use every photon")
    elif vals.size:
        why = f"the highest is {int(vals.max())}; lower min_signal_conf or drop it"
    else:
        why = "there are no photons"
    return (f"{beam} of {path}: no photon has land signal confidence >= {minimum} ({why})")


def read_atl03(
    path: str | os.PathLike[str],
    beam: str,
    *,
    bbox: Sequence[float] | None = None,
    s_range: Sequence[float] | None = None,
    atl08: str | os.PathLike[str] | None = None,
    crs: pyproj.CRS | str | int | None = None,
    min_signal_conf: int | None = None,
    extra_group: str | None = EXTRA_GROUP,
    progress: Progress | None = None,
) -> PhotonTrack:
    """Read the photons of one ATL03 beam.

    Parameters
    ----------
    path : path-like
        ATL03 granule (HDF5), v005/v006 layout (subsets such as NSIDC/Harmony clips
        work; ``ancillary_data`` and ``orbit_info`` are optional).
    beam : str
        ``"gt1l"`` ... ``"gt3r"``.
    bbox : (lon_min, lat_min, lon_max, lat_max), optional
        WGS84 degrees; only photons inside are returned.  Only the geolocation
        segments near the box are read.
    s_range : (s_min, s_max), optional
        Along-track distance, metres, in the product's frame (``segment_dist_x``:
        distance from the equator crossing).
    atl08 : path-like, optional
        The matching ATL08 granule; its ``signal_photons`` classes are joined by
        (``ph_segment_id``, ``classed_pc_indx``) into ``track.classification``
        (-1 = not classified).
    crs : CRS-like, optional
        Metric CRS for ``x``/``y`` (default: UTM zone of the track centre).
    min_signal_conf : int, optional
        Keep only photons whose land ``signal_conf_ph`` (column 0) is at least this
        (-2..4).
    extra_group : str or None
        Per-beam group whose 1-D per-photon datasets go into ``track.extra``
        (the simulator's truth); None skips it.
    progress : Progress, optional

    Returns
    -------
    PhotonTrack
        ``time`` = ``delta_time`` (s since the ATLAS SDP epoch), ``h`` = ``h_ph``
        (m above the WGS84 ellipsoid, ``vertical_datum="EPSG:4979"``; a file written by
        canopyblocks from airborne lidar states its heights' CRS in the root attribute
        ``canopyblocks_height_crs``, which then becomes ``vertical_datum``),
        ``s = segment_dist_x + dist_ph_along`` (m), ``signal_conf`` = land column,
        ``background`` = ``bckgrd_atlas/bckgrd_rate`` (photons/s) when present;
        sorted by ``s``.

    Raises
    ------
    FileFormatError
        Not HDF5/ATL03, truncated, or a required dataset is missing.
    InputError
        Unknown beam or a beam the file lacks (the message lists the file's beams),
        bad ``bbox``/``s_range``/``min_signal_conf``, ATL08 not matching.
    NoUsableDataError
        No photon in the beam / subset, or none reaching ``min_signal_conf``.
    """
    prog = as_progress(progress)
    bb = check_bbox(bbox)
    sr = check_s_range(s_range)
    beam = str(beam).lower().strip()
    if beam not in BEAMS:
        raise InputError(f"beam {beam!r} is not an ATL03 beam; use one of {', '.join(BEAMS)}")
    if min_signal_conf is not None and (
            not isinstance(min_signal_conf, (int, np.integer)) or not -2 <= min_signal_conf <= 4):
        raise InputError(f"min_signal_conf {min_signal_conf!r} must be an integer in -2..4")
    prog.update(0.0, f"reading {beam}")
    with open_h5(path, "ATL03") as f:
        beams = _require_atl03(f)
        if beam not in beams:
            orient = _sc_orient(f)
            have = ", ".join(f"{b.name} ({b.strength}, {b.n_photons} photons)"
                             for b in (_beam_info(f, b, orient) for b in beams))
            raise InputError(f"{f.path}: beam {beam} is not in this file; it has {have}")
        hg = f"{beam}/heights"
        n_all = check_photon_datasets(f, hg, PHOTON_DATASETS, optional=("signal_conf_ph",))
        segs = _read_segments(f, beam, n_all)
        if n_all == 0 or segs.segment_id.size == 0:
            raise NoUsableDataError(f"{f.path}: beam {beam} has no photons")
        segs = segs.take(_select_segments(segs, bb, sr))
        total = int(segs.count.sum())
        if total == 0:
            raise NoUsableDataError(_empty_message(f, beam, bb, sr))
        # the common case: the selected segments tile one run of photon rows, so every
        # column is read straight into its final array (no index arrays, no gathers)
        contiguous = bool(np.all(segs.start0[1:] == segs.start0[:-1] + segs.count[:-1]))
        if contiguous:
            lo = int(segs.start0[0])
            hi = lo + total
            take = None
        else:
            rows = _photon_rows(segs)[0]
            lo, hi = int(rows.min()), int(rows.max()) + 1
            take = rows - lo
            del rows
        prog.update(0.2, f"reading {total} photons of {beam}")

        def col(name: str, dtype: DTypeLike = None, column: int | None = None) -> np.ndarray:
            if take is None and column is not None:
                return f.read_column(f"{hg}/{name}", lo, hi, column, dtype)
            arr = f.read(f"{hg}/{name}", np.s_[lo:hi], dtype=dtype)
            if take is None:
                return arr
            if column is not None and arr.ndim == 2:
                arr = arr[:, column]
            return arr[take]

        def valid(name: str, values: np.ndarray) -> np.ndarray:
            return valid_photon_mask(name, values, f.attr(f"{hg}/{name}", "_FillValue"))

        lat = col("lat_ph", np.float64)
        lon = col("lon_ph", np.float64)
        s = col("dist_ph_along", np.float64)
        masks = {f"{hg}/lat_ph": valid("lat_ph", lat), f"{hg}/lon_ph": valid("lon_ph", lon),
                 f"{hg}/dist_ph_along": valid("dist_ph_along", s)}
        _add_per_segment(s, segs.dist_x, segs.count)  # s = segment_dist_x + dist_ph_along
        with np.errstate(invalid="ignore"):
            masks[f"{beam}/geolocation/segment_dist_x"] = np.abs(s) < S_LIMIT + PHOTON_LIMITS["dist_ph_along"][1]
        keep = None
        if bb is not None or sr is not None:
            keep = bbox_mask(lon, lat, bb) & s_mask(s, sr)
        conf = None
        cpath = f"{hg}/signal_conf_ph"
        if f.is_dataset(cpath):
            ndim = len(f.shape(cpath))
            conf = col("signal_conf_ph", None, 0 if ndim == 2 else None)
            masks[cpath] = valid("signal_conf_ph", conf)
            conf = conf.astype(np.int8, copy=False)  # wrapped values are dropped below
        elif min_signal_conf is not None:
            raise FileFormatError(f"{f.path}: /{hg}/signal_conf_ph is missing, so "
                                  "min_signal_conf cannot be applied; drop min_signal_conf")
        if keep is not None and not keep.any():
            raise NoUsableDataError(_empty_message(f, beam, bb, sr))
        if min_signal_conf is not None and conf is not None:
            ok = conf >= min_signal_conf
            if not (ok if keep is None else ok & keep).any():
                raise NoUsableDataError(_signal_conf_message(
                    beam, f.path, conf if keep is None else conf[keep], int(min_signal_conf)))
            keep = ok if keep is None else keep & ok
        if keep is not None and bool(keep.all()):
            keep = None
        cut = keep is not None or total < n_all  # a part of the track: settle its rate whole
        prog.update(0.5, "reading heights")
        cols: dict[str, np.ndarray] = {
            "time": col("delta_time", np.float64), "lat": lat, "lon": lon,
            "h": col("h_ph", np.float64), "s": s}
        masks[f"{hg}/h_ph"] = valid("h_ph", cols["h"])
        masks[f"{hg}/delta_time"] = valid("delta_time", cols["time"])
        usable = drop_invalid_photons(f.path, f"beam {beam}", masks)
        del masks
        if usable is not None:
            keep = usable if keep is None else keep & usable
            if not keep.any():
                raise NoUsableDataError(
                    f"{f.path}: beam {beam}: no photon with valid values is left in the "
                    "selection (bbox, s_range, min_signal_conf)")
        del lat, lon, s
        if conf is not None:
            cols["signal_conf"] = conf
            del conf
        extra: dict[str, np.ndarray] = {}
        if extra_group and f.is_group(f"{beam}/{extra_group}"):
            for name in f.keys(f"{beam}/{extra_group}"):
                dpath = f"{beam}/{extra_group}/{name}"
                if f.is_dataset(dpath) and f.shape(dpath) == (n_all,):
                    arr = f.read(dpath, np.s_[lo:hi])
                    extra[name] = arr if take is None else arr[take]
        geo = segment_geolocation_sigma(f, beam, segs.segment_id)
        if geo is not None:  # per photon, in the order the columns were read
            extra[GEOLOCATION_SIGMA_COLUMN] = np.repeat(geo.astype(np.float32), segs.count)
        seg_ids = within_k = None
        if atl08 is not None:
            _rows, seg_of_ph, within = _photon_rows(segs)
            del _rows
            seg_ids = segs.segment_id[seg_of_ph]
            within_k = within
            del seg_of_ph, within
        if keep is not None:
            for k in list(cols):
                cols[k] = cols[k][keep]
            for k in list(extra):
                extra[k] = extra[k][keep]
            if seg_ids is not None and within_k is not None:
                seg_ids, within_k = seg_ids[keep], within_k[keep]
        keep = None
        rgt_cycle = (f.scalar("orbit_info/rgt"), f.scalar("orbit_info/cycle_number"))
        src = str(f.path)
        stated = f.attr("/", "canopyblocks_height_crs")
        height_crs = stated if isinstance(stated, str) and stated.strip() else "EPSG:4979"
        background = read_background_rate(f, beam, float(np.min(cols["time"])),
                                          float(np.max(cols["time"])))
        background = whole_track_background(f, beam, background, cut=cut, photons=(
            cols["s"], cols["h"], cols["time"]))
    if atl08 is not None and seg_ids is not None and within_k is not None:
        prog.update(0.7, "joining ATL08 classes")
        a8 = read_atl08_photons(atl08, beam)
        _check_same_granule(src, rgt_cycle, a8.source, (a8.rgt, a8.cycle))
        cols["classification"] = np.asarray(
            join_atl08(seg_ids, within_k, cols["time"], a8, what=f"{beam} of {src}"), np.int8)
        del seg_ids, within_k
    prog.update(0.85, "projecting")
    _sort_by_s(cols, extra)
    x, y, used = to_metric_local_affine(cols["lon"], cols["lat"],
                                        None if crs is None else as_crs(crs, "photon CRS"))
    track = PhotonTrack(
        time=cols["time"], lat=cols["lat"], lon=cols["lon"], h=cols["h"], x=x, y=y,
        s=cols["s"], track=beam, crs=used, signal_conf=cols.get("signal_conf"),
        classification=cols.get("classification"), extra=extra, source=src,
        vertical_datum=height_crs, background=background,
    )
    prog.update(1.0, f"{beam}: {len(track)} photons")
    log.info("read %d photons of %s from %s", len(track), beam, src)
    return track


def _add_per_segment(arr: np.ndarray, values: np.ndarray, count: np.ndarray) -> None:
    """``arr += np.repeat(values, count)`` in place, ~64k photons at a time (no
    full-length temporary)."""
    ends = np.cumsum(count)
    if ends.size == 0:
        return
    cuts = np.r_[0, np.searchsorted(ends, np.arange(1 << 16, int(ends[-1]), 1 << 16)),
                 ends.size]
    cuts = np.unique(cuts)
    for a, b in zip(cuts[:-1].tolist(), cuts[1:].tolist()):
        p0 = int(ends[a - 1]) if a else 0
        arr[p0:int(ends[b - 1])] += np.repeat(values[a:b], count[a:b])


def _sort_by_s(cols: dict[str, np.ndarray], extra: dict[str, np.ndarray]) -> None:
    """Sort every column by ``cols["s"]`` in place in the dicts (stable: ties keep file
    order).  Real ATL03 photons are only locally out of order (``dist_ph_along`` scatters
    by ~1 m), so they are sorted window by window, in place
    (:func:`~canopyblocks.readers.photon_order.sort_columns_in_windows`: the same order as a
    global stable sort, scratch memory of a few windows); synthetic ones often are in
    order already (one cheap comparison pass)."""
    from .photon_order import sort_columns_in_windows

    s = cols["s"]
    arrays = [*cols.values(), *extra.values()]
    if (len({id(a) for a in arrays}) == len(arrays)
            and all(a.ndim >= 1 and a.shape[0] == s.size and a.flags.writeable
                    and a.base is None for a in arrays)):
        # (checks the order itself; touches nothing when it is already sorted)
        sort_columns_in_windows({**{f"c:{k}": v for k, v in cols.items()},
                                 **{f"e:{k}": v for k, v in extra.items()}}, "c:s")
        return
    if s.size < 2 or bool(np.all(s[1:] >= s[:-1])):
        return
    order = stable_order(s)
    for d in (cols, extra):
        for k in list(d):
            d[k] = d[k][order]


def _check_same_granule(a03: str, rc03: tuple[Any, Any], a08: str,
                        rc08: tuple[Any, Any]) -> None:
    """(RGT, cycle) pairs are untyped HDF5 scalars (or None when a file lacks them)."""
    if None in rc03 or None in rc08:
        return
    if tuple(int(v) for v in rc03) != tuple(int(v) for v in rc08):
        raise InputError(
            f"ATL08 file {a08} is from RGT {rc08[0]} cycle {rc08[1]} but ATL03 file {a03} is "
            f"from RGT {rc03[0]} cycle {rc03[1]}; pass the matching ATL08 granule"
        )


def _empty_message(f: H5File, beam: str, bbox: object, s_range: object) -> str:
    cover = ""
    try:
        segs = _read_segments(f, beam, f.shape(f"{beam}/heights/h_ph")[0])
        if segs.ref_lat is not None and segs.ref_lon is not None and segs.ref_lat.size:
            lon, lat = segs.ref_lon, segs.ref_lat
            cover = (f"; the beam covers lon {np.nanmin(lon):.5f}..{np.nanmax(lon):.5f}, "
                     f"lat {np.nanmin(lat):.5f}..{np.nanmax(lat):.5f}")
        if segs.dist_x.size:
            cover += (f", s {segs.dist_x.min():.1f}.."
                      f"{(segs.dist_x + segs.length).max():.1f} m")
    except FileFormatError:
        pass
    return (f"{f.path}: no photons of {beam} inside bbox={bbox} s_range={s_range}{cover}")
