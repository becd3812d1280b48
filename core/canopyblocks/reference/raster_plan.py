"""Which units make a survey's rasters: the grid, the tiles (or windows) and the CRS.

:func:`las_plan` reads the tiles' headers (laspy; PDAL only for SMRF), checks their CRSs,
chooses the one grid (the union of the tiles' extents, or the bounds/polygon) and makes one
unit per tile that meets it; :func:`cloud_plan` does the same for one COPC file or EPT
dataset (its header's extent; units are windows of the grid, read by their bounds).
"""

from __future__ import annotations

import logging
import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from ..errors import (
    CanopyBlocksWarning,
    CoverageError,
    CRSError,
    FileFormatError,
    InputError,
    NoUsableDataError,
)
from ..geo import require_ground_metres, require_metric_crs
from ..readers.las_header import check_header_extent, check_las_file
from ..readers.las_summary import LasSummary, las_summary
from ..readers.tile_checks import check_survey_tiles
from .pdal import TileInfo, tile_info
from .raster_grid import (
    Grid,
    RasterParams,
    authority_crs,
    check_tile_crs,
    crs_label,
)
from .raster_grid import fmt_bounds as _fmt
from .raster_grid import horizontal_crs as _horizontal
from .raster_tiles import TileUnit, cloud_reader, make_units, plausible_box, window_units
from .raster_windows import CORRIDOR_WINDOW, WINDOW, Windows

__all__ = ["Plan", "las_plan", "cloud_plan", "header_info"]

log = logging.getLogger(__name__)

_MAX_CELLS = 100_000_000


@dataclass(frozen=True)
class Plan:
    """The units of one raster run and what the rasters carry."""

    units: list[TileUnit]
    grid: Grid
    names: str
    target: pyproj.CRS
    out_crs: pyproj.CRS
    checked: list[tuple[pyproj.CRS, bool]]
    reprojected: bool
    pdal_version: str = ""
    windows: Windows | None = None


