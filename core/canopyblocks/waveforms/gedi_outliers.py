"""Terrain outliers among GEDI footprints: criteria that fit GEDI's 25 m shots 60 m apart.

The seed-003 filter (:mod:`.terrain_filter`) was made for a 5 m flash-lidar grid: a 60 m
canopy ceiling and a ground more than 10 m below the median of five neighbours on each
side.  Applied to GEDI it flags valid shots: redwoods reach 115 m and tropical forests
exceed 60 m (GEDI exists for them), and on a steep slope neighbours 60 m apart differ by
tens of metres.  For GEDI a shot is a terrain outlier when

* its canopy is taller than ``max_height`` (130 m: taller than any tree measured);
* its ground lies below what its neighbours say by more than the terrain allows: the
  prediction is the median of the neighbours' grounds carried to the shot along the
  neighbours' own along-track trend (Theil-Sen slope), and the tolerance is
  ``max_below`` + 3 robust sd of the neighbours about that trend + the local steepness
  (median gradient between consecutive neighbours) times the distance to the nearest
  neighbour plus half a footprint -- so the rule scales with footprint spacing and slope;
  neighbours farther than ``max_gap`` along the track do not count;
* when a DEM elevation per shot is given (e.g. L1B/L2A ``digital_elevation_model``), its
  ground is more than ``dem_limit`` from it, as L2A's quality logic compares the lowest
  mode with a DEM.

Energy and sensitivity are judged before this: a shot whose waveform does not rise above
the L2A thresholds is ``no_signal``.  Footprints without a ground (NaN) are never
outliers and never anyone's neighbour.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..schema import MAX_CANOPY_HEIGHT_M

__all__ = ["gedi_outliers"]
_EARTH_M = 6_371_008.8


def _along(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Cumulative distance (m) between consecutive positions (local equirectangular)."""
    lat0 = np.radians(np.nanmedian(lat))
    dx = np.diff(np.radians(lon)) * np.cos(lat0) * _EARTH_M
    dy = np.diff(np.radians(lat)) * _EARTH_M
    return np.concatenate([[0.0], np.cumsum(np.hypot(dx, dy))])


