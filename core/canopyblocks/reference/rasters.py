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
from pathlib import Path
from typing import Any, cast

import numpy as np
import pyproj

from ..atomic import atomic_output
from ..errors import (
    CanopyBlocksWarning,
    CoverageError,
    FileFormatError,
    InputError,
    NoUsableDataError,
    PdalError,
)
from ..progress import Progress, as_progress
from ..readers.cloud_checks import warn_if_normalised
from ..readers.las import as_area
from ..readers.las_header import check_header_extent
from .dtm_fill import fill_and_write_windows, groundless_cells, read_windows, write_windows
from .pdal import (
    expand_readers,
    find_pdal,
    insert_after_readers,
    load_pipeline,
    run_pipeline,
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
from .raster_plan import _names, cloud_plan, las_plan
from .raster_tiles import (
    Runner,
    TileResult,
    cloud_kind,
    merge_windows,
    serial_runner,
    tile_surfaces,
)
from .raster_windows import SparseGrids, Windows

__all__ = ["NODATA", "Grid", "RasterParams", "ReferenceRasters", "make_reference_rasters",
           "check_tile_crs", "crs_label"]

log = logging.getLogger(__name__)

_SMRF_BUFFER = 20.0  # metres of extra context around the grid for SMRF's morphology
_MAX_CELLS = 100_000_000


def _intersects(a: Sequence[float], b: Sequence[float]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def make_reference_rasters(
    las_paths: Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    resolution: float = 2.0,
    crs: object = None,
    bounds: Sequence[float] | None = None,
    polygon: object = None,
    ground: GroundMethod = "class2",
    pdal: str | os.PathLike[str] | None = None,
    progress: Progress | None = None,
    runner: Runner | None = None,
) -> ReferenceRasters:
    """Write ``out_dir/dtm.tif``, ``dsm_max.tif``, ``dsm_p90.tif`` and the fill mask.

    The tiles are read tile by tile, each once (:mod:`~canopyblocks.reference.raster_tiles`):
    memory holds one tile's points (per worker) and the pairs of the cells on tile edges,
    never the survey's points; the values equal one computation over all points.

    Parameters
    ----------
    las_paths : sequence of path
        LAS/LAZ tiles (one or many, adjacent or overlapping); tiles whose header extent
        misses the area are skipped without reading their points.
    out_dir : path
        Output folder (created).  Files appear only when all are complete.
    resolution : float
        Cell size, metres (default 2).
    crs : CRS-like, optional
        Output CRS (metric, projected; e.g. the track's UTM zone).  Tiles in another CRS
        are reprojected horizontally (z unchanged).  Tiles without a CRS are read as being
        in ``crs``.  Default: the tiles' common CRS.
    bounds : (minx, miny, maxx, maxy), optional
        Area to rasterise, metres in the output CRS; snapped outward to the resolution.
        Default: the union of the tiles' extents.
    polygon : shapely geometry or WKT, optional
        Area to rasterise (output CRS): cells whose centre lies outside are nodata, and
        only points within the cell radius of it are used (a corridor, a study area).
    ground : {"class2", "smrf"}
        DTM from the files' ground class 2, or from ground points classified by PDAL's
        SMRF (then PDAL makes the DTM over the area in one pipeline).
    pdal : path, optional
        The pdal executable, for ``ground="smrf"`` only.
    progress : Progress, optional
    runner : callable, optional
        ``runner(fn, units, done)`` running the per-tile units (default: one after the
        other here; ``workflows.rasters`` passes the process pool or Dask).

    Returns
    -------
    ReferenceRasters

    Raises
    ------
    CRSError
        A tile without a CRS (and no ``crs``), a tile in feet, tiles in different CRSs
        without ``crs``, a non-metric output CRS.
    CoverageError
        ``bounds``/``polygon`` do not overlap the tiles, or no point lies in the grid.
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
    area_poly = as_area(polygon, "make_reference_rasters: polygon")
    smrf = params.ground == "smrf"
    exe = find_pdal(pdal) if smrf else None
    prog.update(0.0, "reading tile headers")
    kind = cloud_kind(las_paths[0]) if len(las_paths) == 1 else None
    if kind is None and any(cloud_kind(p) == "ept" or (cloud_kind(p) and "://" in str(p))
                            for p in las_paths):  # local COPC files among tiles: LAZ tiles
        raise InputError("a remote COPC or an EPT source is read alone: give it without "
                         "other tiles or sources (or merge them first)")
    plan = (cloud_plan(str(las_paths[0]), kind, params, crs, area_poly) if kind is not None
            else las_plan(paths, params, crs, area_poly, exe))
    units, grid, names, target = plan.units, plan.grid, plan.names, plan.target
    windows = plan.windows if plan.windows is not None else Windows.over(grid)
    results = _run(units, runner, prog.sub(0.02, 0.8))
    _check_tally(results, params, names)
    read = [(r.path, r.n_points, r.n_ground, u.box) for r, u in zip(results, units)]
    surf = merge_windows(results, windows, ground=not smrf)
    del results
    if area_poly is not None:
        surf.mask_outside(area_poly)
    if not np.isfinite(surf.top).any():
        raise CoverageError(f"no point of {names} lies in the grid {_fmt(grid.bounds)} "
                            f"({crs_label(target)}); check the bounds and the CRS")
    out_crs = plan.out_crs
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stats: dict[str, Any] = {"tiles_read": len(units), "tiles": len(paths), "units": len(units),
                             "windows": int(windows.ids.size)}
    if kind is not None:
        stats["tiles_read"], stats["tiles"] = 0, 0
    whole = area_poly is None  # a whole survey's rasters get overviews
    with contextlib.ExitStack() as stack:
        dtm_path = stack.enter_context(atomic_output(out / "dtm.tif"))
        max_path = stack.enter_context(atomic_output(out / "dsm_max.tif"))
        p90_path = stack.enter_context(atomic_output(out / "dsm_p90.tif"))
        mask_path = stack.enter_context(atomic_output(out / "dtm_fill_mask.tif"))
        if smrf:
            assert exe is not None
            used = [u.path for u in units]
            _smrf_dtm(used, plan.checked, [Path(p) for p in used], paths, grid, target,
                      plan.reprojected, exe, dtm_path, prog.sub(0.8, 0.9))
            surf.dtm = read_windows(dtm_path, windows)
            if area_poly is not None:
                surf.mask_outside(area_poly)
        stats.update(_check_outputs(surf, grid, params, paths))
        bare = None if smrf or kind is not None else groundless_cells(read, windows, surf.dtm)
        stats["dtm_unsupported"] = 0 if bare is None else int(bare.sum())
        stats["dtm_filled"], _ = fill_and_write_windows(dtm_path, mask_path, surf.dtm,
                                                        np.isfinite(surf.top), windows,
                                                        out_crs, overviews=whole, exclude=bare)
        prog.update(0.86, "dtm done, its holes filled")
        write_windows(max_path, surf.top, windows, out_crs, overviews=whole)
        prog.update(0.92, "dsm_max done")
        write_windows(p90_path, surf.p90, windows, out_crs, overviews=whole)
        prog.update(0.97, "dsm_p90 done")
    log.info("reference rasters in %s: %s", out, stats)
    prog.report(1.0, "done")  # outputs are committed: too late to cancel
    return ReferenceRasters(dtm=out / "dtm.tif", dsm_max=out / "dsm_max.tif",
                            dsm_p90=out / "dsm_p90.tif", grid=grid, crs=out_crs,
                            tiles=() if kind is not None else tuple(paths),
                            ground=params.ground, pdal_version=plan.pdal_version,
                            dtm_fill_mask=out / "dtm_fill_mask.tif", stats=stats)


def _run(units: list[Any], runner: Runner | None, prog: Progress) -> list[TileResult]:
    """The units through ``runner`` with progress per tile and cancellation."""
    n = len(units)
    count = [0]

    def done(res: TileResult) -> None:
        count[0] += 1
        prog.report(count[0] / n, f"tile {count[0]} of {n}: {Path(res.path).name}")

    prog.update(0.0, f"reading {n} tile(s)")
    run = runner or serial_runner
    if run is serial_runner:
        def checked(unit: Any) -> TileResult:
            prog.check()
            return tile_surfaces(unit)
        results = run(checked, units, done)
    else:
        results = run(tile_surfaces, units, done)
    prog.check()  # a pool stopped by a cancellation returns what it had
    return cast("list[TileResult]", results)


def _check_tally(results: list[TileResult], params: RasterParams, names: str) -> None:
    """The checks a survey's points must pass, from the units' tallies."""
    for r in results:
        r.heights.check(r.path)
        if r.n_points and (not check_header_extent(r.path, r.header_bounds, r.bounds,
                                                   tolerance=max(params.resolution, 1.0))
                           or r.n_points != r.header_count):
            warnings.warn(
                f"tile {r.path}: its header says {r.header_count} points in "
                f"{_fmt(r.header_bounds)}, its points are {r.n_points} in "
                f"{_fmt(r.bounds)}; using the points (the header is wrong: rewrite the file "
                "with a LAS tool to fix it)", CanopyBlocksWarning, stacklevel=4)
    if sum(r.n_points for r in results) == 0:
        raise NoUsableDataError(f"the tiles {names} hold no points")
    if all(r.n_points == r.n_noise for r in results):
        raise NoUsableDataError(
            f"every point of {names} is classed noise (ASPRS class 7 or 18), which the rasters "
            "exclude; reclassify the tiles (e.g. PDAL filters.outlier only on real outliers)")
    if params.ground == "class2" and sum(r.n_ground for r in results) == 0:
        raise NoUsableDataError(
            f"no point of {names} is classed ground (ASPRS class 2): the tiles are "
            "unclassified; use ground='smrf' (--smrf) to classify the ground first")


def _smrf_dtm(used: list[str], checked: list[tuple[pyproj.CRS, bool]], used_paths: list[Path],
              paths: list[Path], grid: Grid, target: pyproj.CRS, reproject: bool, exe: Path,
              dtm_path: Path, prog: Progress) -> None:
    """The SMRF DTM by PDAL over the tiles that meet the area (20 m of context)."""
    by_path = {str(p): c for p, c in zip(paths, checked)}
    tiles: list[tuple[str | os.PathLike[str], str | None]] = [
        (p, by_path[p][0].to_wkt() if by_path[p][1] else None) for p in used]
    b = grid.bounds
    buf = grid.radius + _SMRF_BUFFER
    with tempfile.TemporaryDirectory(prefix="canopyblocks-pdal-") as tmp:
        stages = expand_readers(load_pipeline("dtm_smrf"), tiles)
        if reproject:
            stages = insert_after_readers(stages, {"type": "filters.reprojection",
                                                   "out_srs": target.to_wkt()})
        pipe = write_pipeline(stages, Path(tmp) / "dtm_smrf.json")
        try:
            run_pipeline(pipe, {"filters.crop.bounds": f"([{b[0] - buf!r},{b[2] + buf!r}],"
                                                       f"[{b[1] - buf!r},{b[3] + buf!r}])",
                                "writers.gdal.filename": dtm_path, **grid.writer_options()},
                         pdal=exe, progress=prog)
        except PdalError as exc:
            if "no points" in str(exc):
                raise NoUsableDataError(f"no ground point of {_names(used_paths)} in the "
                                        f"grid {_fmt(grid.bounds)}") from None
            if "readers.las" in str(exc):
                raise FileFormatError(f"PDAL could not read the tiles {_names(used_paths)}: "
                                      f"{exc}; check that they are complete LAS/LAZ "
                                      "files") from None
            raise


def _check_outputs(surf: SparseGrids, grid: Grid, params: RasterParams,
                   paths: list[Path]) -> dict[str, Any]:
    """Refuse empty rasters with a clear message; return valid-cell counts."""
    measured = np.isfinite(surf.dtm)
    counts = {"dtm": int(measured.sum()), "dsm_max": int(np.isfinite(surf.top).sum()),
              "cells": grid.width * grid.height, "cells_held": surf.windows.n_cells}
    if counts["dsm_max"] == 0:
        raise CoverageError(f"no point of {', '.join(map(str, paths))} lies in the grid "
                            f"{_fmt(grid.bounds)}; check the bounds/CRS")
    if counts["dtm"] == 0:
        hint = ("; the files may be unclassified: use ground='smrf' (--smrf)"
                if params.ground == "class2" else "")
        raise NoUsableDataError(f"no ground point of {', '.join(map(str, paths))} in the "
                                f"grid {_fmt(grid.bounds)}{hint}")
    ground = surf.dtm[measured].astype(np.float32)  # as the file holds them
    warn_if_normalised(ground, np.full(ground.size, 2), ", ".join(map(str, paths)))
    return counts
