"""Survey rasters that stream: DTM mean, DSM max and DSM p90, tile by tile.

A survey is many tiles; a raster cell needs every point within the cell rule's radius
``r`` of its centre (:mod:`canopyblocks.reference.rasters`), which near a tile's edge may
lie in the neighbouring tile.  Each tile is one independent unit:

1. its points are read once, chunk by chunk (laspy), noise (7, 18) dropped, kept only
   within ``r`` of the grid (and of the area polygon, when one is given), reprojected
   horizontally when the output CRS differs;
2. every (cell, point) pair of the cell rule is made on the survey's one grid;
3. a cell whose circle's box meets no other tile's box (the tiles' header extents, in
   the output CRS, widened by the header tolerance) can hold points of this tile only:
   its DTM mean (class 2), maximum and 90th percentile are final and computed here;
4. the pairs of the other cells (a strip about ``r`` wide along the tile edges, a few per
   cent of the points) are returned, and the parent computes those cells from the pairs
   of every tile that met them.

So every cell is the whole-survey computation, exactly (same pairs, same
order-independent statistics), while no process holds more than one tile's points plus
the edge strips' pairs; units run serially, on local processes or on Dask
(:func:`~canopyblocks.workflows.backends.run_items` through ``run_units``), with the same
result.  Each unit also tallies what :func:`~canopyblocks.readers.las_summary.las_summary`
did (true extent, counts, heights on Earth, nothing beyond the header's count), so a tile is
decompressed once.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import FileFormatError
from ..readers.cloud_checks import HeightTally
from ..readers.las_header import (
    check_las_file,
    check_nothing_beyond_count,
    plausible_box,
    points_unreadable,
)
from .lidar_points import cell_groups, cell_neighbourhoods, max_and_percentile
from .raster_grid import Grid
from .raster_windows import SparseGrids, Windows, area_test

__all__ = ["TileUnit", "TileResult", "SurveyGrids", "tile_surfaces", "merge_tiles",
           "plausible_box", "cell_stats", "make_units", "serial_runner", "Runner",
           "cloud_kind", "cloud_reader", "window_units", "merge_windows"]

Box = tuple[float, float, float, float]
_CHUNK = 2_000_000
_NOISE = np.array([7, 18], dtype=np.uint8)


@dataclass(frozen=True)
class TileUnit:
    """One tile's work: its file, the grid, and the boxes it may share cells with.

    Attributes
    ----------
    path : str
    grid : Grid
        The survey's grid (output CRS).
    box : (minx, miny, maxx, maxy)
        This tile's box in the output CRS, metres (header extent, widened).
    neighbours : tuple of boxes
        The other tiles' boxes that come within ``2 r`` of ``box``.
    src_wkt, dst_wkt : str or None
        Horizontal CRSs when the points must be reprojected (else None).
    area_wkb : bytes or None
        The area polygon (output CRS) widened by ``r``: points outside are dropped.
    ground : bool
        Whether to compute the DTM mean (class 2) too.
    kind : {"las", "copc", "ept"}
        A LAS/LAZ tile, or a window of one cloud-optimised source (``path``).
    cells : (row0, row1, col0, col1) or None
        For a window: the grid cells it owns (half-open ranges); it reads the points
        within ``r`` of them and finishes exactly those cells.
    """

    path: str
    grid: Grid
    box: Box
    neighbours: tuple[Box, ...]
    src_wkt: str | None = None
    dst_wkt: str | None = None
    area_wkb: bytes | None = None
    ground: bool = True
    kind: str = "las"
    cells: tuple[int, int, int, int] | None = None


@dataclass(frozen=True)
class TileResult:
    """What one unit returns: its final cells, its shared pairs and its tally.

    ``cells``/``dtm``/``top``/``p90`` are the final values of the cells only this tile
    can reach (NaN DTM where no ground point); ``pair_cell``/``pair_z``/``pair_ground``
    the pairs of the shared cells.  ``bounds`` is the points' true extent (file CRS),
    ``header_bounds`` the header's, ``n_points``/``n_noise``/``n_ground`` all points.
    """

    path: str
    cells: np.ndarray
    dtm: np.ndarray
    top: np.ndarray
    p90: np.ndarray
    pair_cell: np.ndarray
    pair_z: np.ndarray
    pair_ground: np.ndarray
    n_points: int
    n_noise: int
    n_ground: int
    header_count: int
    bounds: Box
    header_bounds: Box
    heights: HeightTally


@dataclass
class SurveyGrids:
    """The merged (height, width) float64 grids; NaN where no value."""

    dtm: np.ndarray
    top: np.ndarray
    p90: np.ndarray


def cell_stats(cell: np.ndarray, z: np.ndarray, ground: np.ndarray, n_cells: int,
               with_ground: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cells and their DTM mean (ground pairs), maximum and 90th percentile.

    Returns
    -------
    cells : int64 array of the cells with at least one pair (sorted)
    dtm, top, p90 : float64 arrays aligned with ``cells`` (DTM NaN without ground)
    """
    if cell.size == 0:
        e = np.empty(0)
        return np.empty(0, np.int64), e, e, e
    uniq, inverse, top, p90 = cell_groups(cell, z, 90.0)
    dtm = np.full(uniq.size, np.nan)
    if with_ground and ground.any():
        g = ground.astype(bool)
        s = np.bincount(inverse[g], weights=z[g], minlength=uniq.size)
        n = np.bincount(inverse[g], minlength=uniq.size)
        has = n > 0
        dtm[has] = s[has] / n[has]
    return uniq, dtm, top, p90


