"""CLI command ``validate``: blocks or footprints vs reference lidar -> residuals, stats."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import click

from ..options import OPTIONS, SURVEY_SOURCES_HELP
from .common import vertical_options
from .options import option
from .sources import SurveySource
from .vocabulary import ChoiceWithOld, deprecated_option, deprecated_value, take_alias

if TYPE_CHECKING:
    import pandas as pd

log = logging.getLogger(__name__)


def register(group: click.Group) -> None:
    """Add this module's commands to ``group``."""
    group.add_command(validate)


@click.command("validate")
@click.argument("blocks_path", metavar="BLOCKS_OR_FOOTPRINTS", type=click.Path(dir_okay=False))
@click.option("--dtm", type=click.Path(dir_okay=False), help="Terrain GeoTIFF (reference).")
@click.option("--dsm-max", type=click.Path(dir_okay=False), help="Maximum-surface GeoTIFF.")
@click.option("--dsm-p90", type=click.Path(dir_okay=False),
              help="90th-percentile surface GeoTIFF.")
@option("--atl08")
@option("--reference", type=ChoiceWithOld(OPTIONS["--reference"].choices, ("rasters",)),
        help="Reference for blocks: corridor rasters (default), ATL08 (default with "
        "--atl08), or the footprint-matched airborne points (--points; default with "
        "--points and no --dtm). Footprint tables (GEDI) always use the footprint reference.")
@click.option("--points", "points", multiple=True, type=SurveySource(),
              help=f"The airborne survey for the footprint reference: {SURVEY_SOURCES_HELP}.")
@click.option("--diameter", type=float, default=None,
              help="Footprint diameter of photon blocks, m (default 13; GEDI footprints are "
                   "the instrument's 22 m).")
@click.option("--cut", type=float, default=None,
              help="Footprint reference: points within cut x R count (default 1 for blocks, "
                   "1.5 = 3 sigma for GEDI footprints).")
@click.option("--weighting", type=click.Choice(["gaussian", "gaussian_density"]),
              default=None, help="Footprint reference: Gaussian weights, optionally divided "
              "by the points per 1.5 m cell (default gaussian for blocks, gaussian_density "
              "for GEDI footprints).")
@click.option("--footprint-definition", type=click.Choice(["waveform", "points"]),
              default=None, help="GEDI footprints: compare each with the airborne points "
              "formed into the waveform GEDI would record and read by the same algorithm "
              "(waveform, the default: ground = lowest mode, RH from the energy above it) or "
              "with the weighted points themselves (points: ground = weighted mean of the "
              "ground points, RH = weighted percentiles of all returns). --cut and "
              "--weighting shape the points definition; the waveform's beam has sigma = "
              "--diameter / 4 and reaches 3 sigma.")
@option("--reference-statistic")
@option("--points-crs")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output .gpkg (layers residuals, stats), or .csv/.parquet.")
@option("--width")
@vertical_options
@click.option("--reference-vcrs", help="Vertical/compound CRS of the rasters, e.g. "
              "EPSG:32612+5703 (default: the DTM's CRS).")
@click.option("--photon-vcrs", default="EPSG:4979", show_default=True,
              help="Vertical datum of the block heights (ATL03/MABEL/GEDI: WGS84 ellipsoid).")
@click.option("--slope-threshold", type=float, default=2.0, show_default=True,
              help="Degrees below which a block's aspect class is 'flat'.")
@option("--table-crs", "blocks_crs",
        help="CRS of the x/y of a CSV block table (CSV carries none).")
@deprecated_option("--crs", "old_crs")
@click.option("--coregister", is_flag=True,
              help="First find the track's geolocation offset against --dtm (and --dsm-max) "
                   "and validate the shifted table; offsets -> <output>_offsets.json, "
                   "uncorrected statistics kept beside the corrected ones.")
@click.option("--coregister-vertical", is_flag=True,
              help="With --coregister: also apply the vertical offset (it then absorbs the "
                   "ground bias, which is reported as zero).")
@click.option("--search-range", type=float, default=15.0, show_default=True,
              help="With --coregister: search +- this many metres along and across the track.")
@deprecated_option("--coregister-range", "old_range", type=float)
@click.option("--coregister-photons", type=click.Path(dir_okay=False),
              help="With --coregister: find the offset from these photons (the file the "
                   "blocks were made from) instead of the blocks; the same offsets as "
                   "'coregister PHOTONS' with the blocks' CRS.")
