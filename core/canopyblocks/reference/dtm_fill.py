"""Filling the DTM's holes, and writing the rasters of a run with one CRS.

PDAL's cell rule (the mean of the ground points within ``resolution * sqrt(2) / 2`` of a
cell centre) leaves cells without a value where dense canopy hid the ground: 3-45 % of the
cells of the bundled tiles at 2 m.  :func:`fill_dtm_holes` gives them a value and says
which:

* **what is filled**: DTM cells without a value that either hold points (the DSM has a
  value there: the survey saw the cell, only not its ground) or are enclosed by such
  cells (a gap inside the survey).  Cells outside the survey stay nodata: nothing there
  to interpolate from.
* **how**: harmonic (Laplace) interpolation: each filled cell is the mean of its four
  neighbours, the measured cells held fixed -- one sparse linear system for all holes.  It
  reproduces planes exactly, never leaves the range of the measured ground around a hole,
  and scales with the number of holes (a Delaunay TIN over grid cells was measured at
  486 s for 1000 x 1000 cells with 11 % holes: the cell centres are a degenerate input
  for the triangulation).  A group of holes with no measured neighbour (only possible when
  the survey holds no ground near it) takes the value of the nearest measured cell.

Every filled cell is marked in the fill mask (``dtm_fill_mask.tif``: 1 filled, 0 measured,
255 no value), so a user can leave them out or judge them.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from ..errors import DependencyError
from ..geo import as_crs
from .raster_grid import NODATA, Grid, authority_crs
from .raster_windows import WINDOW, Windows

__all__ = ["fill_dtm_holes", "fill_windows", "groundless_cells", "solve_holes", "MASK_FILLED",
           "MASK_MEASURED", "MASK_NODATA"]

log = logging.getLogger(__name__)

MASK_MEASURED = 0
MASK_FILLED = 1
MASK_NODATA = 255


def fill_dtm_holes(dtm: np.ndarray, support: np.ndarray,
                   exclude: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The DTM with its holes filled, and the mask of the filled cells.

    Parameters
    ----------
    dtm : ndarray, shape (rows, cols)
        Ground heights (m), NaN where the cell has no ground point.
    support : ndarray of bool, same shape
        True where the cell holds points of any class (where the DSM has a value).
    exclude : ndarray of bool, same shape, optional
        Cells never filled (e.g. a tile without ground points: see :func:`groundless_cells`).

    Returns
    -------
    filled : ndarray float64
        ``dtm`` with the holes inside the survey interpolated (see the module docstring).
    mask : ndarray bool
        True exactly where ``filled`` has a value that ``dtm`` had not.
    """
    from scipy import ndimage

    dtm = np.asarray(dtm, dtype=np.float64)
    support = np.asarray(support, dtype=bool)
    if dtm.shape != support.shape or dtm.ndim != 2:
        raise ValueError(f"dtm {dtm.shape} and support {support.shape} must be one 2-D grid")
    measured = np.isfinite(dtm)
    covered = ndimage.binary_fill_holes(support | measured)
    holes = covered & ~measured
    if exclude is not None:
        holes &= ~np.asarray(exclude, dtype=bool)
    filled = dtm.copy()
    if not holes.any() or not measured.any():
        return filled, np.zeros(dtm.shape, dtype=bool)
    flat = np.flatnonzero(holes)
    values, solvable = solve_holes(flat, lambda cells: dtm.reshape(-1)[cells], dtm.shape[1],
                                   dtm.shape[0])
    filled.reshape(-1)[flat[solvable]] = values[solvable]
    rest = np.zeros(dtm.size, dtype=bool)
    rest[flat[~solvable]] = True
    rest = rest.reshape(dtm.shape)
    if rest.any():  # a group of holes with no measured neighbour: the nearest measured cell
        idx = ndimage.distance_transform_edt(~measured, return_distances=False,
                                             return_indices=True)
        filled[rest] = dtm[idx[0][rest], idx[1][rest]]
    return filled, holes


