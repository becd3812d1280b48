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
    "require_ground_metres",
    "to_metric_local_affine",
    "ground_metres",
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
        from .arguments import describe
        msg = " ".join(str(exc).split())
        raise CRSError(f"{what} {describe(crs)} is not a CRS pyproj understands: {msg}") from None


def _median(a: np.ndarray) -> float:
    """``float(np.median(a))`` of a finite 1-D array, exactly, without sorting it all.

    A sample of ~16k values brackets the median; two counting passes check that both
    middle order statistics lie in the bracket, and only the values inside it are
    partitioned.  Falls back to ``np.median`` when the bracket misses.
    """
    n = a.size
    if n < 200_000:
        return float(np.median(a))
    sample = np.sort(a[:: max(1, n // 16_384)])
    m = sample.size
    half = int(4.0 * np.sqrt(m)) + 2  # ~8 standard deviations of the sample rank
    lo_v = sample[max(0, m // 2 - half)]
    hi_v = sample[min(m - 1, m // 2 + half)]
    k1, k2 = (n - 1) // 2, n // 2  # 0-based middle order statistics
    under = a < lo_v
    below = int(np.count_nonzero(under))
    inside = np.compress(np.logical_xor(a <= hi_v, under, out=under), a)  # lo_v <= a <= hi_v
    if not (below <= k1 and below + inside.size > k2):
        return float(np.median(a))
    part = np.partition(inside, (k1 - below, k2 - below))
    # as np.median: the mean of the two middle values (one value when n is odd)
    return float(np.mean(part[[k1 - below, k2 - below]])) if k1 != k2 else float(part[k1 - below])


def utm_crs_for(lon: float | np.ndarray, lat: float | np.ndarray) -> pyproj.CRS:
    """The default metric CRS of a track: the WGS84 UTM zone of its centre.

    Uses the median of finite ``lon``/``lat`` (degrees), so a few wild photons do not
    move the zone.  Beyond UTM's limits (north of 84 N, south of 80 S) the polar
    stereographic CRS of that pole is used (EPSG:3413, EPSG:3031).
    """
    from .arguments import check_array, check_lonlat
    check_lonlat(
        check_array(lon, "utm_crs_for: lon", what="degrees (a number or 1-D array)", scalar=True),
        check_array(lat, "utm_crs_for: lat", what="degrees (a number or 1-D array)", scalar=True),
        "utm_crs_for",
    )
    lon_a = np.asarray(lon, dtype=float)
    lat_a = np.asarray(lat, dtype=float)
    if lon_a.size and lon_a.shape == lat_a.shape:
        with np.errstate(invalid="ignore"):
            lims = (float(lon_a.min()), float(lon_a.max()), float(lat_a.min()),
                    float(lat_a.max()))
        if all(np.isfinite(lims)):
            epsg = _epsg_from_limits(*lims)
            if epsg is not None:
                return pyproj.CRS.from_epsg(epsg)
            return pyproj.CRS.from_epsg(_epsg_for(_median(lon_a.ravel()),
                                                  _median(lat_a.ravel())))
    ok = np.isfinite(lon_a) & np.isfinite(lat_a)
    if not ok.any():
        raise CRSError("cannot choose a UTM zone: no finite longitude/latitude")
    return pyproj.CRS.from_epsg(_epsg_for(float(np.median(lon_a[ok])),
                                          float(np.median(lat_a[ok]))))


def _epsg_from_limits(lon_min: float, lon_max: float, lat_min: float, lat_max: float
                      ) -> int | None:
    """The EPSG code of :func:`utm_crs_for` when the ranges of finite ``lon``/``lat``
    alone decide it, else None.  Every step of :func:`_epsg_for` is monotone in lon on
    [-180, 179] and in lat, so when both ends of the ranges give the same code, the
    median does too (no sorting needed)."""
    if not (-180.0 <= lon_min and lon_max <= 179.0):
        return None
    epsg = _epsg_for(lon_min, lat_min)
    return epsg if epsg == _epsg_for(lon_max, lat_max) else None


def _epsg_for(lon_c: float, lat_c: float) -> int:
    """EPSG code of :func:`utm_crs_for` for a centre ``lon_c``, ``lat_c`` (degrees)."""
    if lat_c > 84.0:
        return 3413  # NSIDC Sea Ice Polar Stereographic North
    if lat_c < -80.0:
        return 3031  # Antarctic Polar Stereographic
    lon_c = ((lon_c + 180.0) % 360.0) - 180.0
    zone = int(np.floor((lon_c + 180.0) / 6.0)) % 60 + 1
    return (32600 if lat_c >= 0 else 32700) + zone


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


def ground_metres(crs: object) -> bool:
    """Whether a CRS's metre is a metre on the ground (within a survey's extent): projected,
    in metres, and not a Mercator projection (Web Mercator, EPSG:3857 -- USGS 3DEP's EPT
    -- stretches lengths by 1/cos(latitude): 1.58 at 50.7 N).  A survey in such a CRS is
    read and reprojected to a local metric CRS (the UTM zone of the track), never used as
    metres."""
    try:
        c = as_crs(crs)
    except CRSError:
        return False
    if c.is_compound:
        c = next((s for s in c.sub_crs_list if s.is_projected or s.is_geographic), c)
    if not c.is_projected:
        return False
    unit = c.axis_info[0].unit_conversion_factor if c.axis_info else 1.0
    op = c.coordinate_operation
    method = (op.method_name if op is not None else "").lower()
    return abs(unit - 1.0) <= 1e-9 and not ("mercator" in method and "transverse" not in method)


def require_ground_metres(crs: object, what: str = "CRS") -> pyproj.CRS:
    """:func:`require_metric_crs`, and refuse a Mercator projection (Web Mercator, EPSG:3857),
    whose metre is not a metre on the ground (:func:`ground_metres`); for a CRS the user asks
    the outputs in.

    Raises
    ------
    CRSError
        Naming the CRS and what to give instead.
    """
    c = require_metric_crs(as_crs(crs, what), what)
    if not ground_metres(c):
        raise CRSError(
            f"{what} {c.to_string()} is a Mercator projection: its metre is 1/cos(latitude) "
            "metres on the ground (1.58 at 50.7 N), so cells and corridors would not have the "
            "sizes asked; give a local metric CRS (e.g. the UTM zone of the survey) or leave "
            "it out")
    return c


def require_metre_units(crs: object, what: str) -> None:
    """Refuse a CRS with any axis (horizontal or vertical) in feet or other non-metre units.

    One unit rule for every command: heights and positions are metres.  Degrees of a
    geographic CRS pass (they are handled where positions are projected).

    Parameters
    ----------
    crs : CRS-like
        Possibly compound.
    what : str
        Names the data (e.g. ``"tile a.laz"``, ``"DTM dtm.tif"``) in the message.

    Raises
    ------
    CRSError
        An axis in feet (or another non-metre length unit), with what to do.
    """
    c = as_crs(crs, what)
    subs = c.sub_crs_list if c.is_compound and c.sub_crs_list else [c]
    for sub in subs:
        for axis in sub.axis_info:
            if abs(axis.unit_conversion_factor - 1.0) > 1e-9 and "degree" not in \
                    axis.unit_name and axis.unit_name != "radian":
                raise CRSError(
                    f"{what} is in {axis.unit_name!r} ({sub.name}); positions and heights in "
                    "feet are not supported: convert it to metres (x, y and z) first, e.g. "
                    "with PDAL filters.reprojection plus a Z scale of 0.3048006, or "
                    "gdal_calc.py for a raster")


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


# --------------------------------------------------------------------------- fast path
_AFFINE_STEP_DEG = 1e-6  # forward-difference step of the local Jacobian (~0.1 m)
_HESS_STEP_DEG = 1e-3  # step of the second-derivative estimate at the knots (~100 m)
_KNOT_EVERY = 16  # blocks between second-derivative knots
_AFFINE_MAX_SPAN_DEG = 0.01  # a block reaching farther from its reference is projected exactly
_CHUNK = 1 << 16  # photons per cache-sized chunk of the per-photon arithmetic


def _block_size(lon: np.ndarray, lat: np.ndarray, target_m: float = 64.0) -> int:
    """Photons per affine block: a power of two spanning about ``target_m`` metres.

    The density is estimated from ~1000 evenly spaced photons (equirectangular
    distances); NaNs or a degenerate track give a block of 64.
    """
    n = lon.size
    step = max(1, n // 1024)
    lo, la = lon[::step], lat[::step]
    dx = np.diff(lo) * np.cos(np.radians(np.clip(la[1:], -89.9, 89.9)))
    dy = np.diff(la)
    with np.errstate(invalid="ignore"):
        length_m = float(np.nansum(np.hypot(dx, dy))) * 111_195.0
    if not np.isfinite(length_m) or length_m <= 0.0:
        return 64
    per_m = n / length_m
    b = 1 << max(0, int(np.floor(np.log2(max(per_m * target_m, 1.0)))))
    return int(min(max(b, 16), 1024))


def to_metric_local_affine(
    lon: np.ndarray,
    lat: np.ndarray,
    crs: pyproj.CRS | None = None,
    *,
    tol_m: float = 1e-4,
    min_photons: int = 65_536,
    block: int | None = None,
    _knot_every: int = _KNOT_EVERY,
) -> tuple[np.ndarray, np.ndarray, pyproj.CRS]:
    """Fast :func:`to_metric` for photons ordered along a track, exact to ``tol_m`` metres.

    The photons are cut into blocks of ``block`` consecutive points (default: a power
    of two spanning ~64 m of track, 16..1024 photons).  Each block's middle point is
    projected with pyproj, plus two points 1e-6 degrees east and north of it (a
    forward-difference Jacobian); every photon of the block is then mapped with that
    local affine map in numpy.  The neglected second-order term is bounded per block
    from the block's extent in degrees around its middle point and the projection's
    second derivatives (finite differences with pyproj at every 16th block, the larger
    of the two enclosing estimates, times a safety factor of 2).  Blocks whose bound
    exceeds ``tol_m`` (sparse or scattered photons, tracks heading east near the poles)
    are redone with blocks 4 times shorter (second derivatives then at every block),
    down to 16 photons, and then projected exactly with pyproj; so are blocks with
    NaN/inf coordinates or points outside the CRS's domain (the antimeridian makes a
    block's extent huge), and the last partial block.  The result therefore differs
    from :func:`to_metric` by less than ``tol_m`` everywhere and is identical where
    pyproj gives non-finite values.

    Parameters
    ----------
    lon, lat : ndarray
        WGS84 degrees, in track order (consecutive photons close to each other).
    crs : pyproj.CRS, optional
        Metric target CRS; default the UTM zone of the centre (as :func:`to_metric`).
    tol_m : float
        Largest allowed difference from the full pyproj projection, metres.
    min_photons : int
        Fewer photons than this are projected exactly with pyproj (no gain below).
    block : int, optional
        Photons per affine block (for tests); default chosen from the density.

    Returns
    -------
    x, y : ndarray of float64, metres
    crs : pyproj.CRS actually used
    """
    lon = np.ascontiguousarray(lon, dtype=np.float64)
    lat = np.ascontiguousarray(lat, dtype=np.float64)
    n = lon.size
    ok_shape = lon.shape == lat.shape and lon.ndim == 1
    b = int(block) if block is not None else (
        _block_size(lon, lat) if ok_shape and n >= 2 else 1)
    m = n // b if b >= 2 else 0
    if n < max(min_photons, 2) or m < 2 or not ok_shape:
        crs = utm_crs_for(lon, lat) if crs is None else require_metric_crs(crs)
        x, y = _transform(_transformer(WGS84, crs), lon, lat)
        return x, y, crs
    nb = m * b
    lon2, lat2 = lon[:nb].reshape(m, b), lat[:nb].reshape(m, b)
    lon0 = lon2[:, b // 2].copy()
    lat0 = lat2[:, b // 2].copy()
    # the default CRS is decided from the photons' ranges after the pass below (the
    # median only when the ranges do not decide it); guess it from the blocks' middles
    guess = crs is None
    crs = utm_crs_for(lon0, lat0) if crs is None else require_metric_crs(crs)
    rows = max(1, _CHUNK // b)
    tr = _transformer(WGS84, crs)
    # reference points, the Jacobian's forward points, and the knots' second differences
    kn = np.unique(np.r_[np.arange(0, m, max(1, _knot_every)), m - 1])
    hs, hh = _AFFINE_STEP_DEG, _HESS_STEP_DEG
    k_lon, k_lat = lon0[kn], lat0[kn]
    qlon = np.concatenate([lon0, lon0 + hs, lon0, k_lon - hh, k_lon + hh, k_lon, k_lon,
                           k_lon + hh])
    qlat = np.concatenate([lat0, lat0, lat0 + hs, k_lat, k_lat, k_lat - hh, k_lat + hh,
                           k_lat + hh])
    with np.errstate(invalid="ignore", over="ignore"):
        qx, qy = _transform(tr, qlon, qlat)
        x0, x1, x2 = qx[:m], qx[m:2 * m], qx[2 * m:3 * m]
        y0, y1, y2 = qy[:m], qy[m:2 * m], qy[2 * m:3 * m]
        jxl, jxp = (x1 - x0) / hs, (x2 - x0) / hs
        jyl, jyp = (y1 - y0) / hs, (y2 - y0) / hs
        k = kn.size
        kx = [qx[3 * m + i * k: 3 * m + (i + 1) * k] for i in range(5)]
        ky = [qy[3 * m + i * k: 3 * m + (i + 1) * k] for i in range(5)]
        h_ll = h_pp = h_lp = np.zeros(k)
        for q, q0 in ((kx, x0[kn]), (ky, y0[kn])):
            h_ll = h_ll + np.abs(q[0] - 2 * q0 + q[1]) / hh**2
            h_pp = h_pp + np.abs(q[2] - 2 * q0 + q[3]) / hh**2
            h_lp = h_lp + np.abs(q[4] - q[1] - q[3] + q0) / hh**2
        # each block takes the larger estimate of its two enclosing knots
        pos = np.clip(np.searchsorted(kn, np.arange(m), side="right") - 1, 0, k - 1)
        nxt = np.minimum(pos + 1, k - 1)
        c_ll = np.maximum(h_ll[pos], h_ll[nxt])
        c_pp = np.maximum(h_pp[pos], h_pp[nxt])
        c_lp = np.maximum(h_lp[pos], h_lp[nxt])
        # x = x0 + jxl (lon - lon0) + jxp (lat - lat0) = ax + jxl lon + jxp lat per block
        ax = x0 - jxl * lon0 - jxp * lat0
        ay = y0 - jyl * lon0 - jyp * lat0
    x = np.empty(n)
    y = np.empty(n)
    xv, yv = x[:nb].reshape(m, b), y[:nb].reshape(m, b)
    lon_hi, lon_lo, lat_hi, lat_lo = (np.empty(m) for _ in range(4))
    tmp = np.empty((rows, b))
    with np.errstate(invalid="ignore", over="ignore"):
        for r0 in range(0, m, rows):  # cache-sized chunks: each column read once
            r1 = min(m, r0 + rows)
            lc, pc, xd, yd, c = lon2[r0:r1], lat2[r0:r1], xv[r0:r1], yv[r0:r1], tmp[: r1 - r0]
            lc.max(axis=1, out=lon_hi[r0:r1])  # the block's extent (NaN if it holds a NaN)
            lc.min(axis=1, out=lon_lo[r0:r1])
            pc.max(axis=1, out=lat_hi[r0:r1])
            pc.min(axis=1, out=lat_lo[r0:r1])
            np.multiply(lc, jxl[r0:r1, None], out=xd)
            np.multiply(pc, jxp[r0:r1, None], out=c)
            xd += c
            xd += ax[r0:r1, None]
            np.multiply(lc, jyl[r0:r1, None], out=yd)
            np.multiply(pc, jyp[r0:r1, None], out=c)
            yd += c
            yd += ay[r0:r1, None]
        dl = np.maximum(lon_hi - lon0, lon0 - lon_lo)  # NaN when the block holds a NaN
        dp = np.maximum(lat_hi - lat0, lat0 - lat_lo)
        bound = c_ll * dl * dl + 2.0 * c_lp * dl * dp + c_pp * dp * dp  # 2 x (1/2 H d d)
        good = (bound <= tol_m) & (dl <= _AFFINE_MAX_SPAN_DEG) & (dp <= _AFFINE_MAX_SPAN_DEG) \
            & np.isfinite(ax) & np.isfinite(ay) & np.isfinite(jxl) & np.isfinite(jxp) \
            & np.isfinite(jyl) & np.isfinite(jyp)
    if guess:
        with np.errstate(invalid="ignore"):
            lims = (float(np.minimum(lon_lo.min(), lon[nb:].min(initial=np.inf))),
                    float(np.maximum(lon_hi.max(), lon[nb:].max(initial=-np.inf))),
                    float(np.minimum(lat_lo.min(), lat[nb:].min(initial=np.inf))),
                    float(np.maximum(lat_hi.max(), lat[nb:].max(initial=-np.inf))))
        epsg = _epsg_from_limits(*lims) if all(np.isfinite(lims)) else None
        right = pyproj.CRS.from_epsg(epsg) if epsg is not None else utm_crs_for(lon, lat)
        if right != crs:  # the middles' zone was not the photons' zone: once more
            del x, y, xv, yv
            return to_metric_local_affine(lon, lat, right, tol_m=tol_m,
                                          min_photons=min_photons, block=b,
                                          _knot_every=_knot_every)
    bad = np.flatnonzero(~good)
    if bad.size:  # again with blocks 4 times shorter, then exactly with pyproj
        sel = (bad[:, None] * b + np.arange(b)).ravel()
        if b >= 32:
            x[sel], y[sel], _ = to_metric_local_affine(
                lon[sel], lat[sel], crs, tol_m=tol_m, min_photons=0, block=b // 4,
                _knot_every=1)
        else:
            x[sel], y[sel] = _transform(tr, lon[sel], lat[sel])
    if nb < n:
        x[nb:], y[nb:] = _transform(tr, lon[nb:], lat[nb:])
    return x, y, crs
