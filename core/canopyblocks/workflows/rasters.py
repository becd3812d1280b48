"""Survey rasters: tiles (a list, a folder, a survey source) -> DTM, DSM max, DSM p90.

The one place the ``rasters`` command, ``run``/``validate`` and the QGIS algorithm make
reference rasters: the survey's tiles are listed (:func:`survey_tiles`), each tile is one
unit of :mod:`canopyblocks.reference.raster_tiles` run on the shared process pool
(:func:`~canopyblocks.workflows.backends.run_items`: serial, local processes, Dask) with
progress and Ctrl-C, and the results are the same whatever the backend.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..progress import Progress, as_progress
from ..reference.raster_grid import GroundMethod, ReferenceRasters

__all__ = ["CORRIDOR_MARGIN", "corridor_area", "make_survey_rasters", "pool_runner",
           "read_polygon", "survey_tiles"]

CORRIDOR_MARGIN = 30.0
"""Metres kept around a corridor's half-width: the co-registration search (+-15 m),
terrain slope and context for the DTM fill."""

def survey_tiles(sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]
                 ) -> list[Any]:
    """The point-cloud sources of a survey argument, the one resolver of every command:
    LAS/LAZ files as given, folders expanded (sorted), glob patterns expanded, a ``.vpc``
    as the tiles it names; a COPC file or EPT dataset (``*.copc.laz``, ``ept.json``; a
    path or an ``https://``/``s3://`` URL) as its string
    (:func:`~canopyblocks.readers.survey.survey_sources`).

    Raises
    ------
    InputError
        A folder or pattern holding no tile, or no source at all.
    """
    from ..readers.survey import survey_sources
    from ..readers.tile_checks import check_tile_headers, duplicate_tiles

    out = duplicate_tiles(survey_sources(sources))[0]  # the same points twice: once, warned
    check_tile_headers(out)  # a tile its header misplaces: refused by name, at every door
    return out


def corridor_area(blocks: Any, width: float, *, margin: float = CORRIDOR_MARGIN) -> Any:
    """The area of interest of a block table: the union of its tracks' corridors.

    Each track's (``track`` column) line through its block centres, in ``s_start`` order,
    buffered by half the corridor width, half the longest block and ``margin`` metres
    (the blocks' CRS).  Rasters and points are read over this area only, not over the
    track's bounding box.

    Returns
    -------
    shapely (Multi)Polygon, or None when no block has a finite centre.
    """
    import numpy as np
    import shapely

    x = np.asarray(blocks["x"], dtype=float)
    y = np.asarray(blocks["y"], dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        return None
    reach = 0.5 * float(width) + 0.5 * float(np.nanmax(blocks["length"])) + float(margin)
    tracks = (np.asarray(blocks["track"]).astype(str) if "track" in blocks
              else np.zeros(x.size, dtype=str))
    order = np.argsort(np.asarray(blocks["s_start"], dtype=float), kind="stable") \
        if "s_start" in blocks else np.arange(x.size)
    parts = []
    for t in np.unique(tracks[ok]):  # a loop over tracks, each a vectorised buffer
        sel = order[(tracks[order] == t) & ok[order]]
        xy = np.unique(np.c_[x[sel], y[sel]], axis=0) if sel.size < 2 else np.c_[x[sel], y[sel]]
        geom = shapely.LineString(xy) if len(xy) >= 2 else shapely.Point(xy[0])
        parts.append(geom.buffer(reach))
    return shapely.union_all(parts)


def read_polygon(value: str | os.PathLike[str] | None, *, crs: Any = None,
                 tiles: Sequence[Any] = ()) -> Any:
    """A polygon from WKT text, a file holding WKT, or a vector file (the union of its
    polygons), checked valid and in ``crs`` (default the CRS of the first LAS/LAZ tile of
    ``tiles``): a file in another CRS is reprojected, with a warning; None for None.

    Raises
    ------
    InputError
        Text that is neither WKT nor an existing file, a file without polygons, an
        invalid (e.g. self-intersecting) polygon.
    """
    if value is None:
        return None
    from .polygons import polygon_geometry

    if crs is None:
        from ..readers.las import las_crs
        from ..reference.raster_tiles import cloud_kind

        local = [t for t in (survey_tiles(tiles) if tiles else [])
                 if cloud_kind(t) is None and "://" not in str(t) and Path(t).is_file()]
        crs = las_crs(local[0]) if local else None
    return polygon_geometry(value, crs=crs)[0]


def pool_runner(backend: str = "processes", workers: int | None = None,
                scheduler: str | None = None,
                cancelled: Callable[[], bool] | None = None) -> Callable[..., list[Any]]:
    """A ``runner(fn, units, done)`` over the shared pool (serial for a single unit)."""
    from .backends import run_items

    def run(fn: Callable[[Any], Any], items: Sequence[Any],
            done: Callable[[Any], None]) -> list[Any]:
        chosen = "serial" if len(items) <= 1 or workers == 1 else backend
        return run_items(fn, items, backend=chosen,  # type: ignore[arg-type]
                         workers=workers, scheduler=scheduler, done=done, cancelled=cancelled)
    return run


def _metric_output(tiles: Sequence[Any]) -> Any:
    """None (the survey's own CRS) when its metre is a ground metre; else the UTM zone of
    its centre, with a warning: a Web Mercator survey's "2 m" cells would be 2 m of the
    projection (1.27 m on the ground at 50.7 N)."""
    import warnings

    from ..errors import CanopyBlocksWarning
    from .survey import working_crs

    own = _own_crs(tiles[0])
    utm = working_crs(tiles) if own is not None else None
    if utm is None or own.equals(utm, ignore_axis_order=True):
        return None
    warnings.warn(f"{tiles[0]} is in {own.name}, whose metre is not a metre on the ground: "
                  f"the rasters are made in {utm.name} (EPSG:{utm.to_epsg()}); give --crs "
                  "to choose another metric CRS", CanopyBlocksWarning, stacklevel=3)
    return utm.to_wkt()


def _own_crs(source: Any) -> Any:
    from ..readers.survey import source_crs

    return source_crs(source).horizontal


def make_survey_rasters(
    sources: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    resolution: float = 2.0,
    crs: object = None,
    bounds: Sequence[float] | None = None,
    polygon: object = None,
    ground: GroundMethod = "class2",
    pdal: str | os.PathLike[str] | None = None,
    backend: str = "processes",
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Progress | None = None,
) -> ReferenceRasters:
    """DTM, DSM max, DSM p90 and the fill mask over a survey's tiles, tile by tile.

    Parameters
    ----------
    sources : path or sequence of paths
        LAS/LAZ tiles and/or folders of them.
    out_dir : path
        Output folder.
    resolution, crs, bounds, polygon, ground, pdal
        As :func:`~canopyblocks.reference.rasters.make_reference_rasters` (metres, the
        output CRS).
    backend : {"processes", "serial", "dask"}
        Where the tiles are read (default local processes, one per core; a single tile
        runs here).
    workers : int, optional
        Processes or Dask workers (default: the machine's cores).
    scheduler : str, optional
        A running Dask scheduler's address (implies ``backend="dask"``).
    progress : Progress, optional
        Per tile; cancellation stops the pool and writes nothing.
    """
    from ..reference.rasters import make_reference_rasters

    prog = as_progress(progress)
    if scheduler is not None:
        backend = "dask"
    cancelled = prog.cancelled
    runner = pool_runner(backend, workers, scheduler, cancelled)
    tiles = survey_tiles(sources)
    if crs is None:
        crs = _metric_output(tiles)
    return make_reference_rasters(tiles, out_dir, resolution=resolution,
                                  crs=crs, bounds=bounds, polygon=polygon, ground=ground,
                                  pdal=pdal, progress=prog, runner=runner)
