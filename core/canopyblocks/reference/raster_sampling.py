"""A raster held in memory and sampled at many points at once (bilinear, vectorised).

Used where the same raster is looked up again and again at shifted positions (the
co-registration search), so it is read once and every lookup is a numpy gather.
Nodata: the file's own nodata value, and also -9999 and float32 max (3.4028235e38),
which surveys often leave undeclared (DESIGN 2.9); such cells become NaN.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np
import pyproj

from ..errors import CRSError, DependencyError, FileFormatError, InputError
from ..geo import require_metre_units

__all__ = ["RasterSurface", "read_surface", "clean_heights", "UNDECLARED_NODATA"]

log = logging.getLogger(__name__)

#: Values treated as nodata even when a raster does not declare them.
UNDECLARED_NODATA: tuple[float, ...] = (-9999.0, float(np.finfo(np.float32).max))


def clean_heights(values: np.ndarray, what: str = "raster") -> np.ndarray:
    """``values`` (float64, modified in place) with undeclared nodata and non-finite as NaN.

    Surveys often leave -9999 or float32 max (3.4028235e38) undeclared (DESIGN 2.9);
    used wherever raster cells are read as heights.
    """
    for nd in UNDECLARED_NODATA:
        hit = values == nd
        if hit.any():
            log.info("%s: %d cells hold %g, treated as nodata", what, int(hit.sum()), nd)
            values[hit] = np.nan
    values[~np.isfinite(values)] = np.nan
    return values


@dataclass(frozen=True)
class RasterSurface:
    """One raster band in memory, north-up.

    Attributes
    ----------
    values : ndarray float64, shape (rows, cols)
        Cell values (m), NaN where nodata.
    x0, y0 : float
        Map coordinates (m) of the upper-left corner of cell (0, 0).
    dx, dy : float
        Cell width and height (m, both positive).
    crs : pyproj.CRS
        The raster's CRS (may be compound; ``horizontal_crs`` is its horizontal part).
    path : str
        The file it came from ("" when built from an array).
    """

    values: np.ndarray
    x0: float
    y0: float
    dx: float
    dy: float
    crs: pyproj.CRS
    path: str = ""

    def __post_init__(self) -> None:
        if self.values.ndim != 2 or min(self.values.shape) < 1:
            raise InputError(f"raster {self.path or '(array)'}: need a 2-D band, got shape "
                             f"{self.values.shape}")
        if not (self.dx > 0 and self.dy > 0):
            raise InputError(f"raster {self.path or '(array)'}: cell size must be positive, "
                             f"got {self.dx} x {self.dy}")

    @property
    def horizontal_crs(self) -> pyproj.CRS:
        """The horizontal part of :attr:`crs`."""
        if self.crs.is_compound:
            return self.crs.sub_crs_list[0]
        return self.crs

    def bilinear(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Values at map positions ``x``, ``y`` (m, same CRS), bilinear between cell centres.

        NaN outside the raster, and wherever one of the four surrounding cells is nodata.
        Any shape of ``x``/``y`` (broadcast together); the result has that shape.
        """
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64),
                                   np.asarray(y, dtype=np.float64))
        rows, cols = self.values.shape
        # fractional cell coordinates of the position, measured between cell centres
        c = (x - self.x0) / self.dx - 0.5
        r = (self.y0 - y) / self.dy - 0.5
        with np.errstate(invalid="ignore"):
            c0 = np.floor(c)
            r0 = np.floor(r)
            inside = (c0 >= 0) & (c0 < cols - 1) & (r0 >= 0) & (r0 < rows - 1)
        ci = np.where(inside, c0, 0).astype(np.intp)
        ri = np.where(inside, r0, 0).astype(np.intp)
        fc = np.where(inside, c - c0, 0.0)
        fr = np.where(inside, r - r0, 0.0)
        v = self.values
        top = v[ri, ci] * (1 - fc) + v[ri, ci + 1] * fc
        bottom = v[ri + 1, ci] * (1 - fc) + v[ri + 1, ci + 1] * fc
        out = top * (1 - fr) + bottom * fr
        return np.where(inside, out, np.nan)

    def slope_degrees(self) -> float:
        """Median terrain slope of the raster (degrees), from central differences."""
        gy, gx = np.gradient(self.values, self.dy, self.dx)
        s = np.degrees(np.arctan(np.hypot(gx, gy)))
        s = s[np.isfinite(s)]
        return float(np.median(s)) if s.size else float("nan")


def read_surface(path: str | os.PathLike[str], *, what: str = "raster") -> RasterSurface:
    """Read band 1 of a north-up GeoTIFF (or any GDAL raster) into a :class:`RasterSurface`.

    Raises
    ------
    DependencyError
        rasterio is not installed.
    FileFormatError
        Missing or unreadable file.
    CRSError
        The raster carries no CRS.
    InputError
        A rotated grid, or a band with no valid cell.
    """
    try:
        import rasterio
    except ImportError:
        raise DependencyError("reading rasters needs rasterio: pip install "
                              "'canopyblocks[raster]'") from None
    p = str(path)
    if not os.path.exists(p):
        raise FileFormatError(f"{what} {p}: no such file")
    try:
        with rasterio.open(p) as src:
            if src.crs is None:
                raise CRSError(f"{what} {p} has no CRS; assign one (e.g. gdal_edit.py "
                               "-a_srs EPSG:...)")
            t = src.transform
            if t.b != 0 or t.d != 0 or t.e >= 0:
                raise InputError(f"{what} {p} is not a north-up grid; warp it north-up first")
            band = src.read(1, masked=True)
            crs = pyproj.CRS.from_user_input(src.crs.to_wkt())
    except rasterio.errors.RasterioIOError as exc:
        raise FileFormatError(f"{what} {p}: cannot read ({exc})") from None
    require_metre_units(crs, f"{what} {p}")
    values = clean_heights(np.ma.filled(band.astype(np.float64), np.nan), f"{what} {p}")
    if not np.isfinite(values).any():
        raise InputError(f"{what} {p} holds no valid cell (all nodata)")
    return RasterSurface(values, float(t.c), float(t.f), float(t.a), float(-t.e), crs, p)
