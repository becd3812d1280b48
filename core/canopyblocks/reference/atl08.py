"""ATL08 land segments as a reference for photon blocks (issue 3 item 8).

ATL08 (ICESat-2 land and vegetation heights) summarises each beam in 100 m land
segments (five 20 m ATL03 geolocation segments).  Read per beam from
``gtXX/land_segments``: ``latitude``, ``longitude`` (segment centre, degrees),
``delta_time``, ``segment_id_beg``/``segment_id_end``, ``terrain/h_te_best_fit``
(terrain height at the centre, m, WGS84 ellipsoid), ``canopy/h_canopy`` (RH98 above
terrain, m) and ``canopy/canopy_h_metrics`` (relative heights; 18 columns RH10..RH95 in
steps of 5 in v005+, 9 columns RH25, 50, 60, 70, 75, 80, 85, 90, 95 earlier).  The
fill value 3.4028235e38 becomes NaN.

Reference values per matched block: ``ref_ground = h_te_best_fit``,
``ref_hmax = h_canopy``, ``ref_h90 = RH90``, ``ref_top = ref_ground + h_canopy``,
``ref_top90 = ref_ground + RH90``.  All heights are ellipsoidal like ATL03 photons.

Matching (``match="nearest"``): each segment centre is projected into the blocks' CRS
and matched to the nearest block centre of the same track and block length, if
within ``max_distance`` (default: the block length).  A block claimed by several
segments keeps the closest.  Unmatched blocks get ``ref_flag = "nomatch"``.  Note that
a 100 m segment and a shorter block describe different footprints; use 100 m blocks
aligned with the segments for a like-for-like comparison.
"""

from __future__ import annotations

import logging
import os

import numpy as np
import pandas as pd
import pyproj
from scipy.spatial import cKDTree

from ..errors import CRSError, FileFormatError, InputError, NoUsableDataError
from ..geo import WGS84
from ..readers._h5 import open_h5
from ..readers.atl08 import BEAMS, check_atl08_beams

__all__ = ["read_atl08_segments", "atl08_reference_values", "atl08_beams", "ATL08_FILL"]

log = logging.getLogger(__name__)

ATL08_FILL = 3.4028235e38
_RH90_COLUMN = {18: 16, 9: 7}  # number of canopy_h_metrics columns -> index of RH90


def atl08_beams(path: str | os.PathLike[str]) -> list[str]:
    """Beams of an ATL08 file that hold ``land_segments``."""
    with open_h5(path, "ATL08") as f:
        return [b for b in BEAMS if f.is_group(f"{b}/land_segments")]


