"""Vertical datums: never mix ellipsoidal photon and orthometric lidar heights (DESIGN 2.6).

Photon heights (ATL03, MABEL) are ellipsoidal (WGS84, EPSG:4979); airborne lidar is
often orthometric (a geoid-based vertical CRS such as NAVD88, EPSG:5703, or CGVD2013).

:func:`check_vertical_datums` compares the vertical parts of the two CRSs:

* ``same``: both ellipsoidal heights, or the same vertical CRS -> nothing to do;
* ``differ``: known to differ -> a geoid raster or a constant offset is required,
  else :class:`DatumError`;
* ``unknown``: one side has no vertical information (e.g. a horizontal-only GeoTIFF
  CRS) -> :class:`CanopyBlocksWarning`, continue.

:func:`apply_vertical_offset` brings photon heights into the reference datum:
``H = h - N`` with ``N`` the geoid height (metres above the ellipsoid) sampled from a
geoid raster at the block centres, or a constant ``offset`` playing the role of ``N``
(so ``offset = h_photon - H_reference`` for the same point).  Only the absolute
heights (``top``, ``ground``, ``z90``) change; ``hmax``/``h90`` are differences.
"""

from __future__ import annotations

import logging
import os
import warnings
from typing import Literal

import numpy as np
import pandas as pd
import pyproj

from ..errors import (
    CanopyBlocksWarning,
    CoverageError,
    CRSError,
    DatumError,
    DependencyError,
    FileFormatError,
    InputError,
)
from ..geo import as_crs

__all__ = [
    "vertical_part",
    "check_vertical_datums",
    "apply_vertical_offset",
    "sample_geoid",
    "DatumDecision",
    "ABSOLUTE_HEIGHT_COLUMNS",
]

log = logging.getLogger(__name__)

DatumDecision = Literal["same", "differ", "unknown"]

#: Block columns holding absolute heights (shifted by a datum conversion).
ABSOLUTE_HEIGHT_COLUMNS: tuple[str, ...] = ("top", "ground", "z90")


def vertical_part(crs: object) -> str | pyproj.CRS | None:
    """The vertical component of ``crs``.

    Returns
    -------
    ``"ellipsoidal:<datum name>"`` for a geographic/projected 3-D CRS (ellipsoidal
    heights), the vertical :class:`pyproj.CRS` of a compound or vertical CRS, or
    None when ``crs`` is horizontal only (vertical datum unknown).
    """
    c = as_crs(crs, "CRS")
    if c.is_compound:
        for sub in c.sub_crs_list:
            if sub.is_vertical:
                return sub
            v = vertical_part(sub)
            if v is not None:
                return v
        return None
    if c.is_vertical:
        return c
    if len(c.axis_info) == 3:  # geographic 3D (EPSG:4979) or projected 3D: ellipsoidal heights
        base = c.geodetic_crs if c.geodetic_crs is not None else c
        return f"ellipsoidal:{base.datum.name if base.datum else '?'}"
    return None


def _describe(v: str | pyproj.CRS | None) -> str:
    if v is None:
        return "no vertical datum"
    if isinstance(v, str):
        return v.replace("ellipsoidal:", "ellipsoidal heights of ")
    return f"{v.name} ({v.to_string()})"


def check_vertical_datums(photon_datum: object, reference_crs: object, *,
                          geoid: str | os.PathLike[str] | None = None,
                          offset: float | None = None) -> DatumDecision:
    """Decide whether photon and reference heights may be compared.

    Parameters
    ----------
    photon_datum : CRS-like
        Vertical datum of the photon heights, e.g. ``"EPSG:4979"`` (WGS84 ellipsoid).
    reference_crs : CRS-like or None
        CRS of the reference rasters (compound, vertical or 3-D); None = unknown.
    geoid, offset
        The conversion the caller will apply (at most one).

    Returns
    -------
    "same", "differ" (a conversion was given) or "unknown" (warned).

    Raises
    ------
    DatumError
        The vertical parts are known to differ and neither ``geoid`` nor ``offset``
        was given.
    InputError
        Both ``geoid`` and ``offset`` given.
    """
    if geoid is not None and offset is not None:
        raise InputError("give either a geoid raster or a constant offset, not both")
    vp = vertical_part(photon_datum)
    vr = vertical_part(reference_crs) if reference_crs is not None else None
    if vp is None or vr is None:
        if geoid is None and offset is None:
            warnings.warn(
                f"vertical datum unknown (photons: {_describe(vp)}, reference: {_describe(vr)}); "
                "heights are compared as they are. Give the reference's vertical CRS "
                "(e.g. EPSG:32612+5703) or a geoid/offset to be sure",
                CanopyBlocksWarning, stacklevel=2,
            )
        return "unknown"
    if isinstance(vp, str) and isinstance(vr, str):
        same = True
        if vp != vr:
            log.info("both ellipsoidal but on different datums: %s vs %s (up to ~2 m apart)",
                     vp, vr)
    elif isinstance(vp, pyproj.CRS) and isinstance(vr, pyproj.CRS):
        same = vp == vr or vp.name == vr.name
    else:
        same = False
    if same:
        if geoid is not None or offset is not None:
            log.info("photon and reference heights share a datum, yet a conversion was given; "
                     "applying it as asked")
        return "same"
    if geoid is None and offset is None:
        raise DatumError(
            f"photon heights are {_describe(vp)} but the reference is {_describe(vr)}; they "
            "differ by tens of metres. Give a geoid raster (--geoid, geoid height N in metres "
            "above the ellipsoid) or a constant offset (--offset, h_photon - H_reference)"
        )
    return "differ"