def solve_holes(holes: np.ndarray, value_at: Callable[[np.ndarray], np.ndarray], width: int,
                height: int) -> tuple[np.ndarray, np.ndarray]:
    """Harmonic values at the hole cells, and which could be solved.

    ``holes`` are sorted flat cells ``row * width + col``; ``value_at(cells)`` gives the
    measured DTM at flat cells (NaN where not measured).  A group of holes (4-connected)
    touching a measured cell is solved by Laplace's equation: each hole is the mean of its
    4 neighbours that are measured or holes (other cells do not take part), measured cells
    fixed; one sparse linear system, its unknowns in row-major order.  The others are not
    solvable (NaN).
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import spsolve

    n = holes.size
    row, col = np.divmod(holes, width)
    degree = np.zeros(n)
    known_n = np.zeros(n)
    rhs = np.zeros(n)
    off_i: list[np.ndarray] = []
    off_j: list[np.ndarray] = []
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):  # the 4 directions, not the cells
        rr, cc = row + dr, col + dc
        inside = (rr >= 0) & (rr < height) & (cc >= 0) & (cc < width)
        me = np.flatnonzero(inside)
        nb = rr[inside] * width + cc[inside]
        v = value_at(nb)
        known = np.isfinite(v)
        np.add.at(rhs, me[known], v[known])
        np.add.at(degree, me[known], 1.0)
        np.add.at(known_n, me[known], 1.0)
        pos = np.minimum(np.searchsorted(holes, nb), max(n - 1, 0))
        linked = holes[pos] == nb
        np.add.at(degree, me[linked], 1.0)
        off_i.append(me[linked])
        off_j.append(pos[linked])
    links = csr_matrix((np.ones(sum(a.size for a in off_i)),
                        (np.concatenate(off_i), np.concatenate(off_j))), shape=(n, n))
    _, group = connected_components(links, directed=False)
    solvable = (np.bincount(group, weights=known_n) > 0)[group]
    out = np.full(n, np.nan)
    m = int(solvable.sum())
    if m == 0:
        return out, solvable
    index = np.cumsum(solvable) - 1
    keep = [solvable[a] for a in off_i]
    i = np.concatenate([np.arange(m), *(index[a][k] for a, k in zip(off_i, keep))])
    j = np.concatenate([np.arange(m), *(index[b][k] for b, k in zip(off_j, keep))])
    v = np.concatenate([degree[solvable], -np.ones(i.size - m)])
    matrix = csr_matrix((v, (i, j)), shape=(m, m))
    out[solvable] = np.asarray(spsolve(matrix, rhs[solvable]), dtype=np.float64)
    return out, solvable


def rasterio_module() -> Any:
    """rasterio, or the project's error saying how to install it."""
    try:
        import rasterio
    except ImportError:
        raise DependencyError("writing reference rasters needs rasterio: "
                              "pip install 'canopyblocks[raster]'") from None
    return rasterio


def grid_crs(like: Path, grid: Grid) -> pyproj.CRS:
    """The CRS PDAL wrote into ``like`` with its authority codes (checked: same grid)."""
    rasterio = rasterio_module()
    with rasterio.open(like) as src:
        crs = src.crs
        if (src.width, src.height) != (grid.width, grid.height):
            raise RuntimeError(f"PDAL wrote a {src.width} x {src.height} raster, expected "
                               f"{grid.width} x {grid.height}")
    found = pyproj.CRS.from_wkt(crs.to_wkt()) if crs is not None else as_crs(grid.crs_wkt)
    return authority_crs(found)


def write_grid(path: Path, values: np.ndarray, grid: Grid, crs: pyproj.CRS,
               dtype: str = "float32", nodata: float = NODATA) -> None:
    """Write a (height, width) grid as a GeoTIFF on ``grid`` (non-finite -> ``nodata``)."""
    rasterio = rasterio_module()
    data = np.where(np.isfinite(values), values, nodata).astype(dtype)
    profile = _profile(grid, crs, dtype, nodata)
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data, 1)


def fill_and_write_dtm(dtm_path: Path, mask_path: Path, support: np.ndarray, grid: Grid,
                       crs: pyproj.CRS, exclude: np.ndarray | None = None) -> int:
    """Rewrite PDAL's DTM at ``dtm_path`` with its holes filled and ``crs``; write the fill
    mask to ``mask_path``.  Returns the number of filled cells."""
    rasterio = rasterio_module()
    with rasterio.open(dtm_path) as src:
        raw = src.read(1).astype(np.float64)
        nodata = src.nodata
    raw[(raw == NODATA) | (raw == nodata) | ~np.isfinite(raw)] = np.nan
    filled, mask = fill_dtm_holes(raw, support, exclude)
    write_grid(dtm_path, filled, grid, crs)
    codes = np.where(mask, MASK_FILLED, np.where(np.isfinite(filled), MASK_MEASURED,
                                                 MASK_NODATA))
    write_grid(mask_path, codes, grid, crs, dtype="uint8", nodata=MASK_NODATA)
    n = int(mask.sum())
    log.info("DTM: %d of %d cells filled by interpolation (%.1f %%)", n, mask.size,
             100.0 * n / mask.size)
    return n


