"""CLI command ``run``: the whole chain from photons (or a simulation) and tiles to the
validation layers, plots and an HTML report."""

from __future__ import annotations

import click

from ..options import PHOTON_RATES
from .common import (
    WIDTH_HELP,
    channel_option,
    explicit_value,
    lengths_option,
    min_signal_conf_option,
    parse_channel,
    preset_option,
    sensor_option,
    vertical_options,
)
from .options import option
from .progress_bars import progress_bar
from .sources import SurveySource
from .vocabulary import deprecated_option, say_deprecated, take_alias


@click.command("run")
@click.argument("tiles", nargs=-1, required=True, type=SurveySource())
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Output folder.")
@option("--photons", extra_help="Without it (or with --simulate), "
                   "ICESat-2 photons are simulated over the tiles.")
@click.option("--simulate", is_flag=True, help="Simulate the photons (the default without "
              "--photons).")
@sensor_option("What to simulate without --photons: ICESat-2 photons, GEDI waveforms, "
               "flash-lidar (ESFL) cubes or dual-wavelength pairs (then footprints are "
               "validated against the tiles). A GEDI, ESFL or dual file given as "
               "--photons is told from its content.")
@click.option("--esfl-noise", type=click.FloatRange(min=0.0, max=1.0), default=None,
              help="--sensor esfl: noise sd per pixel and range bin as a share of the mean "
                   "brightest-pixel peak (default 0.05; the flash-lidar paper does not "
                   "state its level; 0 = noise free).")
@click.option("--dual-noise", type=click.FloatRange(min=0.0, max=1.0), default=None,
              help="--sensor dual: noise sd as a share of each pair's near-infrared peak "
                   "(default 0.05, the dual-wavelength paper's; 0 = noise free).")
@click.option("--beam", "beams", multiple=True, help="ATL03 beam(s) to use.")
@channel_option
@option("--atl08", help="Matching ATL08 file: also validate against its land segments.")
@click.option("--azimuth", type=float, default=0.0, show_default=True,
              help="Simulated track direction, degrees clockwise from north.")
@option("--diameter", default=13.0, help="Simulated ICESat-2 footprint diameter, m (GEDI, "
        "flash-lidar and dual-wavelength footprints are their instruments').")
@option("--photon-rate")
@click.option("--seed", type=int, default=0, show_default=True, help="Simulation seed.")
@click.option("--realisations", type=click.IntRange(min=0), default=100, show_default=True,
              help="Simulated runs: photon draws per footprint diameter for the analysis "
                   "of the simulation against its truth (0 skips it).")
@lengths_option(default="10, 25, 50")
@min_signal_conf_option
@option("--width", help=WIDTH_HELP[:-2] + "; the footprint diameter when simulated).")
@click.option("--resolution", type=float, default=2.0, show_default=True,
              help="Reference raster cell size, m.")
@click.option("--smrf", is_flag=True, help="Classify ground with PDAL's SMRF (unclassified tiles).")
@vertical_options
@click.option("--calibrate", is_flag=True,
              help="Also fit the cut-offs to the reference and validate again with them.")
@preset_option("With another preset the recommended ones are computed too (see "
               "--compare).", dest="estimator_preset", old_values=PHOTON_RATES)
@deprecated_option("--estimators", "old_estimators",
                   type=click.Choice(["paper", "icesat2", "mabel", "atl08"]))
@click.option("--calibration", type=click.Path(dir_okay=False), default=None,
              help="Bias calibration JSON to apply to the blocks (fitted for --preset).")
@click.option("--compare/--no-compare", default=True, show_default=True,
              help="Also validate the paper's method beside the recommended estimators "
                   "(atl08), in a section of its own; with another --preset, the recommended "
                   "estimators beside it (the report leads with them).")
@click.option("--coregister", is_flag=True,
              help="Find the track's geolocation offset against the DTM/DSM and validate the "
                   "shifted blocks (offsets.json, layer stats_uncorrected).")
