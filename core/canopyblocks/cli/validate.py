"""CLI command ``validate``: block table vs reference rasters (or ATL08) -> residuals, stats."""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path

import click

from ..errors import CRSError, InputError, NoUsableDataError
from .common import vertical_options

log = logging.getLogger(__name__)


def register(group: click.Group) -> None:
    """Add this module's commands to ``group``."""
    group.add_command(validate)


@click.command("validate")
@click.argument("blocks_path", metavar="BLOCKS", type=click.Path(dir_okay=False))
@click.option("--dtm", type=click.Path(dir_okay=False), help="Terrain GeoTIFF (reference).")
@click.option("--dsm-max", type=click.Path(dir_okay=False), help="Maximum-surface GeoTIFF.")
@click.option("--dsm-p90", type=click.Path(dir_okay=False),
              help="90th-percentile surface GeoTIFF.")
@click.option("--atl08", type=click.Path(dir_okay=False),
              help="Validate against ATL08 land segments instead of rasters.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output .gpkg (layers residuals, stats), or .csv/.parquet.")
@click.option("--width", type=float, default=2.0, show_default=True,
              help="Corridor width, m (use the footprint, 13-17 m, for ICESat-2).")
@vertical_options
@click.option("--reference-vcrs", help="Vertical/compound CRS of the rasters, e.g. "
              "EPSG:32612+5703 (default: the DTM's CRS).")
@click.option("--photon-vcrs", default="EPSG:4979", show_default=True,
              help="Vertical datum of the block heights (ATL03/MABEL: WGS84 ellipsoid).")
@click.option("--slope-threshold", type=float, default=2.0, show_default=True,
              help="Degrees below which a block's aspect class is 'flat'.")
@click.option("--crs", "blocks_crs", help="CRS of a CSV block table (CSV carries none).")
@click.option("--plots", type=click.Path(file_okay=False),
              help="Folder for scatter and aspect PNGs.")
@click.pass_context
def validate(ctx: click.Context, blocks_path: str, dtm: str | None, dsm_max: str | None,
             dsm_p90: str | None, atl08: str | None, output: str, width: float,
             geoid: str | None, offset: float | None, reference_vcrs: str | None,
             photon_vcrs: str,
             slope_threshold: float, blocks_crs: str | None, plots: str | None) -> None:
    """Validate a block table against reference lidar rasters (or ATL08).

    Writes per-block residuals (corridor polygons) and statistics per block length,
    metric, aspect and slope class.
    """
    from ..geo import as_crs
    from ..outputs.atomic import check_writable, new_files_removed_on_failure
    from ..outputs.tables import check_output_path, read_blocks, write_layers
    from ..schema import LAYER_RESIDUALS, LAYER_STATS
    from ..validation.block_validation import validate_atl08, validate_blocks
    from .common import progress_bar

    if geoid is not None and offset is not None:
        raise InputError("give either --geoid or --offset, not both")
    rasters = (dtm, dsm_max, dsm_p90)
    if atl08 is None and any(r is None for r in rasters):
        raise InputError("give --dtm, --dsm-max and --dsm-p90 (or --atl08 FILE)")
    if atl08 is not None and any(r is not None for r in rasters):
        raise InputError("give either the rasters (--dtm ...) or --atl08, not both")
    check_output_path(output)  # fail before the work, not after it
    if plots is not None:
        check_writable(plots, folder=True)
    blocks = read_blocks(blocks_path)
    if len(blocks) == 0:
        raise NoUsableDataError(f"{blocks_path} holds no blocks; nothing to validate "
                                "(check the photons and block lengths that made it)")
    if blocks.crs is None:
        if blocks_crs is None:
            raise CRSError(f"{blocks_path} carries no CRS (CSV); give --crs EPSG:...")
        blocks = blocks.set_crs(as_crs(blocks_crs, "--crs"))
    quiet = bool(ctx.obj.get("quiet")) if ctx.obj else False
    with progress_bar("validate", quiet=quiet) as prog:
        if atl08 is not None:
            result = validate_atl08(blocks, atl08, width=width, progress=prog)
        else:
            result = validate_blocks(blocks, dtm=str(dtm), dsm_max=str(dsm_max),
                                     dsm_p90=str(dsm_p90),
                                     width=width, geoid=geoid, offset=offset,
                                     reference_vertical_crs=reference_vcrs,
                                     photon_vertical_crs=photon_vcrs,
                                     slope_threshold=slope_threshold, progress=prog)
    with (new_files_removed_on_failure(plots) if plots is not None
          else contextlib.nullcontext()):
        if plots is not None:
            from ..outputs.validation_plots import write_validation_plots

            write_validation_plots(result.residuals, result.stats, Path(plots))
        write_layers({LAYER_RESIDUALS: result.residuals, LAYER_STATS: result.stats}, output)
    used = int(result.residuals["use"].sum())
    click.echo(f"validated {used} of {len(result.residuals)} blocks -> {output}", err=True)