def groundless_cells(tiles: Sequence[tuple[str, int, int, Sequence[float]]],
                     windows: Windows, dtm: np.ndarray) -> np.ndarray | None:
    """The cells a tile without ground points covers and no ground point measured.

    A survey tile whose points include no ground (class 2) while other tiles do (an
    unclassified tile among classified ones) would have its whole area interpolated from
    the ground around it.  Its cells without a measured ground are left without DTM
    instead (blocks there get no ground reference: left out of the ground statistics),
    with a warning naming the tile.

    Parameters
    ----------
    tiles : sequence of (path, n_points, n_ground, box)
        Each tile read; ``box`` its extent in the grid's CRS.
    windows : the sparse grid's windows
    dtm : (windows, size, size) blocks, NaN where no ground was measured

    Returns
    -------
    bool blocks like ``dtm``, or None when no tile is groundless (or none has ground).
    """
    from ..readers.tile_checks import warn_groundless

    bare = [t for t in tiles if t[1] > 0 and t[2] == 0]
    if not bare or not any(t[2] > 0 for t in tiles):
        return None
    grid = windows.grid
    wr, wc = np.divmod(windows.ids, windows.n_cols)
    col = wc[:, None] * windows.size + np.arange(windows.size)  # (windows, size)
    row = wr[:, None] * windows.size + np.arange(windows.size)
    cx = grid.origin_x + (col + 0.5) * grid.resolution
    cy = grid.top_y - (row + 0.5) * grid.resolution
    out = np.zeros(dtm.shape, dtype=bool)
    for path, n, _, box in bare:  # a loop over the groundless tiles, vectorised over cells
        cols = (cx >= box[0]) & (cx <= box[2]) & (col < grid.width)  # not past the grid
        rows = (cy >= box[1]) & (cy <= box[3]) & (row < grid.height)
        cells = rows[:, :, None] & cols[:, None, :] & ~np.isfinite(dtm)
        out |= cells
        warn_groundless(path, f"{n:,} points", f"its {int(cells.sum()):,} cells without "
                        "measured ground are left without DTM (not interpolated across the "
                        "tile), so blocks there have no ground reference",
                        "classify its ground (e.g. PDAL filters.smrf) or make the rasters "
                        "with --smrf")
    return out


def _enclosed(uncovered: np.ndarray, windows: Windows) -> np.ndarray:
    """(windows, size, size) bool: the uncovered cells not 4-connected to the grid's edge
    (``scipy.ndimage.binary_fill_holes`` on the dense grid, where the windows that do not
    exist are uncovered): each window's uncovered groups are labelled, then joined across
    window edges, to the absent windows' groups and to the grid's edge."""
    from scipy import ndimage
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    cross = ndimage.generate_binary_structure(2, 1)
    k = windows.ids.size
    labels = np.zeros(uncovered.shape, dtype=np.int64)
    total = 0
    for slot in range(k):  # a loop over windows, each labelled whole
        lab, n = ndimage.label(uncovered[slot], structure=cross)
        labels[slot] = np.where(lab > 0, lab + total, 0)
        total += n
    present = np.zeros((windows.n_rows, windows.n_cols), dtype=bool)
    present.reshape(-1)[windows.ids] = True
    absent, _ = ndimage.label(~present, structure=cross)
    absent = np.where(absent > 0, absent + total, 0)
    edges: list[tuple[np.ndarray, np.ndarray]] = []
    border = np.zeros((windows.n_rows, windows.n_cols), dtype=bool)
    border[[0, -1], :] = True
    border[:, [0, -1]] = True
    edges.append((absent[border & ~present], np.zeros(int((border & ~present).sum()), np.int64)))
    g = windows.grid
    slot_of = np.full(present.shape, -1, dtype=np.int64)
    slot_of.reshape(-1)[windows.ids] = np.arange(k)
    for slot in range(k):  # a loop over windows and their 4 edges
        wr, wc = divmod(int(windows.ids[slot]), windows.n_cols)
        r0, c0, nr, nc = windows.clip(slot)
        lab = labels[slot]
        sides = ((lab[0, :nc], wr - 1, wc, r0 == 0, None),
                 (lab[nr - 1, :nc], wr + 1, wc, r0 + nr == g.height, (0, slice(0, nc))),
                 (lab[:nr, 0], wr, wc - 1, c0 == 0, None),
                 (lab[:nr, nc - 1], wr, wc + 1, c0 + nc == g.width, (slice(0, nr), 0)))
        for edge, nr_, nc_, at_border, far in sides:
            on = edge > 0
            if at_border:
                edges.append((edge[on], np.zeros(int(on.sum()), np.int64)))
                continue
            other = slot_of[nr_, nc_]
            if other < 0:
                edges.append((edge[on], np.full(int(on.sum()), absent[nr_, nc_])))
            elif far is not None:  # the window after this one: its first row or column
                facing = labels[other][far]
                both = on & (facing > 0)
                edges.append((edge[both], facing[both]))
    a = np.concatenate([e[0] for e in edges])
    b = np.concatenate([e[1] for e in edges])
    n_nodes = int(max(total, int(absent.max(initial=0)))) + 1
    graph = coo_matrix((np.ones(a.size), (a, b)), shape=(n_nodes, n_nodes))
    _, comp = connected_components(graph, directed=False)
    open_ = comp == comp[0]
    return (labels > 0) & ~open_[labels]