def _shared(cells: np.ndarray, grid: Grid, neighbours: Sequence[Box]) -> np.ndarray:
    """Whether each cell's circle box meets one of ``neighbours`` (boxes, metres)."""
    col = cells % grid.width
    row = cells // grid.width
    cx = grid.origin_x + (col + 0.5) * grid.resolution
    cy = grid.top_y - (row + 0.5) * grid.resolution
    r = grid.radius
    out = np.zeros(cells.size, dtype=bool)
    for b in neighbours:  # a few boxes: a loop over tiles, vectorised over cells
        out |= (cx - r <= b[2]) & (cx + r >= b[0]) & (cy - r <= b[3]) & (cy + r >= b[1])
    return out


def _scaled_stats(cell: np.ndarray, zi: np.ndarray, ground: np.ndarray,
                  z_scale: tuple[float, float], with_ground: bool
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cell_stats` of ``zi * scale + offset`` from the file's integer heights: one
    sort of int64 keys (cell, height), no float sort (the same values: the heights are
    made by the same expression, and their order is the integers' when scale > 0)."""
    scale, offset = z_scale
    if cell.size == 0 or not scale > 0:
        return cell_stats(cell, zi * scale + offset, ground, 0, with_ground)
    lo, z0 = int(cell.min()), int(zi.min())
    span = int(zi.max()) - z0 + 1
    if (int(cell.max()) - lo + 1) * span >= 2 ** 62:
        return cell_stats(cell, zi * scale + offset, ground, 0, with_ground)
    key = np.sort((cell - lo) * span + (zi - z0))
    c, zs = np.divmod(key, span)
    v = (zs + z0) * scale + offset
    first = np.r_[True, c[1:] != c[:-1]]
    start = np.flatnonzero(first)
    uniq = c[start] + lo
    top, p90 = max_and_percentile(v, start, np.diff(np.r_[start, c.size]), 90.0)
    dtm = np.full(uniq.size, np.nan)
    if with_ground and ground.any():
        inverse = np.searchsorted(uniq, cell[ground])
        z = zi[ground] * scale + offset
        s = np.bincount(inverse, weights=z, minlength=uniq.size)
        n = np.bincount(inverse, minlength=uniq.size)
        has = n > 0
        dtm[has] = s[has] / n[has]
    return uniq, dtm, top, p90


def _shared_pairs(cell: np.ndarray, grid: Grid, neighbours: Sequence[Box]) -> np.ndarray:
    """Whether each pair's cell is shared (:func:`_shared`), decided once per cell of the
    pairs' row/column box."""
    if cell.size == 0 or not neighbours:
        return np.zeros(cell.size, dtype=bool)
    row, col = np.divmod(cell, grid.width)
    r0, c0 = int(row.min()), int(col.min())
    n_cols = int(col.max()) - c0 + 1
    rr, cc = np.divmod(np.arange((int(row.max()) - r0 + 1) * n_cols, dtype=np.int64), n_cols)
    box = _shared((rr + r0) * grid.width + cc + c0, grid, neighbours)
    return box[(row - r0) * n_cols + (col - c0)]


def _read_tile(unit: TileUnit) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The unit's kept points (x, y, z, ground) and the tile's tally, one pass."""
    from ..readers.las_crs import _laspy

    laspy = _laspy()
    check_las_file(unit.path)
    g = unit.grid
    r = g.radius
    gb = g.bounds
    lo = (gb[0] - r, gb[1] - r, gb[2] + r, gb[3] + r)
    transformer = None
    if unit.src_wkt is not None and unit.dst_wkt is not None:
        import pyproj

        transformer = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(unit.src_wkt),
                                                  pyproj.CRS.from_wkt(unit.dst_wkt),
                                                  always_xy=True)
    in_area = None
    if unit.area_wkb is not None:
        import shapely

        in_area = area_test(shapely.from_wkb(unit.area_wkb), unit.box, g.resolution)
    parts: dict[str, list[np.ndarray]] = {"x": [], "y": [], "zi": [], "g": []}
    heights = HeightTally()
    tally: dict[str, Any] = {"n": 0, "noise": 0, "ground": 0}
    ilo = np.full(2, np.iinfo(np.int64).max)
    ihi = np.full(2, np.iinfo(np.int64).min)
    try:
        with laspy.open(unit.path) as reader:
            h = reader.header
            scale = np.asarray(h.scales, float)
            offset = np.asarray(h.offsets, float)
            tally["header_bounds"] = (float(h.mins[0]), float(h.mins[1]),
                                      float(h.maxs[0]), float(h.maxs[1]))
            tally["header_count"] = int(h.point_count)
            for chunk in reader.chunk_iterator(_CHUNK):
                if len(chunk) == 0:
                    continue
                xi, yi, zi = (np.asarray(chunk[k]) for k in "XYZ")
                c = np.asarray(chunk.classification, dtype=np.uint8)
                ilo = np.minimum(ilo, [xi.min(), yi.min()])
                ihi = np.maximum(ihi, [xi.max(), yi.max()])
                heights.add_scaled(zi, c, float(scale[2]), float(offset[2]))
                noise = np.isin(c, _NOISE)
                tally["n"] += c.size
                tally["noise"] += int(noise.sum())
                tally["ground"] += int(np.count_nonzero(c == 2))
                x = xi * scale[0] + offset[0]
                y = yi * scale[1] + offset[1]
                if transformer is not None:
                    x, y = transformer.transform(x, y)
                    x, y = np.asarray(x), np.asarray(y)
                keep = ~noise & (x > lo[0]) & (x < lo[2]) & (y > lo[1]) & (y < lo[3])
                if in_area is not None and keep.any():
                    keep[keep] = in_area(x[keep], y[keep])
                parts["x"].append(x[keep])
                parts["y"].append(y[keep])
                parts["zi"].append(zi[keep])
                parts["g"].append(c[keep] == 2)
            check_nothing_beyond_count(reader, unit.path, tally["n"])
    except FileFormatError:
        raise
    except Exception as exc:  # laspy/lazrs raise several types on damaged data
        raise points_unreadable(unit.path, exc, int(tally.get("header_count", 0))) from None
    nan = float("nan")
    tally["bounds"] = ((float(ilo[0] * scale[0] + offset[0]), float(ilo[1] * scale[1] + offset[1]),
                        float(ihi[0] * scale[0] + offset[0]), float(ihi[1] * scale[1] + offset[1]))
                       if tally["n"] else (nan, nan, nan, nan))
    tally["heights"] = heights
    tally["z_scale"] = (float(scale[2]), float(offset[2])) if tally["n"] else (1.0, 0.0)
    pts = {k: (np.concatenate(v) if v else np.empty(0)) for k, v in parts.items()}
    return pts, tally


def cloud_kind(source: object) -> str | None:
    """``"copc"`` for a ``*.copc.laz`` path/URL, ``"ept"`` for an ``ept.json`` one, else None."""
    text = str(source).split("?", 1)[0].rstrip("/").lower()
    if text.endswith(".copc.laz"):
        return "copc"
    if text.endswith("/ept.json") or text == "ept.json":
        return "ept"
    return None


def cloud_reader(kind: str) -> tuple[Callable[..., Any], Callable[..., Any]]:
    """``(extent, read)`` of the COPC or EPT reader, imported when first needed."""
    from ..errors import DependencyError

    try:
        if kind == "copc":
            from ..readers.copc import copc_extent, read_copc
            return copc_extent, read_copc
        from ..readers.ept import ept_extent, read_ept
        return ept_extent, read_ept
    except ImportError as exc:
        raise DependencyError(f"reading a {kind.upper()} source needs canopyblocks' "
                              f"{kind} reader ({exc}); update canopyblocks") from None


def window_units(source: str, kind: str, grid: Grid, extent: Box, *, block: int = 512,
                 area_wkb: bytes | None, ground: bool, crs_wkt: str | None = None,
                 moved: bool = False) -> list[TileUnit]:
    """Units of ``block`` x ``block`` cells over the part of ``grid`` the source covers
    (``crs_wkt``: the grid's CRS, the source's when it states none (``src_wkt``) or the
    one its points are reprojected to with ``moved`` (``dst_wkt``))."""
    r = grid.radius
    res = grid.resolution
    c0 = max(0, math.floor((extent[0] - r - grid.origin_x) / res))
    c1 = min(grid.width, math.ceil((extent[2] + r - grid.origin_x) / res))
    r0 = max(0, math.floor((grid.top_y - extent[3] - r) / res))
    r1 = min(grid.height, math.ceil((grid.top_y - extent[1] + r) / res))
    area = None
    if area_wkb is not None:
        import shapely

        area = shapely.from_wkb(area_wkb)
        shapely.prepare(area)
    units = []
    for row in range(r0, r1, block):  # a loop over windows (a few per km2 of survey)
        for col in range(c0, c1, block):
            box = (grid.origin_x + col * res, grid.top_y - min(row + block, r1) * res,
                   grid.origin_x + min(col + block, c1) * res, grid.top_y - row * res)
            if area is not None and not area.intersects(shapely.box(*box)):
                continue  # a window the corridor does not meet: nothing to read
            units.append(TileUnit(path=source, grid=grid, box=box, neighbours=(),
                                  area_wkb=area_wkb, ground=ground, kind=kind,
                                  cells=(row, min(row + block, r1), col, min(col + block, c1)),
                                  src_wkt=None if moved else crs_wkt,
                                  dst_wkt=crs_wkt if moved else None))
    return units


def _window_surfaces(unit: TileUnit) -> TileResult:
    """A window of a COPC/EPT source: its points within ``r`` of its cells, its cells."""
    import shapely

    from ..errors import NoUsableDataError

    _, read = cloud_reader(unit.kind)
    g = unit.grid
    r = g.radius
    b = unit.box
    area = None if unit.area_wkb is None else shapely.from_wkb(unit.area_wkb)
    try:
        if unit.dst_wkt is not None:  # the source in another CRS: read into the grid's
            from ..readers.survey import read_survey

            pts = read_survey([unit.path], bbox=(b[0] - r, b[1] - r, b[2] + r, b[3] + r),
                              polygon=area, to_crs=unit.dst_wkt)
        else:
            pts = read(unit.path, bounds=(b[0] - r, b[1] - r, b[2] + r, b[3] + r),
                       polygon=area, crs=unit.src_wkt)
        x, y, z = (np.asarray(a, dtype=np.float64) for a in (pts.x, pts.y, pts.z))
        c = np.asarray(pts.classification, dtype=np.uint8)
    except NoUsableDataError:
        x = y = z = np.empty(0)
        c = np.empty(0, np.uint8)
    heights = HeightTally()
    heights.add(z, c)
    noise = np.isin(c, _NOISE)
    cell, idx = cell_neighbourhoods(x[~noise], y[~noise], origin_x=g.origin_x, top_y=g.top_y,
                                    resolution=g.resolution, width=g.width, height=g.height,
                                    radius=r)
    assert unit.cells is not None
    row, col = cell // g.width, cell % g.width
    r0, r1, c0, c1 = unit.cells
    mine = (row >= r0) & (row < r1) & (col >= c0) & (col < c1)
    zk, gk = z[~noise][idx[mine]], (c[~noise] == 2)[idx[mine]]
    cells, dtm, top, p90 = cell_stats(cell[mine], zk, gk, g.width * g.height, unit.ground)
    nan = float("nan")
    ext = ((float(x.min()), float(y.min()), float(x.max()), float(y.max())) if x.size
           else (nan, nan, nan, nan))
    e = np.empty(0)
    return TileResult(path=unit.path, cells=cells, dtm=dtm, top=top, p90=p90,
                      pair_cell=np.empty(0, np.int64), pair_z=e, pair_ground=np.empty(0, bool),
                      n_points=int(x.size), n_noise=int(noise.sum()),
                      n_ground=int(np.count_nonzero(c == 2)), header_count=int(x.size),
                      bounds=ext, header_bounds=ext, heights=heights)


def tile_surfaces(unit: TileUnit) -> TileResult:
    """One unit: read the tile, finish its own cells, return the shared pairs.

    Runs in a worker process; everything it needs is in ``unit`` (picklable).
    """
    if unit.kind != "las":
        return _window_surfaces(unit)
    pts, t = _read_tile(unit)
    g = unit.grid
    cell, idx = cell_neighbourhoods(pts["x"], pts["y"], origin_x=g.origin_x, top_y=g.top_y,
                                    resolution=g.resolution, width=g.width, height=g.height,
                                    radius=g.radius)
    zi = np.asarray(pts["zi"], dtype=np.int64)[idx]
    gr = pts["g"][idx].astype(bool)
    del pts, idx
    shared = _shared_pairs(cell, g, unit.neighbours)
    own = ~shared
    cells, dtm, top, p90 = _scaled_stats(cell[own], zi[own], gr[own], t["z_scale"],
                                         unit.ground)
    z_scale, z_offset = t["z_scale"]
    z = zi[shared] * z_scale + z_offset
    return TileResult(path=unit.path, cells=cells, dtm=dtm, top=top, p90=p90,
                      pair_cell=cell[shared], pair_z=z, pair_ground=gr[shared],
                      n_points=int(t["n"]), n_noise=int(t["noise"]),
                      n_ground=int(t["ground"]), header_count=int(t["header_count"]),
                      bounds=t["bounds"], header_bounds=t["header_bounds"],
                      heights=t["heights"])


def merge_tiles(results: Sequence[TileResult], grid: Grid, ground: bool) -> SurveyGrids:
    """The survey's grids from the units' own cells and their shared pairs."""
    shape = (grid.height, grid.width)
    out = SurveyGrids(dtm=np.full(grid.width * grid.height, np.nan),
                      top=np.full(grid.width * grid.height, np.nan),
                      p90=np.full(grid.width * grid.height, np.nan))
    for res in results:
        out.dtm[res.cells] = res.dtm
        out.top[res.cells] = res.top
        out.p90[res.cells] = res.p90
    pc = [r.pair_cell for r in results if r.pair_cell.size]
    if pc:
        cells, dtm, top, p90 = cell_stats(
            np.concatenate(pc), np.concatenate([r.pair_z for r in results if r.pair_cell.size]),
            np.concatenate([r.pair_ground for r in results if r.pair_cell.size]),
            grid.width * grid.height, ground)
        out.dtm[cells] = dtm
        out.top[cells] = top
        out.p90[cells] = p90
    return SurveyGrids(dtm=out.dtm.reshape(shape), top=out.top.reshape(shape),
                       p90=out.p90.reshape(shape))


def merge_windows(results: Any, windows: Windows, ground: bool) -> SparseGrids:
    """The sparse grids from the units' own cells and their shared pairs (the values of
    :func:`~canopyblocks.reference.raster_tiles.merge_tiles`, in windows)."""
    g = windows.grid
    out = SparseGrids(windows, windows.blocks(), windows.blocks(), windows.blocks())
    for res in results:
        out.assign(res.cells, res.dtm, res.top, res.p90)
    with_pairs = [r for r in results if r.pair_cell.size]
    if with_pairs:
        cells, dtm, top, p90 = cell_stats(
            np.concatenate([r.pair_cell for r in with_pairs]),
            np.concatenate([r.pair_z for r in with_pairs]),
            np.concatenate([r.pair_ground for r in with_pairs]), g.width * g.height, ground)
        out.assign(cells, dtm, top, p90)
    return out


def make_units(paths: Sequence[str | os.PathLike[str]], boxes: Sequence[Box], grid: Grid, *,
               src_wkts: Sequence[str | None], dst_wkt: str | None,
               area_wkb: bytes | None, ground: bool) -> list[TileUnit]:
    """One :class:`TileUnit` per tile whose box meets the grid widened by ``r``."""
    r = grid.radius
    gb = grid.bounds
    arr = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    units = []
    for i, (p, b) in enumerate(zip(paths, boxes)):
        if not (b[0] <= gb[2] + r and b[2] >= gb[0] - r and b[1] <= gb[3] + r
                and b[3] >= gb[1] - r):
            continue
        near = ((arr[:, 0] <= b[2] + 2 * r) & (arr[:, 2] >= b[0] - 2 * r)
                & (arr[:, 1] <= b[3] + 2 * r) & (arr[:, 3] >= b[1] - 2 * r))
        near[i] = False
        units.append(TileUnit(path=str(p), grid=grid, box=tuple(b),  # type: ignore[arg-type]
                              neighbours=tuple(tuple(map(float, arr[j]))  # type: ignore[misc]
                                               for j in np.flatnonzero(near)),
                              src_wkt=src_wkts[i], dst_wkt=dst_wkt if src_wkts[i] else None,
                              area_wkb=area_wkb, ground=ground))
    return units


def serial_runner(fn: Callable[[Any], Any], items: Sequence[Any],
                  done: Callable[[Any], None]) -> list[Any]:
    """Run the units one after the other here (the default; workflows pass a pool)."""
    out = []
    for it in items:
        out.append(fn(it))
        done(out[-1])
    return out


Runner = Callable[[Callable[[Any], Any], Sequence[Any], Callable[[Any], None]], list[Any]]
"""``runner(fn, items, done)``: results of ``fn`` over ``items`` in order, ``done`` called
with each as it completes (e.g. the process pool of ``workflows/backends``)."""
