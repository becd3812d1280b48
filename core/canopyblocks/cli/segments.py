"""CLI command ``segments``: ATL08-style land segments from a photon file."""

from __future__ import annotations

from pathlib import Path

import click

from .common import channel_option, parse_channel, parse_floats
from .options import option
from .progress_bars import progress_bar
from .vocabulary import deprecated_option, take_alias


@click.command("segments")
@click.argument("path", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Segment table: .gpkg (layer 'segments'), .parquet or .csv.")
@click.option("--beam", "beams", multiple=True,
              help="ATL03 beam (gt1l..gt3r); repeat for several. Default: every beam with photons.")
@channel_option
@option("--length", "length", multiple=False, default=100.0,
        type=click.FloatRange(min=0.0, min_open=True),
        help="Segment length along the track, m (ATL08: 100).")
@click.option("--s0", type=float, default=None,
              help="Segment origin along the track, m (default: the track start).")
@click.option("--bbox", default=None, help="lon_min,lat_min,lon_max,lat_max (degrees) subset.")
@option("--crs")
@option("--photon-layer", help="Also write layer 'photons' with each photon's class "
        "(classed_pc_flag: 0 noise, 1 ground, 2 canopy, 3 top of canopy; GeoPackage "
        "output).")
@deprecated_option("--photons", "old_photons", is_flag=True)
@click.pass_context
def segments_cmd(ctx: click.Context, path: str, output: str, beams: tuple[str, ...],
                 channel: str | None, length: float, s0: float | None, bbox: str | None,
                 crs: str | None, with_photons: bool, old_photons: bool) -> None:
    """Classify photons as ATL08 does (noise, ground, canopy, top of canopy) and summarise
    them in along-track segments with ATL08's column names (h_te_median, h_te_best_fit,
    h_canopy, canopy_h_metrics_NN, canopy_openness, photon counts)."""
    from ..workflows.segments import segments_from_file

    with_photons = take_alias(with_photons, old_photons, old="--photons", new="--photon-layer")
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    with progress_bar("segments", quiet=quiet) as progress:
        table = segments_from_file(
            path, length=length, s0=s0, beams=beams, channel=parse_channel(channel),
            bbox=parse_floats(bbox, 4, "lon_min,lat_min,lon_max,lat_max", "--bbox"),  # type: ignore[arg-type]
            crs=crs, output=output, with_photons=with_photons, progress=progress)
    if quiet:
        return
    n_ok = int((table["flag"] == "ok").sum()) if len(table) else 0
    click.echo(f"canopyblocks: {len(table)} segments of {length:g} m ({n_ok} with ground and "
               f"canopy) -> {Path(output)}", err=True)


def register(group: click.Group) -> None:
    """Add ``segments`` to ``group``."""
    group.add_command(segments_cmd)
