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

__all__ = ["RasterSurface", "TiledValues", "read_surface", "clean_heights",
           "UNDECLARED_NODATA"]

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


_DENSE_CELLS = 16_000_000  # a larger tiled raster is held by its tiles that hold values


@dataclass(frozen=True)
class TiledValues:
    """A large raster band held only in its tiles that hold a value (a corridor's sparse
    rasters): ``blocks[index[r // bh, c // bw], r % bh, c % bw]``, NaN where ``index`` is
    -1."""

    blocks: np.ndarray
    index: np.ndarray
    shape: tuple[int, int]

    @property
    def ndim(self) -> int:
        """Always 2, like the dense band it stands for."""
        return 2

    def take(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Values at integer cell positions (inside the band)."""
        bh, bw = self.blocks.shape[1:]
        k = self.index[rows // bh, cols // bw]
        return np.where(k >= 0, self.blocks[np.maximum(k, 0), rows % bh, cols % bw], np.nan)


@dataclass(frozen=True)
class RasterSurface:
    """One raster band in memory, north-up.

    Attributes
    ----------
    values : ndarray float64, shape (rows, cols), or TiledValues
        Cell values (m), NaN where nodata (a large tiled raster: its tiles with values).
    x0, y0 : float
        Map coordinates (m) of the upper-left corner of cell (0, 0).
    dx, dy : float
        Cell width and height (m, both positive).
    crs : pyproj.CRS
        The raster's CRS (may be compound; ``horizontal_crs`` is its horizontal part).
    path : str
        The file it came from ("" when built from an array).
    """

    values: np.ndarray | TiledValues
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
        take = v.take if isinstance(v, TiledValues) else (lambda r, c: v[r, c])
        top = take(ri, ci) * (1 - fc) + take(ri, ci + 1) * fc
        bottom = take(ri + 1, ci) * (1 - fc) + take(ri + 1, ci + 1) * fc
        out = top * (1 - fr) + bottom * fr
        return np.where(inside, out, np.nan)

    def slope_degrees(self) -> float:
        """Median terrain slope of the raster (degrees), from central differences."""
        v = self.values
        parts = list(v.blocks) if isinstance(v, TiledValues) else [v]  # tiles: within each
        s = np.concatenate([np.degrees(np.arctan(np.hypot(*np.gradient(b, self.dy, self.dx))))
                            .ravel() for b in parts if min(b.shape) > 1] or [np.empty(0)])
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
            crs = pyproj.CRS.from_user_input(src.crs.to_wkt())
            values: np.ndarray | TiledValues = (_read_tiles(src, f"{what} {p}")
                                                if _tiled_and_large(src) else
                                                _read_dense(src, f"{what} {p}"))
    except rasterio.errors.RasterioIOError as exc:
        raise FileFormatError(f"{what} {p}: cannot read ({exc})") from None
    require_metre_units(crs, f"{what} {p}")
    valid = (values.blocks.size > 0 and bool(np.isfinite(values.blocks).any())
             if isinstance(values, TiledValues) else bool(np.isfinite(values).any()))
    if not valid:
        raise InputError(f"{what} {p} holds no valid cell (all nodata)")
    return RasterSurface(values, float(t.c), float(t.f), float(t.a), float(-t.e), crs, p)


def _tiled_and_large(src: object) -> bool:
    h, w = src.height, src.width  # type: ignore[attr-defined]
    return bool(h * w > _DENSE_CELLS and src.profile.get("tiled"))  # type: ignore[attr-defined]


def _read_dense(src: object, what: str) -> np.ndarray:
    band = src.read(1, masked=True)  # type: ignore[attr-defined]
    return clean_heights(np.ma.filled(band.astype(np.float64), np.nan), what)


def _read_tiles(src: object, what: str) -> TiledValues:
    """The band's tiles that hold a value (absent tiles of a sparse GeoTIFF read as nodata
    and are left out)."""
    from rasterio.windows import Window

    h, w = src.height, src.width  # type: ignore[attr-defined]
    bh, bw = src.block_shapes[0]  # type: ignore[attr-defined]
    index = np.full((-(-h // bh), -(-w // bw)), -1, dtype=np.int64)
    blocks: list[np.ndarray] = []
    for i in range(index.shape[0]):  # a loop over tiles
        for j in range(index.shape[1]):
            win = Window(j * bw, i * bh, min(bw, w - j * bw), min(bh, h - i * bh))
            a = src.read(1, window=win, masked=True)  # type: ignore[attr-defined]
            if a.mask.all():
                continue
            full = np.full((bh, bw), np.nan)
            full[:a.shape[0], :a.shape[1]] = clean_heights(
                np.ma.filled(a.astype(np.float64), np.nan), what)
            index[i, j] = len(blocks)
            blocks.append(full)
    return TiledValues(np.asarray(blocks).reshape(-1, bh, bw), index, (h, w))
