"""CLI command ``batch``: many ATL03 granules against many airborne tiles (DESIGN 6)."""

from __future__ import annotations

import logging

import click

from ..options import SURVEY_SOURCES_HELP
from .common import (
    lengths_option,
    min_signal_conf_option,
    preset_option,
    vertical_options,
)
from .options import option
from .sources import GranuleSource, SurveySource

log = logging.getLogger(__name__)


def register(group: click.Group) -> None:
    """Add this module's commands to ``group``."""
    group.add_command(batch)


@click.command("batch")
@click.argument("granules", nargs=-1, required=True, type=GranuleSource(exists=True))
@click.option("--tiles", "tiles", multiple=True, required=True, type=SurveySource(),
              help=f"The airborne survey: {SURVEY_SOURCES_HELP}.")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Output folder: parts/ (one folder per granule and beam), residuals.parquet "
                   "(every unit's validated blocks in one table), manifest.json, stats.csv, "
                   "report.html.")
@click.option("--beam", "beams", multiple=True, help="Beams to use (default all).")
@lengths_option("25")
@option("--width")
@preset_option()
@min_signal_conf_option
@vertical_options
@click.option("--photon-vcrs", default="EPSG:4979", show_default=True,
              help="Vertical datum of the photon heights.")
@click.option("--reference-vcrs", help="Vertical/compound CRS of the tiles' heights.")
@click.option("--resolution", type=float, default=2.0, show_default=True,
              help="Reference raster cell size, m.")
@click.option("--backend", type=click.Choice(["serial", "processes", "dask"]),
              default="processes", show_default=True, help="Where units run.")
@click.option("--workers", type=click.IntRange(1, 512), default=None,
              help="Processes or local Dask workers (default: the machine's cores).")
@click.option("--scheduler", default=None,
              help="Address of a running Dask scheduler (tcp://host:8786) instead of a "
                   "local cluster.")
@click.pass_context
def batch(ctx: click.Context, granules: tuple[str, ...], tiles: tuple[str, ...], output: str,
          beams: tuple[str, ...], lengths: tuple[float, ...], width: float | None, preset: str,
          min_signal_conf: int | None, geoid: str | None, offset: float | None,
          photon_vcrs: str, reference_vcrs: str | None, resolution: float, backend: str,
          workers: int | None, scheduler: str | None) -> None:
    """Validate many ATL03 granules (files or folders) against airborne tiles.

    A granule may also be an s3:// or https:// URL, an s3:// prefix (every .h5 under it),
    or a .txt file listing paths or URLs, one a line.

    One unit of work per (granule, beam, tiles it crosses); a rerun skips finished
    units; a failed unit is reported and the others complete.
    """
    from ..workflows.batch import BatchConfig, run_batch
    from .progress_bars import progress_bar

    if scheduler is not None and backend != "dask":
        backend = "dask"
    cfg = BatchConfig(lengths=tuple(lengths) or (25.0,), preset=preset,
                      **({} if width is None else {"width": width}),
                      min_signal_conf=min_signal_conf, offset=offset, geoid=geoid,
                      photon_vcrs=photon_vcrs, reference_vcrs=reference_vcrs,
                      resolution=resolution)
    quiet = bool(ctx.obj.get("quiet")) if ctx.obj else False
    with progress_bar("batch", quiet=quiet) as prog:
        res = run_batch(list(granules), list(tiles), output, cfg, beams=beams,
                        backend=backend, workers=workers, scheduler=scheduler,  # type: ignore[arg-type]
                        progress=prog)
    ok = sum(u["status"] == "ok" for u in res.units)
    for u in res.failed:  # shown under -q too: a failure is a warning
        click.echo(f"canopyblocks: warning: failed: {u['key']}: {u['error']}", err=True)
    for u in res.not_crossing:  # a granule left out is said, with why
        click.echo(f"canopyblocks: warning: skipped: {u['granule']}: {u['error']}", err=True)
    if not quiet:
        units = len(res.units) - len(res.not_crossing)
        click.echo(f"{ok} of {units} units validated ({res.skipped} already done, "
                   f"{len(res.failed)} failed, {len(res.not_crossing)} granule(s) skipped: "
                   f"no tile on their tracks) -> {output}", err=True)
