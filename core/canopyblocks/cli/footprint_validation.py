"""CLI command ``validate-footprints``: GEDI footprints vs the footprint-matched ALS reference."""

from __future__ import annotations

import logging

import click

from ..errors import InputError
from ..options import SURVEY_SOURCES_HELP
from .common import vertical_options
from .sources import SurveySource
from .vocabulary import say_deprecated

log = logging.getLogger(__name__)


def register(group: click.Group) -> None:
    """Add this module's commands to ``group``."""
    group.add_command(validate_footprints_cmd)


@click.command("validate-footprints", hidden=True)
@click.argument("footprints", metavar="FOOTPRINTS", type=click.Path(dir_okay=False))
@click.option("--points", "points", multiple=True, required=True,
              type=SurveySource(), help=f"The airborne survey: {SURVEY_SOURCES_HELP}.")
@click.option("--diameter", type=float, default=22.0, show_default=True,
              help="Footprint diameter 2R, m (GEDI 22: sigma 5.5 m).")
@click.option("--cut", type=float, default=1.5, show_default=True,
              help="Points within cut x R count (1.5 = 3 sigma for GEDI).")
@click.option("--weighting", type=click.Choice(["gaussian", "gaussian_density"]),
              default="gaussian_density", show_default=True,
              help="Gaussian weights, optionally divided by the points per 1.5 m cell.")
@vertical_options
@click.option("--photon-vcrs", default="EPSG:4979", show_default=True,
              help="Vertical datum of the footprint elevations (GEDI: WGS84 ellipsoid).")
@click.option("--reference-vcrs", help="Vertical CRS of the tiles' heights (default: "
              "the tiles' own, e.g. EPSG:5703).")
@click.option("--points-crs", help="CRS of tiles that state none.")
@click.option("--crs", "table_crs", help="CRS of a CSV footprint table without lon/lat.")
@click.option("--slope-threshold", type=float, default=2.0, show_default=True,
              help="Degrees below which the aspect class is 'flat'.")
@click.option("--dtm", type=click.Path(dir_okay=False),
              help="DTM GeoTIFF for the maps' hillshade (with --plots).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output .gpkg (layers residuals_footprints, stats_footprints), or "
                   ".csv/.parquet.")
@click.option("--plots", type=click.Path(file_okay=False),
              help="Folder for the scatter and map PNGs.")
@click.pass_context
def validate_footprints_cmd(ctx: click.Context, footprints: str, points: tuple[str, ...],
                            diameter: float, cut: float, weighting: str, geoid: str | None,
                            offset: float | None, photon_vcrs: str,
                            reference_vcrs: str | None, points_crs: str | None,
                            table_crs: str | None, slope_threshold: float, dtm: str | None,
                            output: str, plots: str | None) -> None:
    """Deprecated: use ``validate FOOTPRINTS --points TILE`` (the same reference and
    defaults for GEDI footprints).

    Each footprint is compared with the ALS points weighted by a Gaussian footprint
    (ground, RH98, RH50, cover); statistics per beam, aspect, slope and cover class.
    """
    say_deprecated("the command validate-footprints", "validate FOOTPRINTS --points TILE")
    from ..workflows.params import FootprintReferenceParams
    from ..workflows.validate import validate_footprints_file
    from .progress_bars import progress_bar

    if geoid is not None and offset is not None:
        raise InputError("give either --geoid or --offset, not both")
    params = FootprintReferenceParams.gedi(diameter=diameter, cut=cut, weighting=weighting)
    quiet = bool(ctx.obj.get("quiet")) if ctx.obj else False
    with progress_bar("validate-footprints", quiet=quiet) as prog:
        result = validate_footprints_file(
            footprints, list(points), output, plots=plots, dtm=dtm, params=params,
            geoid=geoid, offset=offset, photon_vertical_crs=photon_vcrs,
            reference_vertical_crs=reference_vcrs, points_crs=points_crs,
            table_crs=table_crs, slope_threshold=slope_threshold, progress=prog)
    if quiet:
        return
    used = int(result.residuals["use"].sum())
    click.echo(f"validated {used} of {len(result.residuals)} footprints -> {output}", err=True)