def gedi_outliers(ground: npt.ArrayLike, height: npt.ArrayLike, lon: npt.ArrayLike,
                  lat: npt.ArrayLike, *, dem: npt.ArrayLike | None = None,
                  neighbours: int = 5, max_below: float = 10.0,
                  max_height: float = MAX_CANOPY_HEIGHT_M, max_gap: float = 600.0,
                  diameter: float = 25.0, dem_limit: float = 100.0
                  ) -> npt.NDArray[np.bool_]:
    """Flag terrain outliers along one GEDI beam.

    Parameters
    ----------
    ground : array-like, shape (n,)
        Ground elevation (m), in along-track (time) order; NaN where unknown.
    height : array-like, shape (n,)
        Canopy height above the ground (m); NaN where unknown.
    lon, lat : array-like, shape (n,)
        Footprint position (degrees WGS84).
    dem : array-like, shape (n,), optional
        A DEM's elevation at each footprint (m, the ground's vertical datum); NaN where none.
    neighbours : int
        Footprints on each side that judge a shot (5).
    max_below : float
        Metres below the neighbours' prediction always allowed (10).
    max_height : float
        Canopy heights above this are outliers (130 m).
    max_gap : float
        Neighbours farther than this along the track (m) do not count (600).
    diameter : float
        Footprint diameter (m; GEDI about 25).
    dem_limit : float
        Metres from the DEM beyond which the ground is an outlier (100).

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    z = np.asarray(ground, dtype=np.float64)
    h = np.asarray(height, dtype=np.float64)
    lo = np.asarray(lon, dtype=np.float64)
    la = np.asarray(lat, dtype=np.float64)
    if z.ndim != 1 or not (h.shape == lo.shape == la.shape == z.shape):
        raise InputError(f"ground, height, lon and lat must be 1-D arrays of the same length; "
                         f"got shapes {z.shape}, {h.shape}, {lo.shape}, {la.shape}")
    if isinstance(neighbours, bool) or not isinstance(neighbours, (int, np.integer)) \
            or neighbours < 1:
        raise InputError(f"neighbours must be an integer >= 1; got {neighbours!r}")
    for name, v in (("max_below", max_below), ("max_height", max_height),
                    ("max_gap", max_gap), ("diameter", diameter), ("dem_limit", dem_limit)):
        if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number of metres; got {v!r}")
    out = np.zeros(z.shape, dtype=bool)
    valid = np.isfinite(z) & np.isfinite(lo) & np.isfinite(la)
    idx = np.flatnonzero(valid)
    if idx.size >= 3:
        zv, sv = z[idx], _along(lo[idx], la[idx])
        w = int(neighbours)
        pad = np.full(w, np.nan)
        zw = np.lib.stride_tricks.sliding_window_view(np.concatenate([pad, zv, pad]), 2 * w + 1)
        sw = np.lib.stride_tricks.sliding_window_view(np.concatenate([pad, sv, pad]), 2 * w + 1)
        ds = sw - sv[:, None]
        nb = np.isfinite(zw) & (np.abs(ds) <= max_gap)
        nb[:, w] = False  # the shot itself is no neighbour
        zn = np.where(nb, zw, np.nan)
        # Theil-Sen slope of the neighbours (pairs of window positions)
        a, b = np.triu_indices(2 * w + 1, 1)
        keep = (a != w) & (b != w)
        a, b = a[keep], b[keep]
        with np.errstate(invalid="ignore", divide="ignore"):
            dsp = ds[:, b] - ds[:, a]
            pair = (zn[:, b] - zn[:, a]) / np.where(np.abs(dsp) > 1.0, dsp, np.nan)
            # consecutive neighbours (adjacent window positions, skipping the shot)
            adj = (b == a + 1) | ((a == w - 1) & (b == w + 1))
            grad = np.abs(pair[:, adj])
        has = nb.sum(axis=1) >= 2
        slope = np.zeros(idx.size)
        steep = np.zeros(idx.size)
        fin = has & np.isfinite(pair).any(axis=1)
        slope[fin] = row_nanmedian(pair[fin])
        fin_g = has & np.isfinite(grad).any(axis=1)
        steep[fin_g] = row_nanmedian(grad[fin_g])
        pred_j = zn - slope[:, None] * ds  # each neighbour carried to the shot
        pred = np.full(idx.size, np.nan)
        pred[has] = row_nanmedian(pred_j[has])
        spread = np.zeros(idx.size)
        spread[has] = 1.4826 * row_nanmedian(np.abs(pred_j[has] - pred[has, None]))
        near = np.full(idx.size, np.inf)
        near[has] = np.nanmin(np.where(nb, np.abs(ds), np.nan)[has], axis=1)
        tol = max_below + 3.0 * spread + steep * (near + 0.5 * diameter)
        low = np.zeros(idx.size, dtype=bool)
        low[has] = zv[has] < pred[has] - tol[has]
        out[idx] = low
    with np.errstate(invalid="ignore"):
        out |= valid & np.isfinite(h) & (h > max_height)
        if dem is not None:
            d = np.asarray(dem, dtype=np.float64)
            if d.shape != z.shape:
                raise InputError(f"dem must hold one elevation per shot {z.shape}; got "
                                 f"shape {d.shape}")
            out |= valid & np.isfinite(d) & (np.abs(z - d) > dem_limit)
    return out


def row_nanmedian(x: np.ndarray) -> np.ndarray:
    """``np.nanmedian(x, axis=1)`` (the same bits) for rows of a few dozen values, each with
    at least one number. numpy takes its masked-array path for rows under 600 values (most
    of the time of this module); this is that path's arithmetic without the masked arrays:
    each row sorted as ``argsort`` sorts it (NaN last), the mean of its two middle numbers
    as ``(0 + low + high) / 2`` (an odd count: the middle one twice)."""
    x = np.asarray(x, float)
    xs = np.take_along_axis(x, x.argsort(axis=1), axis=1)
    c = np.count_nonzero(~np.isnan(x), axis=1)
    hi = c // 2
    lo = np.where(c % 2 == 1, hi, hi - 1)
    s = 0.0 + np.take_along_axis(xs, lo[:, None], 1)[:, 0]  # (numpy's sum: -0 + -0 is 0)
    s += np.take_along_axis(xs, hi[:, None], 1)[:, 0]
    return s / 2.0
