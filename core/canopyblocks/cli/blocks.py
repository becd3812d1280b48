"""CLI commands ``info`` and ``blocks``: photon files to block canopy heights."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import click

from .common import (
    channel_option,
    explicit_value,
    lengths_option,
    min_signal_conf_option,
    parse_channel,
    parse_floats,
    preset_option,
)
from .options import option
from .progress_bars import progress_bar
from .vocabulary import deprecated_option, take_alias

log = logging.getLogger(__name__)


@click.command("info")
@click.argument("path", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def info_cmd(path: str, as_json: bool) -> None:
    """Describe a photon file: product, beams or channels, photon counts, extent."""
    from ..workflows.inputs import file_info, format_info

    info = file_info(path)
    if as_json:
        click.echo(json.dumps(info, indent=2, default=str))
    else:
        click.echo(format_info(info))


@click.command("blocks")
@click.argument("paths", metavar="PATH...", nargs=-1, required=True,
                type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Block table: .gpkg (layer 'blocks'), .parquet or .csv.")
@click.option("--beam", "beams", multiple=True,
              help="ATL03 beam (gt1l..gt3r); repeat for several. Default: every beam with photons.")
@channel_option
@lengths_option(default="25")
@click.option("--s0", type=float, default=None,
              help="Block origin along track, m (default: the track start).")
@option("--k-sigma", default=2.5,
        help="Noise filter of the paper's method: keep |z - mean| <= k * std per block.")
@deprecated_option("--k", "old_k", type=float)
@click.option("--noise", type=click.Choice(["sigma", "conf", "density", "atl08", "none"]),
              default=None,
              help="Noise filter: sigma (the paper's), conf (ATL03 signal_conf_ph), "
                   "density (DRAGANN-like: MABEL, simulated, tables), atl08 (the ATL08-style "
                   "classifier, with the file's background rate when it has one), none. "
                   "Without --preset, --noise, --ground-estimator and --top-estimator replace "
                   "parts of the paper's method.")
@preset_option()
@click.option("--ground-estimator", type=click.Choice(["paper", "surface"]), default=None,
              help="Ground: the paper's window mean, or a robust along-track surface.")
@click.option("--top-estimator", type=click.Choice(["paper", "p95", "p98", "p99", "p100"]),
              default=None, help="Canopy top: the paper's window, or a height percentile.")
@click.option("--calibration", type=click.Path(dir_okay=False), default=None,
              help="Bias calibration JSON (canopyblocks calibrate --method bias) to apply.")
@min_signal_conf_option
@click.option("--top-cutoff", type=float, default=None,
              help="Canopy-top window fraction (default by block length, as the paper).")
@click.option("--ground-cutoff", type=float, default=None,
              help="Ground window fraction (default by block length).")
@click.option("--min-photons", type=int, default=10, show_default=True,
              help="Blocks with fewer kept photons are flagged 'sparse'.")
@option("--atl08-classes", "atl08")
@deprecated_option("--atl08", "old_atl08", type=click.Path(dir_okay=False))
@click.option("--bbox", default=None, help="lon_min,lat_min,lon_max,lat_max (degrees) subset.")
@click.option("--polygon", type=click.Path(dir_okay=False), default=None,
              help="Vector file of polygons (any CRS): keep the blocks whose centre lies "
                   "inside.")
@click.option("--time", "time_range", nargs=2, default=None, metavar="START END",
              help="UTC dates or times (2022-04-01 or 2022-04-01T22:00:00): skip ATL03 "
                   "granules taken outside.")
@option("--crs")
@option("--photon-layer", help="Also write layer 'photons' with per-photon labels "
        "(GeoPackage output; with --noise atl08 also classed_pc_flag: 0 noise, 1 ground, "
        "2 canopy, 3 top of canopy).")
@deprecated_option("--photons", "old_photons", is_flag=True)
@option("--plot", "profile",
        help="Write the profile plot PNG (photons, canopy top and ground per block).")
@deprecated_option("--profile", "old_profile", type=click.Path(dir_okay=False))
@click.option("--workers", type=click.IntRange(1, 512), default=None,
              help="Processes reading and blocking the beams of a granule in parallel "
                   "(default: the machine's cores, capped by the memory available; the "
                   "table is the same as with 1).")
@click.pass_context
def blocks_cmd(ctx: click.Context, paths: tuple[str, ...], output: str,
               beams: tuple[str, ...],
               channel: str | None, lengths: tuple[float, ...], s0: float | None, k_sigma: float,
               old_k: float | None, old_atl08: str | None, old_profile: str | None,
               noise: str | None, preset: str, ground_estimator: str | None,
               top_estimator: str | None, calibration: str | None,
               min_signal_conf: int | None, top_cutoff: float | None,
               ground_cutoff: float | None, min_photons: int, atl08: str | None,
               bbox: str | None, polygon: str | None,
               time_range: tuple[str, str] | None, crs: str | None, with_photons: bool,
               old_photons: bool,
               profile: str | None, workers: int | None) -> None:
    """Canopy top, mean ground, Hmax and H90 per along-track block (the recommended
    estimators, atl08, or those of --preset; --preset paper: the paper's method).

    Several PATHs (granules) give one table with a 'granule' column, filtered by
    --bbox, --polygon and --time.
    """
    from ..workflows.blocks import blocks_from_file
    from ..workflows.choices import estimators_from_options, refuse_unused_k_sigma
    from ..workflows.params import BlockParams

    with_photons = take_alias(with_photons, old_photons, old="--photons", new="--photon-layer")
    k_sigma = take_alias(k_sigma, old_k, old="--k", new="--k-sigma", default=2.5)
    atl08 = take_alias(atl08, old_atl08, old="--atl08", new="--atl08-classes")
    profile = take_alias(profile, old_profile, old="--profile", new="--plot")
    estimators = estimators_from_options(explicit_value(ctx, "preset", preset), noise,
                                         ground_estimator, top_estimator, min_signal_conf)
    if old_k is not None or explicit_value(ctx, "k_sigma", k_sigma) is not None:
        refuse_unused_k_sigma(estimators, k_sigma)
    params = BlockParams(
        lengths=tuple(lengths) or (25.0,), s0=s0, k_sigma=k_sigma,
        min_signal_conf=min_signal_conf, top_cutoff=top_cutoff, ground_cutoff=ground_cutoff,
        min_photons=min_photons,
    )
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    box = parse_floats(bbox, 4, "lon_min,lat_min,lon_max,lat_max", "--bbox")
    if len(paths) > 1 or polygon is not None or time_range is not None:
        many = [n for n, v in (("--photon-layer", with_photons), ("--plot", profile),
                               ("--atl08-classes", atl08)) if v]
        if many:
            raise click.UsageError(f"{', '.join(many)}: one PATH at a time (not with "
                                   "several granules, --polygon or --time)")
        from ..workflows.blocks_granules import blocks_from_granules

        with progress_bar("blocks", quiet=quiet) as progress:
            table = blocks_from_granules(
                paths, params, output=output, bbox=box,  # type: ignore[arg-type]
                polygon=polygon, time_range=time_range, crs=crs, estimators=estimators,
                calibration=calibration, beams=beams, channel=parse_channel(channel),
                workers=workers, progress=progress)
        if not quiet:
            click.echo(f"canopyblocks: {len(table)} blocks from "
                       f"{table['granule'].nunique()} granule(s) -> {Path(output)}", err=True)
        return
    path = paths[0]
    with progress_bar("blocks", quiet=quiet) as progress:
        result = blocks_from_file(
            path, params, estimators=estimators, calibration=calibration,
            beams=beams, channel=parse_channel(channel), atl08=atl08,
            bbox=box, crs=crs, output=output, with_photons=with_photons,  # type: ignore[arg-type]
            profile=profile, workers=workers, progress=progress,
        )
    n_ok = int((result.blocks["flag"] == "ok").sum()) if len(result.blocks) else 0
    if quiet:
        return
    click.echo(
        f"canopyblocks: {len(result.blocks)} blocks ({n_ok} ok) from "
        f"{', '.join(result.track_ids)} -> {Path(output)}",
        err=True,
    )


def register(group: click.Group) -> None:
    """Add ``info`` and ``blocks`` to ``group``."""
    group.add_command(info_cmd)
    group.add_command(blocks_cmd)