def _intersects(a: Sequence[float], b: Sequence[float]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _grid(area: Sequence[float], params: RasterParams, wkt: str, names: str,
          poly: Any = None) -> tuple[Grid, Windows]:
    """The grid over ``area`` and its windows that meet ``poly`` (all without one)."""
    grid = Grid.from_bounds(area, params.resolution, wkt)
    if poly is None or params.ground == "smrf":  # PDAL's SMRF raster is dense
        if grid.width * grid.height > _MAX_CELLS:
            raise InputError(f"the grid over {names} would have {grid.width:.3g} x "
                             f"{grid.height:.3g} cells at {params.resolution:g} m (limit "
                             f"{_MAX_CELLS:.0e}); use a coarser resolution or smaller bounds"
                             + ("" if poly is None else " (or the ground class, not SMRF)"))
    windows = Windows.over(grid, poly, WINDOW if poly is None else CORRIDOR_WINDOW)
    windows.check_size(names)
    log.info("grid %d x %d cells of %g m at (%.2f, %.2f), %d windows of %d x %d", grid.width,
             grid.height, grid.resolution, grid.origin_x, grid.origin_y, windows.ids.size,
             windows.size, windows.size)
    return grid, windows


def _under_tiles(poly: Any, boxes: np.ndarray, reach: float) -> Any:
    """The part of ``poly`` within ``reach`` of the tiles' boxes (None for None): the
    windows elsewhere along a corridor can hold no point."""
    if poly is None:
        return None
    import shapely

    b = boxes[np.isfinite(boxes).all(axis=1)]
    near = shapely.union_all(shapely.box(b[:, 0] - reach, b[:, 1] - reach, b[:, 2] + reach,
                                         b[:, 3] + reach))
    return shapely.intersection(poly, near)


def with_vertical(crs: pyproj.CRS) -> pyproj.CRS:
    """``crs`` with an "unknown" vertical part when it states none, as PDAL's rasters
    carried it: the datum rules see the heights' datum stated as unknown, and
    :func:`~canopyblocks.reference.raster_grid.authority_crs` names it "+ unknown height"."""
    if crs.is_compound:
        return crs
    return pyproj.CRS.from_wkt(
        f'COMPD_CS["unknown",{crs.to_wkt("WKT1_GDAL")},VERT_CS["unknown",'
        'VERT_DATUM["unknown",2005],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Up",UP]]]')


def _datum_tile(crss: Sequence[pyproj.CRS]) -> int:
    """The tile whose CRS the rasters declare, whatever the tiles' order: the first stating
    a vertical datum (those stating one agree: checked), else the first."""
    for i, c in enumerate(crss):  # a loop over tiles' CRSs
        if c.is_compound and any(s.is_vertical and s.name.lower() not in ("unknown", "")
                                 for s in c.sub_crs_list):
            return i
    return 0


def las_plan(paths: list[Path], params: RasterParams, crs: object, area_poly: Any,
             exe: Path | None) -> Plan:
    """One unit per LAS/LAZ tile meeting the grid (``exe``: PDAL, for SMRF's CRS reading)."""
    infos = [tile_info(p, pdal=exe) if exe is not None else header_info(p) for p in paths]
    infos = [_fix_broken_header(i, params.resolution) for i in infos]
    names = _names(paths)
    target_in = None if crs is None else require_ground_metres(crs, "output crs")
    checked = [check_tile_crs(i, target_in) for i in infos]
    tile_crss = [c for c, _ in checked]
    target = _target_crs(infos, tile_crss, target_in)
    check_survey_tiles([(i.path, i.bounds) for i in infos if i.n_points > 0],
                       max(params.resolution, 1.0))  # headers vs first points, datums
    src_wkts = [None if _horizontal(c).equals(_horizontal(target), ignore_axis_order=True)
                else _horizontal(c).to_wkt() for c in tile_crss]
    boxes = _boxes(infos, tile_crss, target)
    live = [b for b, i in zip(boxes, infos) if i.n_points > 0]
    if not live:
        raise NoUsableDataError(f"the tiles {names} hold no points")
    arr = np.asarray(live)
    if area_poly is not None:  # the union of the tiles that meet the area, so that a run
        # over a survey has the grid of a run given only the tiles under its area
        import shapely

        meets = shapely.intersects(area_poly, shapely.box(arr[:, 0], arr[:, 1], arr[:, 2],
                                                          arr[:, 3]))
        arr = arr[meets] if meets.any() else arr
    union = (float(arr[:, 0].min()), float(arr[:, 1].min()), float(arr[:, 2].max()),
             float(arr[:, 3].max()))
    tol = max(params.resolution, 1.0)
    try:
        grid, windows = _grid(_area(params.bounds, area_poly, union, target), params,
                              target.to_wkt(), names,
                              _under_tiles(area_poly, np.asarray(live), tol + params.resolution))
    except InputError:
        _blame_headers(infos, tol)  # a header grown by a corrupt max x: named, not the grid
        raise
    wide = [(b[0] - tol, b[1] - tol, b[2] + tol, b[3] + tol) for b in boxes]
    area_wkb = None if area_poly is None else area_poly.buffer(grid.radius).wkb
    units = make_units(paths, wide, grid, src_wkts=src_wkts,
                       dst_wkt=_horizontal(target).to_wkt(), area_wkb=area_wkb,
                       ground=params.ground != "smrf")
    if not units:
        raise CoverageError(f"no tile of {names} meets the area {_fmt(grid.bounds)} "
                            f"({crs_label(target)}); check the bounds and the CRS")
    # the tiles' own CRS as their header states it (with its vertical part), or the
    # output CRS as given when tiles were reprojected
    reprojected = any(w is not None for w in src_wkts)
    assigned = tile_crss[0] is target_in  # a tile without a CRS, read as the given one
    out_crs = authority_crs(target if reprojected or assigned
                            else with_vertical(tile_crss[_datum_tile(tile_crss)]))
    return Plan(units, grid, names, target, out_crs, checked, reprojected,
                infos[0].pdal_version, windows)


def cloud_plan(source: str, kind: str, params: RasterParams, crs: object,
               area_poly: Any) -> Plan:
    """Windows of the grid over one COPC file or EPT dataset (read by their bounds)."""
    if params.ground == "smrf":
        raise InputError(f"SMRF needs LAS/LAZ tiles; {source} is a {kind.upper()} source: use "
                         "its ground class (the default)")
    extent_of, _ = cloud_reader(kind)
    ext = extent_of(source)
    given = None if crs is None else require_ground_metres(crs, "output crs")
    if ext.crs is None and given is None:
        raise CRSError(f"{ext.source} states no CRS; give its CRS (--crs, crs='EPSG:...')")
    target = require_metric_crs(given if given is not None else ext.crs,
                                f"CRS of {ext.source}")
    # another output CRS than the source's: windows read through the reprojecting reader
    moved = ext.crs is not None and not _horizontal(ext.crs).equals(_horizontal(target),
                                                                     ignore_axis_order=True)
    e0, e1, e2, e3 = ext.bounds
    bounds = ext.bounds if not moved else pyproj.Transformer.from_crs(
        _horizontal(ext.crs), _horizontal(target), always_xy=True).transform_bounds(
            e0, e1, e2, e3, densify_pts=21)
    if ext.n_points == 0:
        raise NoUsableDataError(f"{ext.source} holds no points")
    grid, windows = _grid(_area(params.bounds, area_poly, bounds, target), params,
                          target.to_wkt(), ext.source,
                          _under_tiles(area_poly, np.asarray([bounds], dtype=float),
                                       params.resolution))
    area_wkb = None if area_poly is None else area_poly.buffer(grid.radius).wkb
    units = window_units(source, kind, grid, bounds, area_wkb=area_wkb, ground=True,
                         crs_wkt=_horizontal(target).to_wkt() if moved or ext.crs is None
                         else None, moved=moved)
    if not units:
        raise CoverageError(f"{ext.source} does not meet the area {_fmt(grid.bounds)}")
    return Plan(units, grid, ext.source, target, authority_crs(target), [], False, "", windows)


def header_info(path: str | os.PathLike[str]) -> TileInfo:
    """A tile's count, extent and CRS from its header alone (laspy; no point is read).

    The same fields as :func:`~canopyblocks.reference.pdal.tile_info` without starting
    PDAL (which reads every point for its summary); ``crs_wkt`` is None (the CRS is read
    by :func:`~canopyblocks.reference.raster_grid.check_tile_crs`).
    """
    from ..readers.las_crs import _laspy

    p = Path(path)
    if not p.is_file():
        raise FileFormatError(f"point-cloud file {p} does not exist")
    check_las_file(p)
    try:
        with _laspy().open(p) as reader:
            h = reader.header
            n = int(h.point_count)
            bounds = (float(h.mins[0]), float(h.mins[1]), float(h.maxs[0]), float(h.maxs[1]))
            z_range = (float(h.mins[2]), float(h.maxs[2]))
    except FileFormatError:
        raise
    except Exception as exc:  # laspy raises several types on a damaged header
        raise FileFormatError(f"{p}: cannot read its header ({exc}); the file is damaged "
                              "or not LAS/LAZ") from None
    return TileInfo(path=p, n_points=n, bounds=bounds, z_range=z_range, crs_wkt=None,
                    horizontal_wkt=None, dimensions=(), pdal_version="")


def _trust_points(info: TileInfo, summary: LasSummary, resolution: float) -> TileInfo:
    """``info`` with the extent and count of the points when the header disagrees."""
    # a plausible header extent that disagrees with the points raises (it may be the
    # scale/offset that is corrupt); an impossible one (NaN, 1e300, swapped) is replaced
    agree = summary.n_points == 0 or check_header_extent(
        info.path, summary.header_bounds, summary.bounds, tolerance=max(resolution, 1.0))
    if not agree or summary.n_points != info.n_points:
        warnings.warn(
            f"tile {info.path}: its header says {info.n_points} points in "
            f"{_fmt(summary.header_bounds)}, its points are {summary.n_points} in "
            f"{_fmt(summary.bounds)}; using the points (the header is wrong: rewrite the file "
            "with a LAS tool to fix it)", CanopyBlocksWarning, stacklevel=3)
        return replace(info, bounds=summary.bounds, n_points=summary.n_points,
                       z_range=summary.z_range)
    return info



def _blame_headers(infos: Sequence[TileInfo], tolerance: float, suspects: int = 4) -> None:
    """On a grid too large: the tiles with the largest header extents checked against their
    points (one pass over each), so that a header stating a wider extent than its points
    (every point still inside it) is refused by name rather than the grid's size.

    Raises
    ------
    FileFormatError
        A tile whose header extent disagrees with its points by more than ``tolerance`` m.
    """
    area = np.array([(i.bounds[2] - i.bounds[0]) * (i.bounds[3] - i.bounds[1]) if
                     i.n_points > 0 else -1.0 for i in infos], dtype=float)
    for k in np.argsort(-area, kind="stable")[:suspects]:  # a loop over a few tiles
        if area[k] >= 0:
            summary = las_summary(infos[k].path)
            if summary.n_points:
                check_header_extent(infos[k].path, summary.header_bounds, summary.bounds,
                                    tolerance=tolerance)


def _names(paths: Sequence[Path]) -> str:
    """The tiles for a message: all of them when few, else the first and a count."""
    if len(paths) <= 4:
        return ", ".join(map(str, paths))
    return f"{paths[0]}, {paths[1]} and {len(paths) - 2} more"


def _fix_broken_header(info: TileInfo, resolution: float) -> TileInfo:
    """A tile whose header extent cannot be right, or which says it holds no point, gets its
    points' extent and count (one extra pass over that tile only), with the warning the
    header deserves."""
    if info.n_points > 0 and plausible_box(info.bounds):
        return info
    return _trust_points(info, las_summary(info.path), resolution)


def _target_crs(infos: list[TileInfo], tile_crss: list[pyproj.CRS],
                target_in: pyproj.CRS | None) -> pyproj.CRS:
    if target_in is not None:
        return target_in
    first = tile_crss[0]
    for info, c in zip(infos[1:], tile_crss[1:]):
        if not _horizontal(c).equals(_horizontal(first), ignore_axis_order=True):
            raise CRSError(f"tiles are in different CRSs: {infos[0].path} in "
                           f"{crs_label(first)}, {info.path} in {crs_label(c)}; give --crs "
                           "EPSG:XXXX (rasters; crs=... in Python) to reproject all of them "
                           "to one")
    return require_metric_crs(first, f"CRS of tile {infos[0].path}")


def _boxes(infos: list[TileInfo], crss: list[pyproj.CRS],
           target: pyproj.CRS) -> list[tuple[float, float, float, float]]:
    """Each tile's extent in the output CRS (an empty tile gets an empty far box)."""
    out: list[tuple[float, float, float, float]] = []
    for info, crs in zip(infos, crss):
        if info.n_points == 0:
            out.append((math.inf, math.inf, -math.inf, -math.inf))
            continue
        src = _horizontal(crs)
        if src.equals(_horizontal(target), ignore_axis_order=True):
            out.append(info.bounds)
        else:
            t = pyproj.Transformer.from_crs(src, _horizontal(target), always_xy=True)
            b = t.transform_bounds(*info.bounds, densify_pts=21)
            out.append((float(b[0]), float(b[1]), float(b[2]), float(b[3])))
    return out


def _area(bounds: tuple[float, float, float, float] | None, poly: Any,
          union: tuple[float, float, float, float],
          target: pyproj.CRS) -> tuple[float, float, float, float]:
    """The grid's area: the tiles' union, cut to the bounds and the polygon's box."""
    area = union
    for what, box in (("bounds", bounds), ("polygon", None if poly is None else poly.bounds)):
        if box is None:
            continue
        if not _intersects(box, area):
            raise CoverageError(
                f"the {what} {_fmt(box)} {'do' if what == 'bounds' else 'does'} not overlap "
                f"the tiles (their union is "
                f"{_fmt(union)} in {crs_label(target)}); give an area over the tiles, in "
                "the output CRS")
        area = (max(area[0], box[0]), max(area[1], box[1]), min(area[2], box[2]),
                min(area[3], box[3]))
    return bounds if bounds is not None and poly is None else area
