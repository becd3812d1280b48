"""CLI command ``coregister``: a track's geolocation offset against the airborne rasters."""

from __future__ import annotations

import logging

import click
import numpy as np

from ..errors import InputError
from .common import min_signal_conf_option, vertical_options
from .options import option
from .vocabulary import deprecated_option, take_alias

log = logging.getLogger(__name__)


def register(group: click.Group) -> None:
    """Add this module's commands to ``group``."""
    group.add_command(coregister)


@click.command("coregister")
@click.argument("source", metavar="PHOTONS_OR_BLOCKS", type=click.Path(dir_okay=False))
@click.option("--dtm", required=True, type=click.Path(dir_okay=False),
              help="Terrain GeoTIFF (reference), m.")
@click.option("--dsm-max", type=click.Path(dir_okay=False),
              help="Maximum-surface GeoTIFF: also align the canopy top.")
@click.option("--beam", "beams", multiple=True, help="Beam/track to use (repeatable; "
              "default all).")
@option("--crs", help="Metric CRS the photons are projected into (default: the UTM zone "
        "of the track).")
@option("--table-crs", help="CRS of the x/y of a CSV block table (CSV carries none).")
@vertical_options
@click.option("--photon-vcrs", default="EPSG:4979", show_default=True,
              help="Vertical datum of the heights (ATL03/MABEL/GEDI: WGS84 ellipsoid).")
@click.option("--reference-vcrs", help="Vertical/compound CRS of the rasters (default: the "
              "DTM's CRS).")
@min_signal_conf_option
@option("--search-range")
@deprecated_option("--range", "old_range", type=float)
@click.option("--step", type=float, default=1.0, show_default=True,
              help="Coarse grid step, m (then refined by 0.25 m).")
@click.option("--use-top", type=click.Choice(["auto", "yes", "no"]), default="auto",
              show_default=True, help="Also match the canopy top to --dsm-max.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="offsets.json (one entry per track and 'all').")
@option("--plot", help="Write the cost-surface plot (PNG).")
@click.pass_context
def coregister(ctx: click.Context, source: str, dtm: str, dsm_max: str | None,
               beams: tuple[str, ...], crs: str | None, table_crs: str | None, geoid: str | None,
               offset: float | None, photon_vcrs: str, reference_vcrs: str | None,
               min_signal_conf: int | None, search_range: float, old_range: float | None,
               step: float, use_top: str,
               output: str, plot: str | None) -> None:
    """Find the along-track, cross-track and vertical shift that aligns a track
    (photons, blocks or GEDI footprints) with the airborne DTM (and DSM).

    Prints the offsets: the shift to ADD to the reported positions and heights, with
    the horizontal uncertainty (+-, m). An offset is 'ok' only when, fitted on some
    stretches of the track, it also improves the held-out stretches significantly;
    otherwise it is 'undetermined' (a warning says why) and must not be applied. Rasters
    that cover too little of the track are refused.
    """
    from ..atomic import check_writable
    from ..workflows.coregister import coregister_file, offset_to_apply, write_offsets
    from ..workflows.params import CoregParams
    from .progress_bars import progress_bar

    search_range = take_alias(search_range, old_range, old="--range", new="--search-range",
                              default=15.0)
    if not output.lower().endswith(".json"):
        raise InputError(f"-o {output}: the offsets are written as JSON; name it *.json")
    check_writable(output)
    if plot is not None:
        check_writable(plot)
    params = CoregParams(search_range=search_range, step=step, use_top=use_top)  # type: ignore[arg-type]
    quiet = bool(ctx.obj.get("quiet")) if ctx.obj else False
    with progress_bar("coregister", quiet=quiet) as prog:
        result = coregister_file(source, dtm, dsm_max, beams=beams, crs=crs, table_crs=table_crs, geoid=geoid,
                                 offset=offset, photon_vertical_crs=photon_vcrs,
                                 reference_vertical_crs=reference_vcrs,
                                 min_signal_conf=min_signal_conf, params=params, progress=prog)
    if plot is not None:
        from ..workflows.coregister import write_cost_surfaces

        write_cost_surfaces(result, plot)
    write_offsets(result, output)
    offset_to_apply(result, source, applying=False)
    if not quiet:
        click.echo(f"{'track':<10} {'along':>7} {'cross':>7} {'+-':>5} {'east':>7} "
                   f"{'north':>7} {'vert':>7} {'rmse before':>11} {'after':>6}  status")
        for name, o in result.offsets.items():
            sd = float(np.hypot(o.along_track_sd, o.cross_track_sd))
            click.echo(f"{name:<10} {o.along_track:+7.2f} {o.cross_track:+7.2f} {sd:5.2f} "
                       f"{o.east:+7.2f} {o.north:+7.2f} {o.vertical:+7.2f} "
                       f"{o.rmse_before:11.2f} {o.rmse_after:6.2f}  {o.status}")
    if not quiet:
        click.echo(f"offsets -> {output}", err=True)
