"""CLI command ``rasters``: airborne lidar tiles to DTM / DSM-max / DSM-p90 GeoTIFFs."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from .progress_bars import progress_bar, summary
from .sources import SurveySource

log = logging.getLogger(__name__)


@click.command("rasters")
@click.argument("las", nargs=-1, required=True, type=SurveySource())
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Output folder: dtm.tif, dsm_max.tif, dsm_p90.tif and dtm_fill_mask.tif "
                   "(1 where a DTM hole was filled).")
@click.option("--resolution", type=float, default=2.0, show_default=True,
              help="Cell size in metres.")
@click.option("--crs", default=None,
              help="Output CRS (metric, e.g. EPSG:32612, the track's UTM zone); tiles in "
                   "another CRS are reprojected, tiles without a CRS are read as this one. "
                   "Default: the tiles' CRS.")
@click.option("--bounds", nargs=4, type=float, default=None,
              metavar="MINX MINY MAXX MAXY",
              help="Area to rasterise, metres in the output CRS (default: all tiles).")
@click.option("--polygon", type=click.Path(dir_okay=False), default=None,
              help="Area to rasterise: a WKT polygon (in the output CRS), or a "
                   "GeoPackage/GeoJSON/shapefile of polygons (reprojected to the output CRS "
                   "from its own); cells whose centre is outside are nodata.")
@click.option("--backend", type=click.Choice(["serial", "processes", "dask"]),
              default="processes", show_default=True,
              help="Where the tiles are read: here, on local processes or on Dask.")
@click.option("--workers", type=click.IntRange(1, 512), default=None,
              help="Processes or local Dask workers (default: the machine's cores).")
@click.option("--scheduler", default=None,
              help="Address of a running Dask scheduler (tcp://host:8786).")
@click.option("--smrf", is_flag=True,
              help="Classify ground with PDAL's SMRF instead of using the files' class 2.")
@click.option("--pdal", "pdal_exe", default=None, type=click.Path(dir_okay=False),
              help="The pdal executable (default: $CANOPYBLOCKS_PDAL, PATH, "
                   "/opt/canopyblocks-pdal/bin/pdal).")
@click.pass_context
def rasters_cmd(ctx: click.Context, las: tuple[str, ...], out_dir: str, resolution: float,
                crs: str | None, bounds: tuple[float, float, float, float] | None,
                polygon: str | None, backend: str, workers: int | None,
                scheduler: str | None, smrf: bool, pdal_exe: str | None) -> None:
    """Make the reference rasters (DTM, DSM max, DSM 90th percentile) on one grid
    from LAS/LAZ tiles or folders of them, tile by tile.

    A cell's value uses the points within resolution*sqrt(2)/2 of its centre: mean of
    ground points (DTM), max and 90th percentile of all non-noise points (DSMs).  Each
    tile is read once, on the local cores (or a Dask cluster); cells on tile edges see
    the points of every tile around them.
    """
    from ..atomic import check_writable, new_files_removed_on_failure
    from ..workflows.rasters import make_survey_rasters, read_polygon

    check_writable(out_dir, folder=True)
    quiet = bool((ctx.obj or {}).get("quiet", False))
    with new_files_removed_on_failure(out_dir), progress_bar("rasters", quiet=quiet) as progress:
        result = make_survey_rasters(
            list(las), Path(out_dir), resolution=resolution, crs=crs,
            bounds=bounds or None, polygon=read_polygon(polygon, crs=crs, tiles=las),
            ground="smrf" if smrf else "class2", pdal=pdal_exe, backend=backend,
            workers=workers, scheduler=scheduler, progress=progress)
    g = result.grid
    summary(f"grid: {g.width} x {g.height} cells of {g.resolution:g} m, "
            f"bounds {g.bounds}, CRS {result.crs_label}", err=False)
    for path in (result.dtm, result.dsm_max, result.dsm_p90, result.dtm_fill_mask):
        if path is not None:
            summary(str(path), err=False)
    filled = result.stats.get("dtm_filled")
    if filled:
        summary(f"DTM: {filled:,} empty cells filled (marked in dtm_fill_mask.tif)", err=False)
    bare = result.stats.get("dtm_unsupported")
    if bare:
        summary(f"DTM: {bare:,} cells of tiles without ground points left empty (not "
                "interpolated)", err=False)


def register(group: click.Group) -> None:
    """Add this module's commands to ``group``."""
    group.add_command(rasters_cmd)
