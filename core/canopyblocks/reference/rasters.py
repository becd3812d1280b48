"""Reference rasters from airborne lidar tiles: DTM, DSM (max) and DSM (90th percentile).

All three rasters of one run share one grid (:class:`Grid`): the union of the tiles'
bounds (or the user's bounds) in the output CRS, snapped outward to multiples of the
resolution.  PDAL makes the DTM and the DSM-max (``dtm.json`` / ``dtm_smrf.json``,
``dsm_max.json``); PDAL has no percentile writer, so the DSM-p90 is computed here with
numpy from the points that ``points_for_p90.json`` read, cropped and reprojected.

Cell rule (the same for all three rasters)
------------------------------------------
A point counts for a cell when its horizontal distance to the cell centre is strictly
less than ``radius = resolution * sqrt(2) / 2`` (the circle through the cell's corners):
every point inside the cell counts, plus points in the slivers of the four neighbouring
cells that the circle covers.  This is PDAL writers.gdal's own rule (``radius`` option;
PDAL 2.2 has no ``binmode``); it was checked cell by cell against numpy on the sample
tiles (see ``tests/test_rasters.py``).  Then:

- ``dtm.tif``: **mean** z of the ground points (class 2; or the points SMRF classifies as
  ground) of the cell's circle (writers.gdal ``output_type=mean``);
- ``dsm_max.tif``: **max** z of all points except noise (classes 7 and 18);
- ``dsm_p90.tif``: **90th percentile** of the z of those same points, with
  :func:`numpy.percentile`'s default linear interpolation (``v[k] + (v[k+1] - v[k]) * f``
  with ``k + f = 0.9 * (n - 1)`` over the sorted values).

Cells with no point in their circle are nodata (-9999) in the DSMs (writers.gdal
``window_size=0``).  The DTM's cells that hold points but no ground point (under dense
canopy), and gaps enclosed by the survey, are then filled by harmonic interpolation and
marked in ``dtm_fill_mask.tif`` (:mod:`canopyblocks.reference.dtm_fill`).  Rasters are
float32 GeoTIFFs carrying the CRS with its authority codes
(:func:`~canopyblocks.reference.raster_grid.authority_crs`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import tempfile
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import numpy as np
import pyproj

from ..atomic import atomic_output
from ..errors import (
    CanopyBlocksWarning,
    CoverageError,
    CRSError,
    FileFormatError,
    InputError,
    NoUsableDataError,
    PdalError,
)
from ..geo import as_crs, require_metric_crs
from ..progress import Progress, as_progress
from ..readers.cloud_checks import NormalisedCloudWarning, warn_if_normalised
from ..readers.las import read_las
from ..readers.las_header import check_header_extent
from ..readers.las_summary import LasSummary, las_summary
from .dtm_fill import fill_and_write_dtm, grid_crs, rasterio_module, write_grid
from .lidar_points import (
    cell_max_and_percentile,
    cell_neighbourhoods,
    cell_percentile,
    read_points_csv,
)
from .pdal import (
    TileInfo,
    expand_readers,
    find_pdal,
    insert_after_readers,
    load_pipeline,
    run_pipeline,
    tile_info,
    write_pipeline,
)
from .raster_grid import (
    NODATA,
    Grid,
    GroundMethod,
    RasterParams,
    ReferenceRasters,
    check_tile_crs,
    crs_label,
)
from .raster_grid import fmt_bounds as _fmt
from .raster_grid import horizontal_crs as _horizontal

__all__ = ["NODATA", "Grid", "RasterParams", "ReferenceRasters", "make_reference_rasters",
           "check_tile_crs", "crs_label"]

log = logging.getLogger(__name__)

_SMRF_BUFFER = 20.0  # metres of extra context around the grid for SMRF's morphology
_MAX_CELLS = 100_000_000


def _union_bounds(infos: list[TileInfo], crss: list[pyproj.CRS],
                  target: pyproj.CRS) -> tuple[float, float, float, float]:
    boxes = []
    for info, crs in zip(infos, crss):
        if info.n_points == 0:
            continue
        src = _horizontal(crs)
        if src.equals(_horizontal(target), ignore_axis_order=True):
            boxes.append(info.bounds)
        else:
            t = pyproj.Transformer.from_crs(src, _horizontal(target), always_xy=True)
            boxes.append(t.transform_bounds(*info.bounds, densify_pts=21))
    arr = np.asarray(boxes, dtype=np.float64)
    return (float(arr[:, 0].min()), float(arr[:, 1].min()),
            float(arr[:, 2].max()), float(arr[:, 3].max()))


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


def _intersects(a: Sequence[float], b: Sequence[float]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def make_reference_rasters(
    las_paths: Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    resolution: float = 2.0,
    crs: object = None,
    bounds: Sequence[float] | None = None,
    ground: GroundMethod = "class2",
    pdal: str | os.PathLike[str] | None = None,
    progress: Progress | None = None,
) -> ReferenceRasters:
    """Write ``out_dir/dtm.tif``, ``dsm_max.tif`` and ``dsm_p90.tif`` on one grid.

    Parameters
    ----------
    las_paths : sequence of path
        LAS/LAZ tiles (one or several, adjacent or overlapping); all are merged into one
        PDAL run per raster, so cells on tile edges see the points of both tiles.
    out_dir : path
        Output folder (created).  Files appear only when all three are complete.
    resolution : float
        Cell size, metres (default 2).
    crs : CRS-like, optional
        Output CRS (metric, projected; e.g. the track's UTM zone).  Tiles in another CRS
        are reprojected by PDAL (filters.reprojection, horizontal only: z unchanged).
        Tiles without a CRS are read as being in ``crs``.  Default: the tiles' common CRS.
    bounds : (minx, miny, maxx, maxy), optional
        Area to rasterise, metres in the output CRS; snapped outward to the resolution.
        Default: the union of the tiles' bounds.
    ground : {"class2", "smrf"}
        DTM from the files' ground class 2, or from ground points classified by SMRF.
    pdal : path, optional
        The pdal executable (default :func:`~canopyblocks.reference.pdal.find_pdal`).
    progress : Progress, optional

    Returns
    -------
    ReferenceRasters

    Raises
    ------
    CRSError
        A tile without a CRS (and no ``crs``), a tile in feet, tiles in different CRSs
        without ``crs``, a non-metric output CRS.
    CoverageError
        ``bounds`` do not overlap the tiles, or no point lies in the grid.
    NoUsableDataError
        No ground point in the grid (try ``ground="smrf"``).
    PdalError, DependencyError, FileFormatError
    """
    from ..arguments import check_path, check_paths
    check_paths(
        las_paths, "make_reference_rasters: las_paths", "a LAS/LAZ path or a non-empty list of them"
    )
    check_path(out_dir, "make_reference_rasters: out_dir", "a folder path")
    # RasterParams.__post_init__ checks that bounds holds four finite, ordered numbers.
    box = None if bounds is None else cast("tuple[float, float, float, float]", tuple(bounds))
    params = RasterParams(resolution=float(resolution), ground=ground, bounds=box)
    prog = as_progress(progress)
    paths = [Path(p) for p in las_paths]
    if not paths:
        raise InputError("no LAS/LAZ tiles given")
    exe = find_pdal(pdal)
    prog.update(0.0, "reading tile headers")

    # the points, not the headers, say where a tile is and what it holds
    summaries = [las_summary(p) for p in paths]
    infos = [_trust_points(tile_info(p, pdal=exe), s, params.resolution)
             for p, s in zip(paths, summaries)]
    names = ", ".join(map(str, paths))
    if sum(i.n_points for i in infos) == 0:
        raise NoUsableDataError(f"the tiles {names} hold no points")
    if all(s.n_points == s.n_noise for s in summaries):
        raise NoUsableDataError(
            f"every point of {names} is classed noise (ASPRS class 7 or 18), which the rasters "
            "exclude; reclassify the tiles (e.g. PDAL filters.outlier only on real outliers)")
    if params.ground == "class2" and sum(s.n_ground for s in summaries) == 0:
        raise NoUsableDataError(
            f"no point of {names} is classed ground (ASPRS class 2): the tiles are "
            "unclassified; use ground='smrf' (--smrf) to classify the ground first")
    target_in = None if crs is None else require_metric_crs(as_crs(crs, "output crs"),
                                                            "output crs")
    checked = [check_tile_crs(i, target_in) for i in infos]
    tile_crss = [c for c, _ in checked]
    if target_in is None:
        first = tile_crss[0]
        for info, c in zip(infos[1:], tile_crss[1:]):
            if not _horizontal(c).equals(_horizontal(first), ignore_axis_order=True):
                raise CRSError(f"tiles are in different CRSs: {infos[0].path} in "
                               f"{crs_label(first)}, {info.path} in {crs_label(c)}; give --crs EPSG:XXXX (rasters; crs=... in Python) to "
                               "reproject all of them to one")
        target = require_metric_crs(first, f"CRS of tile {infos[0].path}")
    else:
        target = target_in
    reproject = target_in is not None and any(
        not _horizontal(c).equals(_horizontal(target), ignore_axis_order=True)
        for c in tile_crss)
    out_wkt = target.to_wkt()

    union = _union_bounds(infos, tile_crss, target)
    if params.bounds is not None:
        if not _intersects(params.bounds, union):
            raise CoverageError(
                f"the bounds {params.bounds} do not overlap the tiles (their union is "
                f"{_fmt(union)} in {crs_label(target)}); give bounds inside "
                "the tiles, in the output CRS")
        area = params.bounds
    else:
        area = union
    grid = Grid.from_bounds(area, params.resolution, out_wkt)
    if grid.width * grid.height > _MAX_CELLS:
        raise InputError(f"the grid over {names} would have {grid.width:.3g} x "
                         f"{grid.height:.3g} cells at {params.resolution:g} m (limit "
                         f"{_MAX_CELLS:.0e}); use a coarser resolution or smaller bounds")
    log.info("grid %d x %d cells of %g m at (%.2f, %.2f)", grid.width, grid.height,
             grid.resolution, grid.origin_x, grid.origin_y)

    tiles: list[tuple[str | os.PathLike[str], str | None]] = [
        (p, c.to_wkt() if override else None) for p, (c, override) in zip(paths, checked)]
    reproj_stage = {"type": "filters.reprojection", "out_srs": out_wkt}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stats: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="canopyblocks-pdal-") as tmpname, \
            contextlib.ExitStack() as stack:
        tmp = Path(tmpname)

        def run(name: str, options: dict[str, object], sub: Progress) -> None:
            try:
                run_pipeline(prepared(name), options, pdal=exe, progress=sub)
            except PdalError as exc:
                if "readers.las" not in str(exc):
                    raise
                raise FileFormatError(f"PDAL could not read the tiles "
                                      f"{', '.join(map(str, paths))}: {exc}; check that they "
                                      "are complete LAS/LAZ files") from None

        def prepared(name: str) -> Path:
            stages = expand_readers(load_pipeline(name), tiles)
            if reproject:
                stages = insert_after_readers(stages, reproj_stage)
            return write_pipeline(stages, tmp / f"{name}.json")

        def crop(buffer: float) -> str:
            b = grid.bounds
            return (f"([{b[0] - buffer!r},{b[2] + buffer!r}],"
                    f"[{b[1] - buffer!r},{b[3] + buffer!r}])")

        dtm_path = stack.enter_context(atomic_output(out / "dtm.tif"))
        max_path = stack.enter_context(atomic_output(out / "dsm_max.tif"))
        p90_path = stack.enter_context(atomic_output(out / "dsm_p90.tif"))
        mask_path = stack.enter_context(atomic_output(out / "dtm_fill_mask.tif"))

        smrf = params.ground == "smrf"
        no_points = CoverageError(
            f"no point of {names} lies in the grid {_fmt(grid.bounds)} "
            f"({crs_label(target)}); check the bounds and the CRS")
        try:
            run("dtm_smrf" if smrf else "dtm",
                {"filters.crop.bounds": crop(grid.radius + (_SMRF_BUFFER if smrf else 0.0)),
                 "writers.gdal.filename": dtm_path, **grid.writer_options()},
                prog.sub(0.05, 0.45 if smrf else 0.3))
        except PdalError as exc:
            if "no points" not in str(exc):
                raise
            raise NoUsableDataError(f"no ground point of {names} in the grid "
                                    f"{_fmt(grid.bounds)}"
                                    + ("" if smrf else "; the files may be unclassified: use "
                                       "ground='smrf' (--smrf)")) from None
        out_crs = grid_crs(dtm_path, grid)  # PDAL's CRS with its authority codes
        if reproject:  # PDAL reprojects the points: two more PDAL passes
            try:
                run("dsm_max", {"filters.crop.bounds": crop(grid.radius),
                                "writers.gdal.filename": max_path, **grid.writer_options()},
                    prog.sub(0.45, 0.6))
            except PdalError as exc:
                if "no points" not in str(exc):
                    raise
                raise no_points from None
            top = _read_band(max_path)
            pts_path = tmp / "points.csv"
            run("points_for_p90", {"filters.crop.bounds": crop(grid.radius),
                                   "writers.text.filename": pts_path},
                prog.sub(0.6, 0.75))
            prog.update(0.8, "90th percentile per cell")
            p90 = _p90_grid(pts_path, grid)
        else:  # one decode of the tiles: DSM max and p90 from the same neighbourhoods
            any_override = any(override for _, override in checked)
            top, p90 = _surfaces_from_tiles(paths, grid, _horizontal(target)
                                            if any_override else None, prog.sub(0.45, 0.9))
            if not np.isfinite(top).any():
                raise no_points
        write_grid(max_path, top, grid, out_crs)
        prog.update(0.9, "dsm_max done")
        write_grid(p90_path, p90, grid, out_crs)
        prog.update(0.93, "dsm_p90 done")
        stats.update(_check_outputs(dtm_path, max_path, grid, params, paths))
        stats["dtm_filled"] = fill_and_write_dtm(dtm_path, mask_path, np.isfinite(top), grid,
                                                 out_crs)
        prog.update(0.97, "DTM holes filled")
    log.info("reference rasters in %s: %s", out, stats)
    prog.report(1.0, "done")  # outputs are committed: too late to cancel
    return ReferenceRasters(dtm=out / "dtm.tif", dsm_max=out / "dsm_max.tif",
                            dsm_p90=out / "dsm_p90.tif", grid=grid, crs=out_crs,
                            tiles=tuple(paths), ground=params.ground,
                            pdal_version=infos[0].pdal_version,
                            dtm_fill_mask=out / "dtm_fill_mask.tif", stats=stats)


def _read_band(path: Path) -> np.ndarray:
    """Band 1 of a raster PDAL wrote, float64 with NaN for nodata."""
    with rasterio_module().open(path) as src:
        a = src.read(1).astype(np.float64)
    a[(a == NODATA) | ~np.isfinite(a)] = np.nan
    return a


def _surfaces_from_tiles(paths: list[Path], grid: Grid, crs: pyproj.CRS | None,
                         progress: Progress) -> tuple[np.ndarray, np.ndarray]:
    """DSM max and p90 (height, width) grids from one laspy decode of the tiles.

    The neighbourhood is PDAL writers.gdal's (points strictly within ``grid.radius`` of a
    cell centre) and noise classes 7/18 are left out, as in ``dsm_max.json`` and
    ``points_for_p90.json``: the values equal what those pipelines give.
    """
    r = grid.radius
    b = grid.bounds
    with warnings.catch_warnings():  # said once, from the DTM, by _check_outputs
        warnings.simplefilter("ignore", NormalisedCloudWarning)
        pts = read_las(paths, crs=crs, bbox=(b[0] - r, b[1] - r, b[2] + r, b[3] + r),
                       progress=progress.sub(0.0, 0.7))
    cell, idx = cell_neighbourhoods(pts.x, pts.y, origin_x=grid.origin_x, top_y=grid.top_y,
                                    resolution=grid.resolution, width=grid.width,
                                    height=grid.height, radius=r)
    progress.update(0.8, "maximum and 90th percentile per cell")
    top, p90 = cell_max_and_percentile(cell, pts.z[idx], grid.width * grid.height, 90.0)
    shape = (grid.height, grid.width)
    return top.reshape(shape), p90.reshape(shape)


def _p90_grid(points_csv: Path, grid: Grid) -> np.ndarray:
    """The (height, width) float64 p90 grid from the extracted points (NaN = empty)."""
    n_cells = grid.width * grid.height
    if not points_csv.exists():
        return np.full((grid.height, grid.width), np.nan)
    pts = read_points_csv(points_csv)
    cell, idx = cell_neighbourhoods(pts.x, pts.y, origin_x=grid.origin_x, top_y=grid.top_y,
                                    resolution=grid.resolution, width=grid.width,
                                    height=grid.height, radius=grid.radius)
    return cell_percentile(cell, pts.z[idx], n_cells, 90.0).reshape(grid.height, grid.width)


def _check_outputs(dtm: Path, dsm: Path, grid: Grid, params: RasterParams,
                   paths: list[Path]) -> dict[str, Any]:
    """Refuse empty rasters with a clear message; return valid-cell counts."""
    rasterio = rasterio_module()
    counts = {}
    for name, p in (("dtm", dtm), ("dsm_max", dsm)):
        with rasterio.open(p) as src:
            a = src.read(1)
            counts[name] = int(np.count_nonzero(a != NODATA))
    counts["cells"] = grid.width * grid.height
    if counts["dsm_max"] == 0:
        raise CoverageError(f"no point of {', '.join(map(str, paths))} lies in the grid "
                            f"{_fmt(grid.bounds)}; check the bounds/CRS")
    if counts["dtm"] == 0:
        hint = ("; the files may be unclassified: use ground='smrf' (--smrf)"
                if params.ground == "class2" else "")
        raise NoUsableDataError(f"no ground point of {', '.join(map(str, paths))} in the "
                                f"grid {_fmt(grid.bounds)}{hint}")
    with rasterio.open(dtm) as src:
        a = src.read(1)
    ground = a[a != NODATA]
    warn_if_normalised(ground, np.full(ground.size, 2), ", ".join(map(str, paths)))
    return counts