def _clean(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    return np.where(np.isfinite(a) & (np.abs(a) < 1e30), a, np.nan)


def read_atl08_segments(path: str | os.PathLike[str],
                        beams: str | list[str] | None = None) -> pd.DataFrame:
    """Land segments of one or more beams of an ATL08 file.

    Returns
    -------
    DataFrame
        ``beam, lat, lon`` (degrees), ``delta_time`` (s), ``segment_id_beg``,
        ``segment_id_end``, ``h_te_best_fit``, ``h_canopy``, ``rh90`` (m; NaN = fill).

    Raises
    ------
    FileFormatError
        Not an ATL08 file, or a dataset is missing/truncated.
    InputError
        A requested beam is not in the file.
    """
    with open_h5(path, "ATL08") as f:
        want = check_atl08_beams(f, "land_segments",
                           None if beams is None else [beams] if isinstance(beams, str)
                           else list(beams))
        parts = []
        for b in want:
            g = f"{b}/land_segments"
            lat = _clean(f.read(f"{g}/latitude"))
            lon = _clean(f.read(f"{g}/longitude"))
            cols = {
                "beam": np.full(lat.size, b, dtype=object), "lat": lat, "lon": lon,
                "delta_time": _clean(f.read(f"{g}/delta_time")),
                "segment_id_beg": f.read(f"{g}/segment_id_beg", dtype=np.int64),
                "segment_id_end": f.read(f"{g}/segment_id_end", dtype=np.int64),
                "h_te_best_fit": _clean(f.read(f"{g}/terrain/h_te_best_fit")),
                "h_canopy": _clean(f.read(f"{g}/canopy/h_canopy")),
            }
            metrics = _clean(f.read(f"{g}/canopy/canopy_h_metrics"))
            if metrics.ndim != 2 or metrics.shape[1] not in _RH90_COLUMN:
                raise FileFormatError(
                    f"{f.path}: /{g}/canopy/canopy_h_metrics has shape {metrics.shape}; "
                    "expected (n, 18) (ATL08 v005+) or (n, 9)"
                )
            cols["rh90"] = metrics[:, _RH90_COLUMN[metrics.shape[1]]]
            sizes = {k: np.shape(v)[0] for k, v in cols.items()}
            if len(set(sizes.values())) != 1 or metrics.shape[0] != lat.size:
                raise FileFormatError(f"{f.path}: /{g}: datasets of different lengths {sizes}")
            parts.append(pd.DataFrame(cols))
    return pd.concat(parts, ignore_index=True)


def atl08_reference_values(blocks: pd.DataFrame, segments: pd.DataFrame, *,
                           max_distance: float | None = None) -> pd.DataFrame:
    """Reference values for blocks from ATL08 land segments (nearest block centre).

    Parameters
    ----------
    blocks : GeoDataFrame
        Block table in a metric CRS (``x``/``y`` block centres, metres).
    segments : DataFrame
        From :func:`read_atl08_segments`.  Segments of the beam named like the block
        ``track`` are used; if no beam matches a track and the file has a single
        beam, that beam is used.
    max_distance : float, optional
        Metres between segment centre and block centre; default the block length.

    Returns
    -------
    DataFrame
        Index of ``blocks``; ``track, length, block, ref_ground, ref_top, ref_top90,
        ref_hmax, ref_h90, coverage`` (NaN: not applicable), ``ref_flag`` (``ok``,
        ``nomatch``, ``nodata``) and ``atl08_segment_id`` (segment_id_beg, -1 if none).
    """
    crs = getattr(blocks, "crs", None)
    if crs is None:
        raise CRSError("the block table has no CRS; ATL08 segments cannot be placed on it")
    if max_distance is not None and not (np.isfinite(max_distance) and max_distance > 0):
        raise InputError(f"max_distance must be a positive number of metres, got {max_distance!r}")
    seg_ok = np.isfinite(segments["lat"].to_numpy(float)) & \
        np.isfinite(segments["lon"].to_numpy(float))
    segs = segments[seg_ok].reset_index(drop=True)
    if segs.empty:
        raise NoUsableDataError("the ATL08 file has no land segment with a position")
    tr = pyproj.Transformer.from_crs(WGS84, pyproj.CRS.from_user_input(crs), always_xy=True)
    sx, sy = tr.transform(segs["lon"].to_numpy(float), segs["lat"].to_numpy(float))
    sxy = np.column_stack([sx, sy])
    n = len(blocks)
    seg_of_block = np.full(n, -1, dtype=np.int64)
    bx = blocks["x"].to_numpy(float)
    by = blocks["y"].to_numpy(float)
    tracks = blocks["track"].astype(str).to_numpy()
    lengths = blocks["length"].to_numpy(float)
    beams = segs["beam"].astype(str).to_numpy()
    for (track, length), idx in pd.DataFrame({"t": tracks, "l": lengths}).groupby(
            ["t", "l"], sort=False).groups.items():
        rows = np.asarray(idx)
        s_sel = np.flatnonzero(beams == track)
        if s_sel.size == 0 and np.unique(beams).size == 1:
            s_sel = np.arange(len(segs))
        ok = np.isfinite(bx[rows]) & np.isfinite(by[rows])
        rows = rows[ok]
        if s_sel.size == 0 or rows.size == 0:
            continue
        tree = cKDTree(np.column_stack([bx[rows], by[rows]]))
        lim = float(length) if max_distance is None else float(max_distance)
        dist, k = tree.query(sxy[s_sel], k=1)
        good = np.isfinite(dist) & (dist <= lim)
        order = np.argsort(-dist[good])  # farthest first: the closest claim is written last
        seg_of_block[rows[k[good][order]]] = s_sel[good][order]
    matched = seg_of_block >= 0
    pick = np.where(matched, seg_of_block, 0)

    def take(col: str) -> np.ndarray:
        v = segs[col].to_numpy(float)[pick]
        return np.where(matched, v, np.nan)

    ground = take("h_te_best_fit")
    hcan = take("h_canopy")
    rh90 = take("rh90")
    out = pd.DataFrame(index=blocks.index)
    for c in ("track", "length", "block"):
        out[c] = blocks[c].to_numpy()
    out["ref_ground"] = ground
    out["ref_top"] = ground + hcan
    out["ref_top90"] = ground + rh90
    out["ref_hmax"] = hcan
    out["ref_h90"] = rh90
    out["coverage"] = np.nan
    flag = np.full(n, "nomatch", dtype=object)
    flag[matched] = "ok"
    flag[matched & ~(np.isfinite(ground) & np.isfinite(hcan))] = "nodata"
    out["ref_flag"] = flag
    out["atl08_segment_id"] = np.where(
        matched, segs["segment_id_beg"].to_numpy(np.int64)[pick], -1)
    log.info("matched %d of %d ATL08 segments to blocks", int(np.unique(pick[matched]).size),
             len(segs))
    return out
