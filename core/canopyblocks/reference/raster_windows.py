"""A sparse grid: the survey's grid held only in the windows that meet the area.

A corridor is a thin line; its bounding box is not.  The rasters' :class:`Grid` stays the
corridor's (or the survey's) box, so every cell keeps the row, column and value it has on
the dense grid, but cells exist only in square windows of :data:`WINDOW` x :data:`WINDOW`
cells whose box meets the area polygon (every window when there is no polygon).  Memory,
time and disk follow the corridor's area, not its box; the files are tiled GeoTIFFs whose
tiles are the windows, and the windows that do not exist are absent tiles, which GDAL
(and so QGIS) reads as nodata.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError
from .raster_grid import Grid

__all__ = ["WINDOW", "CORRIDOR_WINDOW", "MAX_CELLS", "Windows", "SparseGrids", "to_dense", "area_test"]

WINDOW = 256
"""Cells on a window's side (and on a GeoTIFF tile's side) over a whole survey."""

CORRIDOR_WINDOW = 64
"""Cells on a window's side along a corridor (a thin area: small windows hold less)."""

MAX_CELLS = 100_000_000
"""The most cells a run may hold (in its windows), about 2.4 GB for its rasters."""


@dataclass(frozen=True)
class Windows:
    """The windows of ``grid`` that exist, as sorted flat ids ``wrow * n_cols + wcol``."""

    grid: Grid
    ids: np.ndarray
    size: int = WINDOW

    @property
    def n_rows(self) -> int:
        """Windows down the grid."""
        return -(-self.grid.height // self.size)

    @property
    def n_cols(self) -> int:
        """Windows across the grid."""
        return -(-self.grid.width // self.size)

    @property
    def n_cells(self) -> int:
        """Cells held (every window counted whole)."""
        return int(self.ids.size) * self.size * self.size

    @classmethod
    def over(cls, grid: Grid, area: Any = None, size: int = WINDOW) -> Windows:
        """The windows whose box meets ``area`` (a shapely geometry; None: all of them)."""
        n_rows, n_cols = -(-grid.height // size), -(-grid.width // size)
        if area is None:
            return cls(grid, np.arange(n_rows * n_cols, dtype=np.int64), size)
        if area.is_empty:
            return cls(grid, np.empty(0, np.int64), size)
        found = [_meeting(grid, part, size, n_rows, n_cols)  # a loop over the area's parts
                 for part in getattr(area, "geoms", [area])]
        ids = np.unique(np.concatenate([f for f in found if f.size] or [np.empty(0)]))
        return cls(grid, ids.astype(np.int64), size)

    def check_size(self, what: str) -> None:
        """Refuse a run whose windows would hold more than :data:`MAX_CELLS` cells."""
        if self.n_cells > MAX_CELLS:
            g = self.grid
            raise InputError(
                f"the grid over {what} would have {self.n_cells:.3g} cells at "
                f"{g.resolution:g} m in {self.ids.size} windows of {self.size} x {self.size} "
                f"(limit {MAX_CELLS:.0e}; its box is {g.width:.3g} x {g.height:.3g} cells); "
                "use a coarser resolution or a smaller area")

    def locate(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(slot, row, col, ok)`` of flat grid cells: the window's position in ``ids``
        (valid where ``ok``: the window exists) and the cell's row and column in it."""
        g = self.grid
        row, col = np.divmod(np.asarray(cells, dtype=np.int64), g.width)
        wid = (row // self.size) * self.n_cols + col // self.size
        slot = np.searchsorted(self.ids, wid)
        ok = slot < self.ids.size
        ok[ok] = self.ids[slot[ok]] == wid[ok]
        return np.where(ok, slot, 0), row % self.size, col % self.size, ok

    def origin(self, slot: int) -> tuple[int, int]:
        """The grid row and column of window ``slot``'s first cell."""
        wr, wc = divmod(int(self.ids[slot]), self.n_cols)
        return wr * self.size, wc * self.size

    def cells(self, slot: int) -> np.ndarray:
        """(size, size) flat grid cells of window ``slot`` (-1 beyond the grid's edge)."""
        r0, c0 = self.origin(slot)
        rows = r0 + np.arange(self.size)[:, None]
        cols = c0 + np.arange(self.size)[None, :]
        inside = (rows < self.grid.height) & (cols < self.grid.width)
        return np.where(inside, rows * self.grid.width + cols, -1)

    def clip(self, slot: int) -> tuple[int, int, int, int]:
        """``(row0, col0, rows, cols)`` of window ``slot`` within the grid."""
        r0, c0 = self.origin(slot)
        return (r0, c0, min(self.size, self.grid.height - r0),
                min(self.size, self.grid.width - c0))

    def blocks(self, fill: float = np.nan) -> np.ndarray:
        """A ``(windows, size, size)`` float64 array of ``fill``."""
        return np.full((self.ids.size, self.size, self.size), fill)


@dataclass
class SparseGrids:
    """The merged grids, window by window: ``(windows, size, size)`` float64, NaN = none."""

    windows: Windows
    dtm: np.ndarray
    top: np.ndarray
    p90: np.ndarray

    def assign(self, cells: np.ndarray, dtm: np.ndarray, top: np.ndarray,
               p90: np.ndarray) -> None:
        """Set the values of flat grid ``cells`` (those outside every window are dropped)."""
        slot, r, c, ok = self.windows.locate(cells)
        slot, r, c = slot[ok], r[ok], c[ok]
        self.dtm[slot, r, c] = dtm[ok]
        self.top[slot, r, c] = top[ok]
        self.p90[slot, r, c] = p90[ok]

    def mask_outside(self, poly: Any) -> None:
        """NaN in every grid where a cell with a value has its centre outside ``poly``."""
        import shapely

        has = np.isfinite(self.top) | np.isfinite(self.dtm) | np.isfinite(self.p90)
        s, r, c = np.nonzero(has)
        w = self.windows
        ids = w.ids[s]
        row = (ids // w.n_cols) * w.size + r
        col = (ids % w.n_cols) * w.size + c
        g = w.grid
        shapely.prepare(poly)
        out = ~shapely.contains_xy(poly, g.origin_x + (col + 0.5) * g.resolution,
                                   g.top_y - (row + 0.5) * g.resolution)
        for a in (self.dtm, self.top, self.p90):
            a[s[out], r[out], c[out]] = np.nan

    def dense(self, name: str) -> np.ndarray:
        """One grid as a dense ``(height, width)`` array (for small grids and checks)."""
        return to_dense(getattr(self, name), self.windows)


def _meeting(grid: Grid, part: Any, size: int, n_rows: int, n_cols: int) -> np.ndarray:
    """Flat ids of the windows whose box meets ``part`` (those under its bounds tested)."""
    import shapely

    ext = size * grid.resolution
    a = part.bounds
    c0 = max(0, math.floor((a[0] - grid.origin_x) / ext))
    c1 = min(n_cols, math.floor((a[2] - grid.origin_x) / ext) + 1)
    r0 = max(0, math.floor((grid.top_y - a[3]) / ext))
    r1 = min(n_rows, math.floor((grid.top_y - a[1]) / ext) + 1)
    if part.is_empty or c1 <= c0 or r1 <= r0:
        return np.empty(0, np.int64)
    rr, cc = np.meshgrid(np.arange(r0, r1), np.arange(c0, c1), indexing="ij")
    rr, cc = rr.ravel(), cc.ravel()
    boxes = shapely.box(grid.origin_x + cc * ext, grid.top_y - (rr + 1) * ext,
                        grid.origin_x + (cc + 1) * ext, grid.top_y - rr * ext)
    meets = shapely.intersects(part, boxes)
    return (rr[meets] * n_cols + cc[meets]).astype(np.int64)


def to_dense(blocks: np.ndarray, windows: Windows, fill: float = np.nan) -> np.ndarray:
    """``(windows, size, size)`` blocks as a dense ``(height, width)`` array."""
    g = windows.grid
    out = np.full((g.height, g.width), fill, dtype=blocks.dtype)
    for slot in range(windows.ids.size):  # a loop over windows, each a block copy
        r0, c0, nr, nc = windows.clip(slot)
        out[r0:r0 + nr, c0:c0 + nc] = blocks[slot, :nr, :nc]
    return out


def area_test(area: Any, box: Sequence[float], resolution: float
              ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``test(x, y)``: exactly ``shapely.contains_xy(area, x, y)``, fast for many points.

    The part of the box (a tile's, metres) under the area's bounds is cut into square
    cells (at least ``resolution``, at most ~5,000 of them); a point in a cell wholly
    inside the area is in, one in a cell that misses the area (or outside the area's
    bounds) is out, and only the points of the cells on the area's edge, and those outside
    the box, are tested against the polygon.
    """
    import shapely

    shapely.prepare(area)
    ab = area.bounds
    x0, y0 = max(float(box[0]), ab[0]), max(float(box[1]), ab[1])
    x1, y1 = min(float(box[2]), ab[2]), min(float(box[3]), ab[3])
    if not (all(math.isfinite(v) for v in (x0, y0, x1, y1)) and x1 > x0 and y1 > y0):
        return lambda x, y: np.asarray(shapely.contains_xy(area, x, y))
    step = max(float(resolution), math.sqrt((x1 - x0) * (y1 - y0) / 5_000))
    nx, ny = math.ceil((x1 - x0) / step), math.ceil((y1 - y0) / step)
    iy, ix = np.divmod(np.arange(nx * ny), nx)
    eps = 1e-6  # each cell a little larger: a point on a cell edge is inside its box
    cells = shapely.box(x0 + ix * step - eps, y0 + iy * step - eps,
                        x0 + (ix + 1) * step + eps, y0 + (iy + 1) * step + eps)
    state = np.where(shapely.contains_properly(area, cells), 1,
                     np.where(shapely.intersects(area, cells), 2, 0)).astype(np.int8)

    def test(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        cx = np.floor((x - x0) / step)
        cy = np.floor((y - y0) / step)
        st = np.where((x < ab[0]) | (x > ab[2]) | (y < ab[1]) | (y > ab[3]), 0, 2)
        inside = (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny) & (st == 2)
        st[inside] = state[cy[inside].astype(np.int64) * nx + cx[inside].astype(np.int64)]
        out = st == 1
        edge = np.flatnonzero(st == 2)
        out[edge] = shapely.contains_xy(area, x[edge], y[edge])
        return out

    return test
