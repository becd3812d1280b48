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

Cells with no point in their circle are nodata (-9999); nothing is interpolated
(writers.gdal ``window_size=0``).  Rasters are float32 GeoTIFFs carrying the CRS.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import tempfile
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
import pyproj

from ..errors import (
    CanopyBlocksWarning,
    CoverageError,
    CRSError,
    DependencyError,
    FileFormatError,
    InputError,
    NoUsableDataError,
    PdalError,
)
from ..geo import as_crs, require_metre_units, require_metric_crs
from ..outputs.atomic import atomic_output
from ..progress import Progress, as_progress
from ..readers.cloud_checks import NormalisedCloudWarning, warn_if_normalised
from ..readers.las import read_las
from ..readers.las_header import check_header_extent
from ..readers.las_summary import LasSummary, las_summary
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

__all__ = ["NODATA", "Grid", "RasterParams", "ReferenceRasters", "make_reference_rasters",
           "check_tile_crs", "crs_label"]

log = logging.getLogger(__name__)

NODATA = -9999.0
GroundMethod = Literal["class2", "smrf"]
_SMRF_BUFFER = 20.0  # metres of extra context around the grid for SMRF's morphology
_MAX_CELLS = 100_000_000


@dataclass(frozen=True)
class Grid:
    """A north-up raster grid.

    Attributes
    ----------
    origin_x, origin_y : float
        West and **south** edges, metres (writers.gdal's origin is the lower-left corner).
    width, height : int
        Columns and rows.
    resolution : float
        Cell size, metres.
    crs_wkt : str
        The grid's CRS (WKT).
    """

    origin_x: float
    origin_y: float
    width: int
    height: int
    resolution: float
    crs_wkt: str

    def __post_init__(self) -> None:
        if not (self.width > 0 and self.height > 0):
            raise InputError(f"grid must have at least one cell, got {self.width} x {self.height}")
        if not (self.resolution > 0 and math.isfinite(self.resolution)):
            raise InputError(f"grid resolution must be > 0 m, got {self.resolution}")

    @classmethod
    def from_bounds(cls, bounds: Sequence[float], resolution: float, crs_wkt: str) -> Grid:
        """The smallest grid with edges on multiples of ``resolution`` covering ``bounds``."""
        minx, miny, maxx, maxy = (float(v) for v in bounds)
        x0 = math.floor(minx / resolution) * resolution
        y0 = math.floor(miny / resolution) * resolution
        width = max(1, math.ceil(round((maxx - x0) / resolution, 9)))
        height = max(1, math.ceil(round((maxy - y0) / resolution, 9)))
        return cls(x0, y0, int(width), int(height), float(resolution), crs_wkt)

    @property
    def top_y(self) -> float:
        """North edge, metres."""
        return self.origin_y + self.height * self.resolution

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(minx, miny, maxx, maxy)`` in metres."""
        return (self.origin_x, self.origin_y,
                self.origin_x + self.width * self.resolution, self.top_y)

    @property
    def transform(self) -> tuple[float, float, float, float, float, float]:
        """GDAL geotransform ``(x0, res, 0, top, 0, -res)``."""
        return (self.origin_x, self.resolution, 0.0, self.top_y, 0.0, -self.resolution)

    @property
    def radius(self) -> float:
        """The cell rule's radius, ``resolution * sqrt(2) / 2`` (metres)."""
        return self.resolution * math.sqrt(2.0) / 2.0

    def writer_options(self) -> dict[str, object]:
        """writers.gdal overrides putting PDAL's raster exactly on this grid."""
        return {
            "writers.gdal.resolution": self.resolution,
            "writers.gdal.radius": self.radius,
            "writers.gdal.origin_x": self.origin_x,
            "writers.gdal.origin_y": self.origin_y,
            "writers.gdal.width": self.width,
            "writers.gdal.height": self.height,
            "writers.gdal.nodata": NODATA,
        }


@dataclass(frozen=True)
class RasterParams:
    """Parameters of :func:`make_reference_rasters`, validated once.

    Attributes
    ----------
    resolution : float
        Cell size in metres (> 0).
    ground : {"class2", "smrf"}
        Ground points: the file's class 2, or re-classified by PDAL's SMRF.
    bounds : tuple of float or None
        ``(minx, miny, maxx, maxy)`` in the output CRS, metres.
    """

    resolution: float = 2.0
    ground: GroundMethod = "class2"
    bounds: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.resolution, (int, float)) and math.isfinite(self.resolution)
                and self.resolution > 0):
            raise InputError(f"resolution must be a positive number of metres, "
                             f"got {self.resolution!r}")
        if self.ground not in ("class2", "smrf"):
            raise InputError(f"ground must be 'class2' or 'smrf', got {self.ground!r}")
        if self.bounds is not None:
            b = tuple(float(v) for v in self.bounds)
            if len(b) != 4 or not all(math.isfinite(v) for v in b) or b[0] >= b[2] \
                    or b[1] >= b[3]:
                raise InputError(f"bounds must be (minx, miny, maxx, maxy) with min < max, "
                                 f"got {self.bounds!r}")
            object.__setattr__(self, "bounds", b)


@dataclass(frozen=True)
class ReferenceRasters:
    """The three rasters of one run and their shared grid."""

    dtm: Path
    dsm_max: Path
    dsm_p90: Path
    grid: Grid
    crs: pyproj.CRS
    tiles: tuple[Path, ...]
    ground: GroundMethod
    pdal_version: str = ""
    stats: dict[str, Any] = field(default_factory=dict, compare=False)

    @property
    def crs_label(self) -> str:
        """The horizontal CRS's name and EPSG code, for messages."""
        return crs_label(self.crs)