def fill_windows(dtm: np.ndarray, support: np.ndarray, windows: Windows,
                 exclude: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fill_dtm_holes` on a sparse grid: ``(windows, size, size)`` blocks.

    The same holes and values as on the dense grid where the windows that do not exist
    hold no point, except that those windows' cells stay without a value (they are outside
    the area); a group of holes with no measured neighbour takes the value of the nearest
    measured cell (a k-d tree: on a tie of distances it may take another of the nearest).
    """
    measured = np.isfinite(dtm)
    covered = support | measured
    for slot in range(windows.ids.size):  # cells beyond the grid's edge are not cells
        _, _, nr, nc = windows.clip(slot)
        covered[slot, nr:, :] = True
        covered[slot, :, nc:] = True
    holes = (covered | _enclosed(~covered, windows)) & ~measured
    for slot in range(windows.ids.size):
        _, _, nr, nc = windows.clip(slot)
        holes[slot, nr:, :] = False
        holes[slot, :, nc:] = False
    if exclude is not None:  # e.g. a tile without ground points (groundless_cells)
        holes &= ~exclude
    filled = dtm.copy()
    if not holes.any() or not measured.any():
        return filled, np.zeros(dtm.shape, dtype=bool)
    flat = np.concatenate([windows.cells(s)[holes[s]] for s in range(windows.ids.size)])
    order = np.argsort(flat)
    flat = flat[order]
    g = windows.grid

    def value_at(cells: np.ndarray) -> np.ndarray:
        at, r, c, ok = windows.locate(cells)
        return np.where(ok, dtm[at, r, c], np.nan)

    values, solvable = solve_holes(flat, value_at, g.width, g.height)
    if not solvable.all():  # the nearest measured cell
        from scipy.spatial import cKDTree

        known = np.concatenate([windows.cells(s)[measured[s]] for s in range(windows.ids.size)])
        tree = cKDTree(np.column_stack(np.divmod(known, g.width)))
        _, near = tree.query(np.column_stack(np.divmod(flat[~solvable], g.width)))
        values[~solvable] = value_at(known[near])
    at, r, c, _ = windows.locate(flat)
    filled[at, r, c] = values
    return filled, holes


def _profile(grid: Grid, crs: pyproj.CRS, dtype: str, nodata: float) -> dict[str, Any]:
    from rasterio.crs import CRS
    from rasterio.transform import Affine

    code = crs.srs if crs.srs.upper().startswith("EPSG:") else None
    return dict(driver="GTiff", width=grid.width, height=grid.height, count=1,
                dtype=dtype, nodata=nodata,
                crs=CRS.from_user_input(code) if code else CRS.from_wkt(crs.to_wkt()),
                transform=Affine.from_gdal(*grid.transform))


def write_windows(path: Path, blocks: np.ndarray, windows: Windows, crs: pyproj.CRS,
                  dtype: str = "float32", nodata: float = NODATA,
                  overviews: bool = False) -> None:
    """Write ``(windows, size, size)`` blocks as a tiled, DEFLATE-compressed GeoTIFF of
    :data:`~canopyblocks.reference.raster_windows.WINDOW`-cell tiles, each written once
    from the windows in it: a tile without a value, and every tile without a window, is
    absent (``SPARSE_OK``), read as ``nodata`` by GDAL and QGIS.  With ``overviews`` (a
    whole survey), overviews by averaging are added."""
    rasterio = rasterio_module()
    from rasterio.windows import Window

    tile = max(WINDOW, windows.size)
    per = tile // windows.size  # windows on a tile's side
    profile = _profile(windows.grid, crs, dtype, nodata)
    profile.update(tiled=True, blockxsize=tile, blockysize=tile, compress="deflate",
                   predictor=3 if dtype.startswith("float") else 2, sparse_ok=True,
                   bigtiff="if_safer")
    wr, wc = np.divmod(windows.ids, windows.n_cols)
    tile_of = (wr // per) * (-(-windows.n_cols // per)) + wc // per
    order = np.argsort(tile_of, kind="stable")
    tile_of = tile_of[order]
    starts = (np.flatnonzero(np.r_[True, tile_of[1:] != tile_of[:-1]]) if tile_of.size
              else np.empty(0, np.int64))
    g = windows.grid
    with rasterio.open(path, "w", **profile) as dst:
        for k, first in enumerate(starts):  # a loop over tiles, each written once
            last = starts[k + 1] if k + 1 < len(starts) else tile_of.size
            slots = order[first:last]
            r0 = int(wr[slots[0]] // per) * tile
            c0 = int(wc[slots[0]] // per) * tile
            nr, nc = min(tile, g.height - r0), min(tile, g.width - c0)
            data = np.full((nr, nc), nodata, dtype=dtype)
            for slot in slots:  # the windows of this tile (at most per * per)
                wr0, wc0, wnr, wnc = windows.clip(int(slot))
                block = blocks[slot, :wnr, :wnc]
                ok = np.isfinite(block) if block.dtype.kind == "f" else block != nodata
                data[wr0 - r0:wr0 - r0 + wnr, wc0 - c0:wc0 - c0 + wnc] = np.where(ok, block,
                                                                                 nodata)
            if (data != nodata).any():
                dst.write(data, 1, window=Window(c0, r0, nc, nr))
        if overviews:
            from rasterio.enums import Resampling

            factors = [2 ** i for i in range(1, 16)
                       if max(g.width, g.height) / 2 ** i >= tile / 2]
            if factors:
                dst.build_overviews(factors, Resampling.average if dtype.startswith("float")
                                    else Resampling.nearest)


def fill_and_write_windows(dtm_path: Path, mask_path: Path, dtm: np.ndarray,
                           support: np.ndarray, windows: Windows, crs: pyproj.CRS,
                           overviews: bool = False, exclude: np.ndarray | None = None
                           ) -> tuple[int, np.ndarray]:
    """Fill the DTM's holes (:func:`fill_windows`), write it and its fill mask; the number
    of filled cells and the filled blocks."""
    filled, mask = fill_windows(dtm, support, windows, exclude)
    write_windows(dtm_path, filled, windows, crs, overviews=overviews)
    codes = np.where(mask, MASK_FILLED, np.where(np.isfinite(filled), MASK_MEASURED,
                                                 MASK_NODATA)).astype(np.uint8)
    write_windows(mask_path, codes, windows, crs, dtype="uint8", nodata=MASK_NODATA,
                  overviews=overviews)
    n = int(mask.sum())
    log.info("DTM: %d cells filled by interpolation (%.1f %% of those with a value)", n,
             100.0 * n / max(int(np.isfinite(filled).sum()), 1))
    return n, filled


def read_windows(path: Path, windows: Windows) -> np.ndarray:
    """Band 1 of a raster on ``windows.grid`` (e.g. PDAL's), as ``(windows, size, size)``
    float64 blocks with NaN for nodata."""
    rasterio = rasterio_module()
    from rasterio.windows import Window

    out = windows.blocks()
    with rasterio.open(path) as src:
        for slot in range(windows.ids.size):  # a loop over windows
            r0, c0, nr, nc = windows.clip(slot)
            a = src.read(1, window=Window(c0, r0, nc, nr), masked=True)
            a = np.ma.filled(a.astype(np.float64), np.nan)
            a[(a == NODATA) | ~np.isfinite(a)] = np.nan
            out[slot, :nr, :nc] = a
    return out
