"""CLI command ``waveforms``: GEDI L1B waveforms, flash-lidar (ESFL) cubes or
dual-wavelength pairs -> footprints layer (DESIGN section 4)."""

from __future__ import annotations

import logging

import click

from .common import parse_floats
from .options import option
from .progress_bars import progress_bar
from .vocabulary import deprecated_option, take_alias

log = logging.getLogger(__name__)


def register(group: click.Group) -> None:
    """Add this module's commands to ``group``."""
    group.add_command(waveforms_cmd)


@click.command("waveforms")
@click.argument("path", metavar="FILE", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Footprints: .gpkg (layer 'footprints'), .parquet or .csv.")
@click.option("--beam", "beams", multiple=True,
              help="Beam (BEAM0000 .. BEAM1011); repeat for several. Default: every beam.")
@click.option("--setting", type=click.Choice(["a1", "a2", "a3", "a4", "a5", "a6"]),
              default="a1", show_default=True, help="L2A setting group (thresholds, "
              "smoothing).")
@click.option("--decompose", is_flag=True,
              help="Also fit a sum of Gaussians to each waveform and add ground_gauss "
                   "(15-25x slower).")
@click.option("--all-rh", is_flag=True, help="Write rh0 .. rh100 (every percent).")
@click.option("--bbox", default=None, help="lon_min,lat_min,lon_max,lat_max (degrees) subset.")
@option("--crs", help="Metric CRS of the output x/y (default: the UTM zone of the shots).")
@click.option("--quality", is_flag=True,
              help="Drop stale and degraded shots (default: keep them, flagged).")
@click.option("--l2a", type=click.Path(dir_okay=False), default=None,
              help="GEDI L2A of the same shots: add its values and the differences "
                   "(layer l2a_comparison).")
@click.option("--l2b", type=click.Path(dir_okay=False), default=None,
              help="GEDI L2B of the same shots: add its cover.")
@option("--plots", help="Folder for the waveform plots (PNG) and waveforms.html.")
@click.option("--shot", "shots", multiple=True, type=int,
              help="Shot number to plot (repeatable; default a few ok shots per beam).")
@click.option("--workers", type=click.IntRange(1, 512), default=None,
              help="Processes reading and processing the beams of a granule in parallel "
                   "(default: the machine's cores; the table is the same as with 1).")
@click.option("--fraction", type=click.FloatRange(0.0, 1.0, min_open=True), default=None,
              help="Flash lidar (ESFL): energy fraction of the brightest pixel that makes a "
                   "pixel of the 4 x 4 region part of the footprint (the paper's f; "
                   "default 0.5).")
@click.option("--cell", type=click.FloatRange(min=0.0), default=None,
              help="Flash lidar (ESFL): grid cell, m, on which the footprints' pixels are "
                   "merged into waveforms (the paper's 5 m; 0: one waveform per footprint).")
@click.option("--noise-fit", type=click.Choice(["ml", "lsq"]), default=None,
              help="Flash lidar (ESFL): the Gaussian fitted to each waveform's value "
                   "histogram: ml (maximum likelihood below the mode, default) or lsq "
                   "(least squares to the counts around the mode).")
@option("--k-sigma", "noise_threshold", type=click.FloatRange(min=0.0, min_open=True),
        help="Flash lidar and dual wavelength: signal threshold k, in noise standard "
             "deviations above the noise mean (the papers' 4).")
@deprecated_option("--noise-threshold", "old_noise_threshold",
                   type=click.FloatRange(min=0.0, min_open=True))
@click.option("--dual-method", type=click.Choice(["paper", "refined"]), default=None,
              help="Dual wavelength: the paper's steps (default) or refined (the search "
                   "confined to the lowest return, the gap rule, weak edges ignored).")
@click.pass_context
def waveforms_cmd(ctx: click.Context, path: str, output: str, beams: tuple[str, ...],
                  setting: str, decompose: bool, all_rh: bool, bbox: str | None,
                  crs: str | None, quality: bool, l2a: str | None, l2b: str | None,
                  plots: str | None, shots: tuple[int, ...], workers: int | None,
                  fraction: float | None, cell: float | None, noise_fit: str | None,
                  noise_threshold: float | None, old_noise_threshold: float | None,
                  dual_method: str | None) -> None:
    """Footprints from waveforms: ground, canopy top, RH metrics and cover per GEDI
    footprint from L1B (GEDI L2A's algorithm, setting groups a1-a6); terrain and canopy
    height per 5 m cell from flash-lidar (ESFL) cubes (the flash-lidar paper's chain);
    ground and tree height per footprint from dual-wavelength pairs (the
    dual-wavelength paper's ground finder). The product is told from the file."""
    from ..workflows.params import WaveformParams

    noise_threshold = take_alias(noise_threshold, old_noise_threshold,
                                 old="--noise-threshold", new="--k-sigma")
    from ..workflows.waveforms import footprints_to_file
    from ..workflows.waveforms_flash_dual import SensorOptions

    params = WaveformParams(setting=setting, decompose=decompose,  # type: ignore[arg-type]
                            all_rh=all_rh)
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    with progress_bar("waveforms", quiet=quiet) as progress:
        res = footprints_to_file(
            path, output, beams=beams or None, params=params,
            bbox=parse_floats(bbox, 4, "lon_min,lat_min,lon_max,lat_max", "--bbox"),  # type: ignore[arg-type]
            crs=crs, quality=quality, l2a=l2a, l2b=l2b, plots_dir=plots,
            plot_shots=shots or None, workers=workers,
            options=SensorOptions(fraction, cell, noise_fit, noise_threshold, dual_method),
            progress=progress)
    if quiet:
        return
    if res.comparison is not None and len(res.comparison):
        for row in res.comparison[res.comparison["beam"] == "all"].to_dict("records"):
            unit = "" if row["metric"] == "cover" else " m"
            click.echo(f"  vs {row['product']} {row['metric']:<6} n={row['n']:<5} "
                       f"bias={row['bias']:+.3f} rmse={row['rmse']:.3f}{unit}  within 0.10"
                       f"{unit}: {100 * row['within_0.10']:.1f} %", err=True)
            if row.get("left_out", "none") != "none":
                click.echo(f"    left out: {row['left_out']}", err=True)
    flags = ", ".join(f"{k} {v}" for k, v in sorted(res.flags.items()))
    click.echo(f"canopyblocks: {len(res.footprints)} footprints ({flags}) -> {res.output}",
               err=True)