def check_tile_crs(info: TileInfo, assigned: pyproj.CRS | None) -> tuple[pyproj.CRS, bool]:
    """A tile's CRS, checked: metric horizontal and vertical units.

    Returns
    -------
    crs : pyproj.CRS
        The tile's CRS: PDAL's reading, else laspy's (PDAL 2.2 ignores GeoTIFF keys in
        LAS 1.4 files), else ``assigned``.
    override : bool
        True when PDAL did not see this CRS, so the pipeline must set it on the reader
        (``spatialreference``).

    Raises
    ------
    CRSError
        No CRS and nothing assigned; a CRS in feet (horizontal or vertical).
    """
    wkt, override = info.crs_wkt, False
    if wkt is None:
        wkt, override = _laspy_crs_wkt(info.path), True
        if wkt is not None:
            log.info("PDAL read no CRS in %s; using the one laspy finds in its header",
                     info.path)
    if wkt is None:
        if assigned is None:
            raise CRSError(f"tile {info.path} has no CRS; give the CRS its coordinates are in "
                           "(--crs EPSG:XXXX in rasters, crs=... in Python) or write it into "
                           "the file (pdal translate with writers.las.a_srs) for `run`")
        log.warning("tile %s has no CRS; reading it as %s (the given crs)", info.path,
                    assigned.to_string())
        return assigned, True
    crs = as_crs(wkt, f"CRS of tile {info.path}")
    require_metre_units(crs, f"tile {info.path}")
    return crs, override


def _laspy_crs_wkt(path: Path) -> str | None:
    """The CRS laspy finds in the header VLRs (PDAL 2.2 misses GeoTIFF keys in LAS 1.4)."""
    try:
        import laspy
        with laspy.open(path) as f:
            crs = f.header.parse_crs()
    except Exception:  # noqa: BLE001 - optional second opinion only
        return None
    return crs.to_wkt() if crs is not None else None


def _horizontal(crs: pyproj.CRS) -> pyproj.CRS:
    if crs.is_compound and crs.sub_crs_list:
        return crs.sub_crs_list[0]
    return crs


def crs_label(crs: pyproj.CRS) -> str:
    """A short name for messages: the horizontal CRS's name and EPSG code when known."""
    h = _horizontal(crs)
    code = h.to_epsg(min_confidence=70)
    return f"{h.name} (EPSG:{code})" if code else h.name


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


def _fmt(bounds: Sequence[float]) -> tuple[float, ...]:
    return tuple(round(float(v), 2) for v in bounds)


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
        if reproject:  # PDAL reprojects the points: two more PDAL passes
            try:
                run("dsm_max", {"filters.crop.bounds": crop(grid.radius),
                                "writers.gdal.filename": max_path, **grid.writer_options()},
                    prog.sub(0.45, 0.6))
            except PdalError as exc:
                if "no points" not in str(exc):
                    raise
                raise no_points from None
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
            _write_grid(max_path, top, grid, dtm_path)
            prog.update(0.9, "dsm_max done")
        dsm_crs = _write_grid(p90_path, p90, grid, dtm_path)
        prog.update(0.95, "dsm_p90 done")
        stats.update(_check_outputs(dtm_path, max_path, grid, params, paths))
    log.info("reference rasters in %s: %s", out, stats)
    prog.report(1.0, "done")  # outputs are committed: too late to cancel
    return ReferenceRasters(dtm=out / "dtm.tif", dsm_max=out / "dsm_max.tif",
                            dsm_p90=out / "dsm_p90.tif", grid=grid, crs=dsm_crs,
                            tiles=tuple(paths), ground=params.ground,
                            pdal_version=infos[0].pdal_version, stats=stats)


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


def _rasterio() -> Any:
    try:
        import rasterio
    except ImportError:
        raise DependencyError("writing reference rasters needs rasterio: "
                              "pip install 'canopyblocks[raster]'") from None
    return rasterio


def _write_grid(path: Path, values: np.ndarray, grid: Grid, like: Path) -> pyproj.CRS:
    """Write a (height, width) grid as a float32 GeoTIFF (nodata -9999) with the CRS PDAL
    wrote into ``like``, so all three rasters carry the same CRS."""
    rasterio = _rasterio()
    from rasterio.transform import Affine

    with rasterio.open(like) as src:
        crs = src.crs
        if (src.width, src.height) != (grid.width, grid.height):
            raise RuntimeError(f"PDAL wrote a {src.width} x {src.height} raster, expected "
                               f"{grid.width} x {grid.height}")
    data = np.where(np.isfinite(values), values, NODATA).astype(np.float32)
    profile = dict(driver="GTiff", width=grid.width, height=grid.height, count=1,
                   dtype="float32", nodata=NODATA, crs=crs,
                   transform=Affine.from_gdal(*grid.transform))
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data, 1)
    return pyproj.CRS.from_wkt(crs.to_wkt()) if crs is not None else as_crs(grid.crs_wkt)


def _check_outputs(dtm: Path, dsm: Path, grid: Grid, params: RasterParams,
                   paths: list[Path]) -> dict[str, Any]:
    """Refuse empty rasters with a clear message; return valid-cell counts."""
    rasterio = _rasterio()
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
