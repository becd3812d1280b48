"""Coordinate reference systems and projections used along a track.

All metric work happens in a projected CRS whose units are metres; by default the
UTM zone (WGS84) of the track centre.
"""

from __future__ import annotations

import numpy as np
import pyproj
from pyproj.exceptions import CRSError as _PyprojCRSError

from .errors import CRSError

__all__ = [
    "WGS84",
    "WGS84_3D",
    "as_crs",
    "utm_crs_for",
    "to_metric",
    "from_metric",
    "require_metric_crs",
]

WGS84 = pyproj.CRS.from_epsg(4326)
WGS84_3D = pyproj.CRS.from_epsg(4979)  # WGS84 with ellipsoidal heights (ATL03, MABEL)


def as_crs(crs: object, what: str = "CRS") -> pyproj.CRS:
    """Parse anything pyproj understands (EPSG code, ``"EPSG:32612"``, WKT, CRS).

    Raises
    ------
    CRSError
        When ``crs`` is None or not understood; the message names ``what``.
    """
    if crs is None:
        raise CRSError(f"{what} is missing: give an EPSG code such as EPSG:32612")
    if isinstance(crs, pyproj.CRS):
        return crs
    try:
        if isinstance(crs, (int, np.integer)):
            return pyproj.CRS.from_epsg(int(crs))
        return pyproj.CRS.from_user_input(crs)
    except (_PyprojCRSError, TypeError, ValueError) as exc:
        raise CRSError(f"{what} {crs!r} is not a CRS pyproj understands: {exc}") from None


def utm_crs_for(lon: float | np.ndarray, lat: float | np.ndarray) -> pyproj.CRS:
    """The default metric CRS of a track: the WGS84 UTM zone of its centre.

    Uses the median of finite ``lon``/``lat`` (degrees), so a few wild photons do not
    move the zone.  Beyond UTM's limits (north of 84 N, south of 80 S) the polar
    stereographic CRS of that pole is used (EPSG:3413, EPSG:3031).
    """
    lon_a = np.asarray(lon, dtype=float)
    lat_a = np.asarray(lat, dtype=float)
    ok = np.isfinite(lon_a) & np.isfinite(lat_a)
    if not ok.any():
        raise CRSError("cannot choose a UTM zone: no finite longitude/latitude")
    lon_c = float(np.median(lon_a[ok]))
    lat_c = float(np.median(lat_a[ok]))
    if lat_c > 84.0:
        return pyproj.CRS.from_epsg(3413)  # NSIDC Sea Ice Polar Stereographic North
    if lat_c < -80.0:
        return pyproj.CRS.from_epsg(3031)  # Antarctic Polar Stereographic
    lon_c = ((lon_c + 180.0) % 360.0) - 180.0
    zone = int(np.floor((lon_c + 180.0) / 6.0)) % 60 + 1
    epsg = (32600 if lat_c >= 0 else 32700) + zone
    return pyproj.CRS.from_epsg(epsg)


def require_metric_crs(crs: pyproj.CRS, what: str = "CRS") -> pyproj.CRS:
    """Check that ``crs`` is projected with metre units; return it.

    Raises
    ------
    CRSError
        For a geographic CRS or one in feet, with what to do instead.
    """
    crs = as_crs(crs, what)
    if not crs.is_projected:
        raise CRSError(
            f"{what} {crs.to_string()} is not projected; use a metric projected CRS "
            "(e.g. the UTM zone of the track)"
        )
    unit = crs.axis_info[0].unit_name if crs.axis_info else ""
    factor = crs.axis_info[0].unit_conversion_factor if crs.axis_info else 1.0
    if abs(factor - 1.0) > 1e-9:
        raise CRSError(
            f"{what} {crs.to_string()} has horizontal units of {unit!r}, not metres; "
            "reproject the data to a metric CRS first"
        )
    return crs


def _transformer(src: pyproj.CRS, dst: pyproj.CRS) -> pyproj.Transformer:
    return pyproj.Transformer.from_crs(src, dst, always_xy=True)


def _transform(tr: pyproj.Transformer, a: np.ndarray, b: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised transform of float64 arrays of any size (pyproj treats size-1 arrays as
    scalars and numpy >= 1.25 deprecates that conversion, so those go through 2 copies)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.size == 1:
        oa, ob = tr.transform(np.repeat(a.ravel(), 2), np.repeat(b.ravel(), 2))
        return np.asarray(oa[:1], np.float64).reshape(a.shape), \
            np.asarray(ob[:1], np.float64).reshape(b.shape)
    oa, ob = tr.transform(a, b)
    return np.asarray(oa, dtype=np.float64), np.asarray(ob, dtype=np.float64)


def to_metric(
    lon: np.ndarray, lat: np.ndarray, crs: pyproj.CRS | None = None
) -> tuple[np.ndarray, np.ndarray, pyproj.CRS]:
    """Project WGS84 ``lon``/``lat`` (degrees) to ``crs`` (default: UTM of the centre).

    Returns
    -------
    x, y : ndarray of float64, metres
    crs : pyproj.CRS actually used
    """
    crs = utm_crs_for(lon, lat) if crs is None else require_metric_crs(crs)
    x, y = _transform(_transformer(WGS84, crs), lon, lat)
    return x, y, crs


def from_metric(
    x: np.ndarray, y: np.ndarray, crs: pyproj.CRS
) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`to_metric`: ``x``/``y`` in ``crs`` to WGS84 lon, lat (degrees)."""
    return _transform(_transformer(as_crs(crs), WGS84), x, y)