@option("--plots", help="Folder for the scatter and aspect PNGs.")
@click.pass_context
def validate(ctx: click.Context, blocks_path: str, dtm: str | None, dsm_max: str | None,
             dsm_p90: str | None, atl08: str | None, reference: str | None,
             points: tuple[str, ...], diameter: float | None, cut: float | None,
             weighting: str | None, footprint_definition: str | None,
             reference_statistic: str, points_crs: str | None, output: str, width: float | None, geoid: str | None, offset: float | None,
             reference_vcrs: str | None, photon_vcrs: str, slope_threshold: float,
             blocks_crs: str | None, old_crs: str | None, coregister: bool, coregister_vertical: bool,
             search_range: float, old_range: float | None, coregister_photons: str | None,
             plots: str | None) -> None:
    """Validate a block table (or GEDI footprints) against reference lidar.

    Blocks: corridor rasters (DTM, DSM max, DSM p90), ATL08 land segments, or the
    footprint-matched airborne points. Footprints: the footprint-matched airborne points.
    Writes per-block residuals and statistics per block length, metric, aspect and slope
    class (footprints: per beam, aspect, slope and cover class).
    """
    from ..workflows.params import CoregParams, FootprintReferenceParams
    from ..workflows.validate import is_footprint_table, validate_file
    from .progress_bars import progress_bar

    search_range = take_alias(search_range, old_range, old="--coregister-range",
                              new="--search-range", default=15.0)
    reference = deprecated_value(reference, option="--reference", old="rasters", new="corridor")
    blocks_crs = take_alias(blocks_crs, old_crs, old="--crs", new="--table-crs")
    footprints = is_footprint_table(blocks_path)
    given: dict[str, Any] = {k: v for k, v in (("diameter", diameter), ("cut", cut),
                                               ("weighting", weighting),
                                               ("definition", footprint_definition))
                             if v is not None}
    from ..errors import InputError

    if footprints and diameter is not None:
        from .simulate import WAVEFORM_FOOTPRINT

        raise click.BadParameter(
            f"applies to photon blocks only: the {WAVEFORM_FOOTPRINT['gedi']} is the "
            "instrument's, as run and simulate use it; leave it out", param_hint="--diameter")
    if footprint_definition is not None and not footprints:
        raise InputError("--footprint-definition applies to GEDI footprint tables; photon "
                         "blocks are compared with the weighted points")
    fparams = None
    if given:  # the sensor's footprint, with what was given changed
        fparams = (FootprintReferenceParams.gedi(**given) if footprints
                   else FootprintReferenceParams.icesat2(**given))
    quiet = bool(ctx.obj.get("quiet")) if ctx.obj else False
    with progress_bar("validate", quiet=quiet) as prog:
        result = validate_file(
            blocks_path, output, reference=reference,  # type: ignore[arg-type]
            dtm=dtm, dsm_max=dsm_max, dsm_p90=dsm_p90, atl08=atl08, points=points,
            footprint_params=fparams, width=width, geoid=geoid, offset=offset,
            reference_vertical_crs=reference_vcrs, photon_vertical_crs=photon_vcrs,
            slope_threshold=slope_threshold, table_crs=blocks_crs, points_crs=points_crs,
            plots=plots, coregister=coregister, coregister_vertical=coregister_vertical,
            coreg_params=CoregParams(search_range=search_range) if coregister else None,
            coregister_photons=coregister_photons, reference_statistic=reference_statistic,
            progress=prog)
    if result.coregistration is not None and not quiet:
        for name, o in result.coregistration.offsets.items():
            status = "applied" if name == result.applied else (
                "" if o.determined else "undetermined, not applied")
            click.echo(f"offset {name}: along {o.along_track:+.2f} cross {o.cross_track:+.2f} "
                       f"(+-{o.along_track_sd:.2f}/{o.cross_track_sd:.2f}) vertical "
                       f"{o.vertical:+.2f} m; held-out ground RMSE "
                       f"{o.heldout_rmse_before:.2f} -> {o.heldout_rmse_after:.2f} m "
                       f"{status}".rstrip(), err=True)
        if result.stats_before is not None:
            _print_before_after(result.stats_before, result.stats)
    if not quiet:
        click.echo(f"validated {result.n_used} of {len(result.residuals)} {result.kind} -> "
                   f"{', '.join(str(p) for p in result.files or (result.output,))}", err=True)


def _print_before_after(before: pd.DataFrame, after: pd.DataFrame) -> None:
    keys = [k for k in ("length", "metric") if k in after.columns]
    b = before[before["group"] == "all"] if "group" in before.columns else before
    a = after[after["group"] == "all"] if "group" in after.columns else after
    m = b.merge(a, on=keys, suffixes=("_before", "_after"))
    for row in m.itertuples():
        label = " ".join(f"{getattr(row, k)}" for k in keys)
        click.echo(f"  {label:<14} rmse {row.rmse_before:.2f} -> {row.rmse_after:.2f}  "
                   f"bias {row.bias_before:+.2f} -> {row.bias_after:+.2f}", err=True)
