"""The cell rule on points in Python, and corridor crops through PDAL.

PDAL has no percentile writer: :mod:`canopyblocks.reference.raster_tiles` pairs points with
cells by PDAL's neighbourhood rule here and computes per-cell maxima and percentiles with
numpy.  Also cuts the points inside a corridor polygon (``crop_corridor.json``).
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_output
from ..errors import InputError, NoUsableDataError
from ..progress import Progress
from .pdal import expand_readers, load_pipeline, run_pipeline, tile_info, write_pipeline

__all__ = ["LidarPoints", "cell_neighbourhoods", "cell_percentile", "cell_groups",
           "max_and_percentile",
           "cell_max_and_percentile",
           "crop_corridor"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LidarPoints:
    """Point coordinates as float64 arrays of equal length (metres)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray

    def __len__(self) -> int:
        return int(self.x.size)


def cell_neighbourhoods(
    x: np.ndarray, y: np.ndarray, *, origin_x: float, top_y: float, resolution: float,
    width: int, height: int, radius: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (cell, point) with the point strictly within ``radius`` of the cell centre.

    This is PDAL writers.gdal's rule (a point counts for every cell whose centre is at a
    horizontal distance ``< radius``), computed for ``radius <= resolution`` by testing the
    3 x 3 cells around each point's own cell (vectorised over points).

    Parameters
    ----------
    x, y : ndarray
        Point coordinates, metres, in the grid's CRS.
    origin_x, top_y : float
        West and north edges of the grid, metres.
    resolution : float
        Cell size, metres.
    width, height : int
        Grid columns and rows (row 0 is the north row).
    radius : float
        Neighbourhood radius, metres; at most ``resolution``.

    Returns
    -------
    cell : ndarray of int64
        Flat cell index ``row * width + col``.
    point : ndarray of int64
        Index into ``x``/``y``.
    """
    if not 0 < radius <= resolution:
        raise InputError(f"radius {radius} must be in (0, resolution={resolution}]")
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    fx = (x - origin_x) / resolution
    fy = (top_y - y) / resolution
    col0 = np.floor(fx).astype(np.int64)
    row0 = np.floor(fy).astype(np.int64)
    fx -= col0  # the position in the own cell, 0..1 (a prefilter only)
    fy -= row0
    reach = radius / resolution + 1e-6
    near = {-1: fy < reach - 0.5, 0: None, 1: fy > 1.5 - reach}
    near_c = {-1: fx < reach - 0.5, 0: None, 1: fx > 1.5 - reach}
    cells, points = [], []
    for dr in (-1, 0, 1):  # nine neighbour offsets, each vectorised over the points that
        for dc in (-1, 0, 1):  # can reach that cell (the exact test is the same for all)
            a, b = near[dr], near_c[dc]
            cand = (a & b if a is not None and b is not None else a if a is not None else b)
            if cand is None:  # the own cell: only a point near a corner needs the test
                idx = np.arange(x.size, dtype=np.int64)
                col, row = col0, row0
                test = np.flatnonzero((np.abs(fx - 0.5) > 0.49) | (np.abs(fy - 0.5) > 0.49))
                ok = (col >= 0) & (col < width) & (row >= 0) & (row < height)
                cx = origin_x + (col[test] + 0.5) * resolution
                cy = top_y - (row[test] + 0.5) * resolution
                ok[test] &= np.hypot(x[test] - cx, y[test] - cy) < radius
            else:
                idx = np.flatnonzero(cand)
                col = col0[idx] + dc
                row = row0[idx] + dr
                cx = origin_x + (col + 0.5) * resolution
                cy = top_y - (row + 0.5) * resolution
                ok = ((col >= 0) & (col < width) & (row >= 0) & (row < height)
                      & (np.hypot(x[idx] - cx, y[idx] - cy) < radius))
            cells.append(row[ok] * width + col[ok])
            points.append(idx[ok])
    return np.concatenate(cells), np.concatenate(points)


def cell_percentile(
    cell: np.ndarray, values: np.ndarray, n_cells: int, q: float = 90.0
) -> np.ndarray:
    """Per-cell ``q``-th percentile of ``values``, numpy's default ("linear") rule.

    For a cell with sorted values ``v[0..n-1]``: ``pos = q/100 * (n - 1)``,
    ``result = v[floor(pos)] + (v[ceil(pos)] - v[floor(pos)]) * (pos - floor(pos))``,
    exactly :func:`numpy.percentile` with ``method="linear"``.  Vectorised: one sort by
    (cell, value), no loop over cells.

    Returns
    -------
    ndarray of float64, shape (n_cells,)
        NaN where a cell has no value.
    """
    return cell_max_and_percentile(cell, values, n_cells, q)[1]


def cell_max_and_percentile(
    cell: np.ndarray, values: np.ndarray, n_cells: int, q: float = 90.0
) -> tuple[np.ndarray, np.ndarray]:
    """Per-cell maximum and ``q``-th percentile (numpy's "linear" rule) from one sort.

    The same values as ``cell_percentile(..., 100.0)`` and ``cell_percentile(..., q)``.

    Returns
    -------
    (max, percentile) : ndarrays of float64, shape (n_cells,)
        NaN where a cell has no value.
    """
    if not 0.0 <= q <= 100.0:
        raise InputError(f"percentile q={q} must be in [0, 100]")
    top = np.full(n_cells, np.nan)
    pct = np.full(n_cells, np.nan)
    if cell.size == 0:
        return top, pct
    uniq, _, top_u, pct_u = cell_groups(cell, values, q)
    top[uniq] = top_u
    pct[uniq] = pct_u
    return top, pct


def cell_groups(cell: np.ndarray, values: np.ndarray, q: float = 90.0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The distinct cells (sorted), each pair's position among them, and each cell's
    maximum and ``q``-th percentile (numpy's "linear" rule) of ``values``: one sort by
    (cell, value), no array over the whole grid."""
    v = np.asarray(values, dtype=np.float64)
    order = _cell_value_order(cell, v)
    c = cell[order]
    v = v[order]
    first = np.r_[True, c[1:] != c[:-1]]
    start = np.flatnonzero(first)
    uniq = c[start]
    count = np.diff(np.r_[start, c.size])
    inverse = np.empty(c.size, dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    return (uniq, inverse, *max_and_percentile(v, start, count, q))


def max_and_percentile(v: np.ndarray, start: np.ndarray, count: np.ndarray, q: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Each group's maximum and ``q``-th percentile (numpy's "linear" rule) of values
    ``v`` sorted within groups of ``count`` values from ``start``."""
    pos = (q / 100.0) * (count - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, count - 1)
    a = v[start + lo]
    return v[start + count - 1], a + (v[start + hi] - a) * (pos - lo)


def _cell_value_order(cell: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``np.lexsort((values, cell))`` (sorted by cell, then value, ties in input order),
    from two plain sorts: the values' stable rank, then one int64 key per pair."""
    n = values.size
    cell = np.asarray(cell, dtype=np.int64)
    lo, hi = int(cell.min()), int(cell.max())
    if (hi - lo + 1) * n >= 2 ** 62:  # a key would not fit in 64 bits
        return np.lexsort((values, cell))
    rank = np.empty(n, dtype=np.int64)
    rank[np.argsort(values, kind="stable")] = np.arange(n, dtype=np.int64)
    return np.argsort((cell - lo) * n + rank)


def crop_corridor(
    las_paths: list[str | os.PathLike[str]],
    polygon_wkt: str,
    out_path: str | os.PathLike[str],
    *,
    pdal: str | os.PathLike[str] | None = None,
    progress: Progress | None = None,
) -> Path:
    """Write the points of ``las_paths`` inside ``polygon_wkt`` to ``out_path`` (LAS/LAZ).

    ``polygon_wkt`` is in the tiles' CRS (metres).  Uses ``crop_corridor.json``; the
    output keeps the input's header format (``forward: all``) and is written atomically.

    Raises
    ------
    NoUsableDataError
        No point falls inside the polygon.
    """
    if not polygon_wkt.strip().upper().startswith(("POLYGON", "MULTIPOLYGON")):
        raise InputError(f"corridor must be a WKT POLYGON or MULTIPOLYGON, got "
                         f"{polygon_wkt[:40]!r}")
    stages = expand_readers(load_pipeline("crop_corridor"), [(p, None) for p in las_paths])
    out = Path(out_path)
    with tempfile.TemporaryDirectory(prefix="canopyblocks-pdal-") as tmp, \
            atomic_output(out) as part:
        pipe = write_pipeline(stages, Path(tmp) / "crop_corridor.json")
        run_pipeline(pipe, {"filters.crop.polygon": polygon_wkt,
                            "writers.las.filename": part}, pdal=pdal, progress=progress)
        if not part.exists() or tile_info(part, pdal=pdal).n_points == 0:
            raise NoUsableDataError(f"no point of {', '.join(map(str, las_paths))} lies in "
                                    "the corridor polygon; check its CRS and position")
    return out
