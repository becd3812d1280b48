"""ATL08-style land segments from classified photons (DESIGN 1.11).

Segments of ``length`` metres (ATL08: 100 m) along the track, segment ``i`` holding the
photons with ``i*L <= s - s0 < (i+1)*L``; one row per segment holding at least one
classified photon, with ATL08's column names:

- terrain from the ground photons (class 1): ``h_te_mean``, ``h_te_median``, ``h_te_min``,
  ``h_te_max`` (m, the photons' vertical datum), ``h_te_best_fit`` (the classifier's ground
  surface at the segment centre, m), ``terrain_slope`` (rise of the surface over the
  segment / length);
- canopy from the canopy and top-of-canopy photons (classes 2 and 3), heights above the
  ground surface (m): ``h_canopy`` (98th percentile), ``h_mean_canopy``, ``h_max_canopy``,
  ``h_median_canopy``, ``canopy_openness`` (standard deviation, ddof 0), and
  ``canopy_h_metrics_10`` ... ``canopy_h_metrics_95`` (ATL08 v005+'s 18 percentiles, as
  separate columns);
- counts: ``n_te_photons``, ``n_ca_photons`` (class 2), ``n_toc_photons`` (class 3),
  ``n_seg_ph`` (all signal photons, classes 1-3), ``n_noise`` (class 0);
- position: ``x``, ``y`` (track CRS, m) and ``lon``, ``lat`` (WGS84 degrees) of the
  track at the segment centre, ``delta_time`` (s) there, ``s_start``/``s_end`` (m).

Percentiles use numpy's linear interpolation. ``flag``: ``ok``; ``no_ground`` (terrain
statistics NaN; ``h_te_best_fit`` bridged from neighbouring ground); ``no_canopy`` (canopy
heights NaN: no canopy photon, e.g. bare ground).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..errors import InputError, NoUsableDataError
from ..geo import from_metric
from ..photons import PhotonTrack
from .atl08_classify import CLASS_CANOPY, CLASS_GROUND, CLASS_NOISE, CLASS_TOP, Atl08Classes
from .grouped import percentiles_by_group

if TYPE_CHECKING:
    import geopandas as gpd

__all__ = ["SEGMENT_COLUMNS", "CANOPY_METRIC_PERCENTILES", "atl08_segments"]

log = logging.getLogger(__name__)

#: ATL08 v005+ ``canopy_h_metrics`` percentiles (10, 15, ..., 95).
CANOPY_METRIC_PERCENTILES: tuple[int, ...] = tuple(range(10, 100, 5))

SEGMENT_COLUMNS: tuple[str, ...] = (
    "track", "length", "segment", "s_start", "s_end", "x", "y", "lon", "lat", "delta_time",
    "n_seg_ph", "n_te_photons", "n_ca_photons", "n_toc_photons", "n_noise",
    "h_te_mean", "h_te_median", "h_te_min", "h_te_max", "h_te_best_fit", "terrain_slope",
    "h_canopy", "h_mean_canopy", "h_median_canopy", "h_max_canopy", "canopy_openness",
    *(f"canopy_h_metrics_{q}" for q in CANOPY_METRIC_PERCENTILES),
    "flag",
)


def _mean_std(group: np.ndarray, v: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    cnt = np.bincount(group, minlength=n).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(group, v, minlength=n) / cnt
        var = np.bincount(group, (v - mean[group]) ** 2, minlength=n) / cnt
    return mean, np.sqrt(var)


def atl08_segments(track: PhotonTrack, classes: Atl08Classes, length: float = 100.0,
                   s0: float | None = None) -> gpd.GeoDataFrame:
    """ATL08-style segment table of a classified track.

    Parameters
    ----------
    track : PhotonTrack
    classes : Atl08Classes
        From :func:`~canopyblocks.blocks.atl08_classify.classify_photons` on ``track``.
    length : float
        Segment length along the track, m (ATL08: 100).
    s0 : float, optional
        Along-track origin of segment 0 (m, the track's ``s`` axis); default the first
        classified photon. For ATL03 files, the ``segment_dist_x`` of an ATL08 segment's
        first geolocation segment lines the segments up with ATL08's.

    Returns
    -------
    GeoDataFrame
        Columns :data:`SEGMENT_COLUMNS`, point geometry at the segment centre, CRS of the
        track.
    """
    import geopandas as gpd

    if not isinstance(track, PhotonTrack) or not isinstance(classes, Atl08Classes):
        raise InputError("atl08_segments needs a PhotonTrack and its Atl08Classes "
                         f"(got {type(track).__name__}, {type(classes).__name__})")
    if classes.classes.shape != (len(track),):
        raise InputError(f"the classes hold {classes.classes.size} photons but track "
                         f"{track.track} has {len(track)}; classify this track")
    if not (isinstance(length, (int, float)) and np.isfinite(length) and length > 0):
        raise InputError(f"segment length must be a positive number of metres, got {length!r}")
    cls = classes.classes
    valid = cls >= 0
    if not valid.any():
        raise NoUsableDataError(f"track {track.track}: no classified photon")
    s = np.asarray(track.s, float)
    origin = float(np.min(s[valid])) if s0 is None else float(s0)
    rel = np.floor((s - origin) / length)
    inside = valid & (rel >= 0)
    if not inside.any():
        raise NoUsableDataError(f"track {track.track}: no photon at or after s0={origin} m")
    seg_all = rel[inside].astype(np.int64)
    used, seg_idx = np.unique(seg_all, return_inverse=True)
    n = used.size
    c = cls[inside]
    z = np.asarray(track.h, float)[inside]
    hrel = classes.height[inside]

    def count(code: int) -> np.ndarray:
        return np.bincount(seg_idx[c == code], minlength=n)

    n_te, n_ca, n_toc, n_noise = (count(CLASS_GROUND), count(CLASS_CANOPY), count(CLASS_TOP),
                                  count(CLASS_NOISE))
    g = c == CLASS_GROUND
    te = percentiles_by_group(seg_idx[g], z[g], (0.0, 50.0, 100.0), n)
    te_mean, _ = _mean_std(seg_idx[g], z[g], n)
    can = (c == CLASS_CANOPY) | (c == CLASS_TOP)
    qs = (*CANOPY_METRIC_PERCENTILES, 50.0, 98.0, 100.0)
    rh = percentiles_by_group(seg_idx[can], hrel[can], qs, n)
    can_mean, can_std = _mean_std(seg_idx[can], hrel[can], n)
    s_start = origin + used * length
    mid = s_start + 0.5 * length
    best = classes.surface(mid)
    slope = (classes.surface(s_start + length) - classes.surface(s_start)) / length
    order = np.argsort(s[valid], kind="stable")
    sv = s[valid][order]
    x = np.interp(mid, sv, np.asarray(track.x, float)[valid][order])
    y = np.interp(mid, sv, np.asarray(track.y, float)[valid][order])
    t = np.interp(mid, sv, np.asarray(track.time, float)[valid][order])
    if n == 1:
        lon, lat = (a[:1] for a in from_metric(np.repeat(x, 2), np.repeat(y, 2), track.crs))
    else:
        lon, lat = from_metric(x, y, track.crs)
    has_can = (n_ca + n_toc) > 0
    flag = np.where(n_te == 0, "no_ground", np.where(~has_can, "no_canopy", "ok"))
    cols: dict[str, object] = {
        "track": np.full(n, track.track, dtype=object), "length": np.full(n, float(length)),
        "segment": used, "s_start": s_start, "s_end": s_start + length,
        "x": x, "y": y, "lon": lon, "lat": lat, "delta_time": t,
        "n_seg_ph": n_te + n_ca + n_toc, "n_te_photons": n_te, "n_ca_photons": n_ca,
        "n_toc_photons": n_toc, "n_noise": n_noise,
        "h_te_mean": te_mean, "h_te_median": te[:, 1], "h_te_min": te[:, 0],
        "h_te_max": te[:, 2], "h_te_best_fit": best, "terrain_slope": slope,
        "h_canopy": rh[:, -2], "h_mean_canopy": can_mean, "h_median_canopy": rh[:, -3],
        "h_max_canopy": rh[:, -1], "canopy_openness": can_std,
    }
    for j, q in enumerate(CANOPY_METRIC_PERCENTILES):
        cols[f"canopy_h_metrics_{q}"] = rh[:, j]
    cols["flag"] = flag.astype(object)
    df = pd.DataFrame({k: cols[k] for k in SEGMENT_COLUMNS})
    return gpd.GeoDataFrame(df, geometry=gpd.points_from_xy(x, y), crs=track.crs)
