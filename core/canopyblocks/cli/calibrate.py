"""CLI command ``calibrate``: fit the expansion-window cut-offs to airborne-lidar rasters."""

from __future__ import annotations

import click

from .common import (
    channel_option,
    lengths_option,
    min_signal_conf_option,
    parse_channel,
    progress_bar,
    vertical_options,
)


@click.command("calibrate")
@click.argument("photons", type=click.Path(dir_okay=False))
@click.option("--dtm", required=True, type=click.Path(dir_okay=False), help="Terrain GeoTIFF.")
@click.option("--dsm-max", required=True, type=click.Path(dir_okay=False),
              help="Maximum-surface GeoTIFF.")
@click.option("--dsm-p90", required=True, type=click.Path(dir_okay=False),
              help="90th-percentile surface GeoTIFF.")
@click.option("--beam", default=None, help="ATL03 beam (default: the file's default beam).")
@channel_option
@lengths_option(default="10, 25, 50")
@min_signal_conf_option
@click.option("--width", type=float, default=2.0, show_default=True,
              help="Corridor width, m (the footprint, 13-17 m, for ICESat-2).")
@click.option("--crs", default=None, help="Metric CRS for the photons (default: the DTM's).")
@vertical_options
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="Write the calibration table (.csv, .parquet or .gpkg).")
@click.pass_context
def calibrate_cmd(ctx: click.Context, photons: str, dtm: str, dsm_max: str, dsm_p90: str,
                  beam: str | None, channel: str | None, lengths: tuple[float, ...],
                  min_signal_conf: int | None, width: float, crs: str | None,
                  geoid: str | None, offset: float | None, output: str | None) -> None:
    """Fit the canopy-top and ground cut-offs of PHOTONS to the reference rasters.

    Blocks are computed with the paper's cut-offs, their corridor reference values read
    from the rasters, and for each length the (top, ground) fractions that best match
    are searched (seed 001 calibrated its cut-offs this way).  The RMSE columns are
    held out: cut-offs fitted on even blocks are scored on odd blocks and vice versa.
    """
    from ..blocks import BlockParams
    from ..validation.calibration import calibrate_reference_rasters

    if output is not None:
        from ..outputs.tables import check_output_path

        check_output_path(output)  # fail before the work, not after it
    params = BlockParams(lengths=tuple(lengths) or (10.0, 25.0, 50.0),
                         min_signal_conf=min_signal_conf)
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    with progress_bar("calibrate", quiet=quiet) as progress:
        cal = calibrate_reference_rasters(
            photons, params, dtm=dtm, dsm_max=dsm_max, dsm_p90=dsm_p90, width=width,
            beam=beam, channel=parse_channel(channel), crs=crs, geoid=geoid, offset=offset,
            progress=progress)
    for row in cal.table.itertuples():
        click.echo(f"{row.length:>5g} m: top {row.top_cutoff:.3f} (paper {row.default_top_cutoff:.3f})"
                   f"  ground {row.ground_cutoff:.3f} (paper {row.default_ground_cutoff:.3f})"
                   f"  held-out Hmax RMSE {row.rmse_hmax_default:.2f} -> "
                   f"{row.rmse_hmax_calibrated:.2f} m (n={row.n_holdout})")
    if output is not None:
        from ..outputs.tables import write_table

        write_table(cal.table, output, layer="calibration")
    top = ",".join(f"{L:g}:{t:g}" for L, t in ((r.length, r.top_cutoff)
                                                for r in cal.table.itertuples()))
    click.echo(f"canopyblocks: use them with `canopyblocks blocks ... --top-cutoff`/"
               f"`--ground-cutoff` per length (top {top})", err=True)


def register(group: click.Group) -> None:
    """Add ``calibrate`` to ``group``."""
    group.add_command(calibrate_cmd)