@click.option("--footprint-reference/--no-footprint-reference", default=True,
              show_default=True,
              help="Validate also against the footprint-matched airborne points, the "
                   "like-with-like reference the report leads with (layers "
                   "residuals_footprint, stats_footprint); without it the report leads with "
                   "the corridor maximum.")
@option("--reference-statistic")
@click.pass_context
def run_cmd(ctx: click.Context, tiles: tuple[str, ...], out_dir: str, photons: str | None,
            simulate: bool, beams: tuple[str, ...], channel: str | None, atl08: str | None,
            azimuth: float, diameter: float, photon_rate: str, seed: int,
            lengths: tuple[float, ...], min_signal_conf: int | None, width: float | None,
            resolution: float, smrf: bool, geoid: str | None, offset: float | None,
            calibrate: bool, realisations: int, estimator_preset: str,
            old_estimators: str | None,
            calibration: str | None, compare: bool, coregister: bool,
            footprint_reference: bool, reference_statistic: str, sensor: str, esfl_noise: float | None,
            dual_noise: float | None) -> None:
    """Photons + airborne TILES -> blocks, reference rasters, validation, plots, report."""
    from ..options import RECOMMENDED_PRESET
    from ..workflows.chain import run_chain
    from ..workflows.params import BlockParams
    from ..workflows.params import preset as named_preset

    if simulate and photons:
        raise click.UsageError("give either --photons or --simulate, not both")
    if sensor != "icesat2" and photons:
        raise click.UsageError(f"--sensor {sensor} simulates; give either --photons or "
                               "--sensor")
    if sensor != "icesat2" and explicit_value(ctx, "diameter", diameter) is not None:
        from .simulate import WAVEFORM_FOOTPRINT

        raise click.BadParameter(
            f"applies to --sensor icesat2 only: the {WAVEFORM_FOOTPRINT[sensor]} is the "
            "instrument's, simulated and validated alike; leave it out",
            param_hint="--diameter")
    for name, value, want in (("--esfl-noise", esfl_noise, "esfl"),
                              ("--dual-noise", dual_noise, "dual")):
        if value is not None and sensor != want:
            raise click.BadParameter(f"applies to --sensor {want} only", param_hint=name)
    estimator_preset = take_alias(explicit_value(ctx, "estimator_preset", estimator_preset),
                                  old_estimators, old="--estimators",
                                  new="--preset") or RECOMMENDED_PRESET
    if estimator_preset in PHOTON_RATES:  # the old meaning of --preset
        if explicit_value(ctx, "photon_rate", photon_rate) is not None:
            raise click.UsageError(f"give --photon-rate only, not also the deprecated "
                                   f"--preset {estimator_preset} (its old spelling)")
        say_deprecated(f"--preset {estimator_preset}", f"--photon-rate {estimator_preset}")
        photon_rate, estimator_preset = estimator_preset, RECOMMENDED_PRESET
    params = BlockParams(lengths=tuple(lengths) or (10.0, 25.0, 50.0),
                         min_signal_conf=min_signal_conf)
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    chan = parse_channel(channel)
    with progress_bar("run", quiet=quiet) as progress:
        result = run_chain(tiles, out_dir, photons=photons, beams=beams, channel=chan,
                           atl08=atl08, azimuth=azimuth, diameter=diameter,
                           photon_rate=photon_rate,
                           seed=seed, params=params, width=width, resolution=resolution,
                           ground="smrf" if smrf else "class2", geoid=geoid, offset=offset,
                           calibrate=calibrate, realisations=realisations,
                           estimators=named_preset(estimator_preset),
                           calibration=calibration,
                           compare_preset=RECOMMENDED_PRESET if compare else None,
                           coregister=coregister, footprint_reference=footprint_reference,
                           reference_statistic=reference_statistic, sensor=sensor, noise=esfl_noise if sensor == "esfl" else dual_noise,
                           progress=progress)
    if quiet:
        return
    for line in result.summary:
        click.echo(line, err=True)
    click.echo(f"canopyblocks: wrote {result.report}", err=True)


def register(group: click.Group) -> None:
    """Add ``run`` to ``group``."""
    group.add_command(run_cmd)