def sample_geoid(geoid: str | os.PathLike[str], lon: np.ndarray, lat: np.ndarray
                 ) -> np.ndarray:
    """Geoid heights N (metres) from a raster at WGS84 ``lon``/``lat`` (nearest cell).

    Raises
    ------
    FileFormatError
        Missing or unreadable raster.
    CoverageError
        A point outside the raster or on nodata.
    """
    try:
        import rasterio
    except ImportError:
        raise DependencyError("geoid rasters need rasterio: pip install 'canopyblocks[raster]'") \
            from None
    if not os.path.exists(geoid):
        raise FileFormatError(f"geoid raster {geoid}: no such file")
    lon = np.asarray(lon, dtype=float)
    lat = np.asarray(lat, dtype=float)
    try:
        with rasterio.open(geoid) as src:
            if src.crs is None:
                raise CRSError(f"geoid raster {geoid} has no CRS; assign one (usually EPSG:4326)")
            rcrs = pyproj.CRS.from_user_input(src.crs.to_wkt())
            tr = pyproj.Transformer.from_crs("EPSG:4326", rcrs, always_xy=True)
            x, y = tr.transform(lon, lat)
            t = src.transform
            if t.b != 0 or t.d != 0:
                raise InputError(f"geoid raster {geoid} has a rotated grid; warp it north-up")
            col = np.floor((np.asarray(x) - t.c) / t.a).astype(np.int64)
            row = np.floor((np.asarray(y) - t.f) / t.e).astype(np.int64)
            ok = (col >= 0) & (col < src.width) & (row >= 0) & (row < src.height)
            if not ok.all():
                raise CoverageError(
                    f"geoid raster {geoid} does not cover {int((~ok).sum())} block centre(s); "
                    "use a geoid grid covering the track"
                )
            data = src.read(1, masked=True).astype(np.float64).filled(np.nan)
    except rasterio.errors.RasterioIOError as exc:
        raise FileFormatError(f"geoid raster {geoid}: cannot read ({exc})") from None
    n = data[row, col]
    if not np.isfinite(n).all():
        raise CoverageError(
            f"geoid raster {geoid} has nodata at {int((~np.isfinite(n)).sum())} block centre(s)"
        )
    return n


def apply_vertical_offset(blocks: pd.DataFrame, *, geoid: str | os.PathLike[str] | None = None,
                          offset: float | None = None,
                          columns: tuple[str, ...] = ABSOLUTE_HEIGHT_COLUMNS) -> pd.DataFrame:
    """Photon block heights converted to the reference datum: ``H = h - N``.

    Parameters
    ----------
    blocks : DataFrame
        Block table with ``lon``/``lat`` (degrees, for the geoid) and height columns.
    geoid : path, optional
        Geoid-height raster (N, metres above the ellipsoid), any CRS.
    offset : float, optional
        Constant N, metres (``h_photon - H_reference``).
    columns : tuple of str
        Absolute height columns to shift (default top, ground, z90).

    Returns
    -------
    A copy of ``blocks`` with shifted columns (unchanged copy if neither is given).
    """
    if geoid is not None and offset is not None:
        raise InputError("give either a geoid raster or a constant offset, not both")
    out = blocks.copy()
    n: float | np.ndarray  # metres, one constant or one value per block
    if offset is not None:
        n = float(offset)
        if not np.isfinite(n):
            raise InputError(f"vertical offset must be a finite number of metres, got {offset!r}")
    elif geoid is not None:
        ok = np.isfinite(out["lon"].to_numpy(float)) & np.isfinite(out["lat"].to_numpy(float))
        per_block = np.full(len(out), np.nan)
        if ok.any():
            per_block[ok] = sample_geoid(geoid, out["lon"].to_numpy(float)[ok],
                                         out["lat"].to_numpy(float)[ok])
        n = per_block
    else:
        return out
    for c in columns:
        if c in out.columns:
            out[c] = out[c].to_numpy(float) - n
    return out
