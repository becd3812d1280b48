"""CLI command ``simulate``: ICESat-2/MABEL photons from airborne lidar (seed 002)."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from ..options import PHOTON_RATES
from .common import parse_floats as _floats
from .common import sensor_option
from .options import option
from .progress_bars import progress_bar
from .vocabulary import deprecated_option, take_alias

log = logging.getLogger(__name__)


#: What fixes each waveform sensor's footprint (``--diameter`` is refused for them).
WAVEFORM_FOOTPRINT = {"gedi": "GEDI footprint (22 m Gaussian, sigma 5.5 m)",
                      "dual": "dual-wavelength footprint (22 m Gaussian, sigma 5.5 m)",
                      "esfl": "flash-lidar footprint (its pixel array)"}


@click.command("simulate")
@click.argument("las", nargs=-1, required=True, type=click.Path(dir_okay=False))
@sensor_option("icesat2: photons (--instrument mabel for MABEL); gedi: "
               "waveforms in the GEDI L1B layout; esfl: flash-array data cubes "
               "(electronically steerable flash lidar); dual: visible/NIR waveform "
               "pairs.")
@click.option("--azimuth", type=float, default=None,
              help="Track through the survey centre at this azimuth, degrees clockwise "
                   "from grid north, clipped to the survey extent.")
@click.option("--line", "line", default=None,
              help="Track from x0,y0 to x1,y1 (metres, in the LAS CRS).")
@click.option("--polyline", default=None,
              help="Track through the vertices 'x0,y0;x1,y1;...' (metres, LAS CRS).")
@click.option("--centre", default=None,
              help="x,y the --azimuth track passes through (default: survey centre).")
@click.option("--diameter", "diameters", multiple=True, type=float,
              help="Footprint diameter, m; repeat (e.g. 13 and 17) for the report table. "
                   "Default: the instrument's (ICESat-2 13 m, MABEL 2 m). The output file "
                   "holds the first diameter. Photons only: GEDI, flash-lidar and "
                   "dual-wavelength footprints are their instruments'.")
@click.option("--instrument", type=click.Choice(["icesat2", "mabel"]), default="icesat2",
              show_default=True, help="Sets footprint, shot spacing and pulse rate defaults.")
@click.option("--shot-spacing", type=float, default=None,
              help="Metres between footprint centres (ICESat-2 0.7, MABEL 0.04, GEDI 60).")
@option("--photon-rate")
@deprecated_option("--preset", "old_preset", type=click.Choice(list(PHOTON_RATES)))
@option("--beam-strength", "beam")
@deprecated_option("--beam", "old_beam", type=click.Choice(["strong", "weak"]))
@click.option("--mean-photons", type=float, default=None,
              help="Poisson mean photons per shot (overrides --photon-rate/--beam-strength).")
@click.option("--background-rate", type=float, default=0.0, show_default=True,
              help="Solar background noise, MHz, the same for strong and weak beams "
                   "(0 = off; night ~0.1-0.3, day ~1-5). Noise photons fall uniformly in "
                   "a telemetry window around the smoothed terrain.")
@click.option("--night", is_flag=True, help="Night-time background: --background-rate 0.15.")
@click.option("--day", is_flag=True, help="Daytime background: --background-rate 3.")
@click.option("--telemetry-window", type=float, default=100.0, show_default=True,
              help="Half-height of the window the background photons fill, m, around "
                   "the airborne ground smoothed over 1 km.")
@deprecated_option("--noise-rate", "noise_rate", type=float)  # photons per shot per metre
@click.option("--geolocation-sigma", type=float, default=0.0, show_default=True,
              help="Horizontal geolocation error (Gaussian sigma), metres.")
@click.option("--dual-noise", type=click.FloatRange(min=0.0, max=1.0), default=None,
              help="--sensor dual: noise sd as a share of each pair's near-infrared peak "
                   "(default 0.05, the dual-wavelength paper's; 0 = noise free).")
@click.option("--esfl-noise", type=click.FloatRange(min=0.0, max=1.0), default=None,
              help="--sensor esfl: noise sd per pixel and range bin as a share of the mean "
                   "brightest-pixel peak (default 0.05; the flash-lidar paper does not "
                   "state its level; 0 = noise free).")
@click.option("--realisations", type=click.IntRange(min=1), default=100, show_default=True,
              help="Photon draws per diameter for the statistics (the file holds the first).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Random seed.")
@option("--points-crs", "crs")
@deprecated_option("--crs", "old_crs")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Photons: .h5 (ATL03 layout, or MABEL with --format mabel), or a "
                   ".parquet/.gpkg/.csv table with truth columns.")
@click.option("--format", "fmt", type=click.Choice(["atl03", "mabel"]), default=None,
              help="HDF5 layout (default: atl03 for icesat2, mabel for mabel).")
@option("--photon-table")
@deprecated_option("--photons", "old_photon_table", type=click.Path(dir_okay=False))
@click.option("--report", type=click.Path(file_okay=False), default=None,
              help="Folder for the table of errors against truth (CSV), residuals by cover (CSV), the "
                   "cover plot (PNG) and the per-footprint truth (CSV).")
@click.pass_context
def simulate_cmd(ctx: click.Context, las: tuple[str, ...], sensor: str, azimuth: float | None,
                 line: str | None, polyline: str | None, centre: str | None,
                 diameters: tuple[float, ...],
                 instrument: str, shot_spacing: float | None, photon_rate: str,
                 old_preset: str | None, beam: str, old_beam: str | None,
                 mean_photons: float | None, background_rate: float, night: bool, day: bool,
                 telemetry_window: float, noise_rate: float | None, geolocation_sigma: float,
                 dual_noise: float | None, esfl_noise: float | None, realisations: int, seed: int, crs: str | None, old_crs: str | None, output: str,
                 fmt: str | None, photon_table: str | None, old_photon_table: str | None,
                 report: str | None) -> None:
    """Simulate lidar along a track over airborne LAS/LAZ tiles: ICESat-2/MABEL photons
    (default), GEDI waveforms, flash-array cubes or dual-wavelength pairs.

    Heights keep the LAS files' CRS (converted to WGS84 lat/lon in HDF5 files) and
    vertical datum; the truth (footprint ground, top, RH, cover) travels with them.
    """
    from ..workflows.params import SimParams
    from ..workflows.simulate import simulate_photons_over_tiles

    crs = take_alias(crs, old_crs, old="--crs", new="--points-crs")
    photon_table = take_alias(photon_table, old_photon_table, old="--photons",
                              new="--photon-table")
    photon_rate = take_alias(photon_rate, old_preset, old="--preset", new="--photon-rate",
                             default="temperate")
    beam = take_alias(beam, old_beam, old="--beam", new="--beam-strength", default="strong")
    if sum(v is not None for v in (azimuth, line, polyline)) != 1:
        raise click.UsageError(
            "give exactly one of --azimuth DEG, --line x0,y0,x1,y1 or --polyline 'x,y;x,y;...'")
    if sensor != "icesat2":
        if diameters:
            raise click.BadParameter(
                f"applies to --sensor icesat2 only: the {WAVEFORM_FOOTPRINT[sensor]} is the "
                "instrument's, simulated and validated alike; leave it out",
                param_hint="--diameter")
        _waveform_sensor(ctx, las, sensor, azimuth, line, polyline, centre, seed, crs,
                         output, report, shot_spacing, dual_noise, esfl_noise)
        return
    if dual_noise is not None:
        raise click.BadParameter("applies to --sensor dual only", param_hint="--dual-noise")
    if esfl_noise is not None:
        raise click.BadParameter("applies to --sensor esfl only", param_hint="--esfl-noise")
    if night and day:
        raise click.UsageError("give the background noise once; got --day and --night")
    light = "night" if night else "day" if day else None
    background_rate = _background_rate(background_rate, light, noise_rate, quiet=bool(
        ctx.obj and ctx.obj.get("quiet")))
    params = SimParams(instrument=instrument,  # type: ignore[arg-type]
                       diameter=diameters[0] if diameters else None,
                       shot_spacing=shot_spacing,
                       photon_rate=photon_rate,  # type: ignore[arg-type]
                       beam=beam, mean_photons=mean_photons,  # type: ignore[arg-type]
                       background_rate_mhz=background_rate if noise_rate is None else 0.0,
                       noise_rate=noise_rate, telemetry_window=telemetry_window,
                       geolocation_sigma=geolocation_sigma)
    out = Path(output)
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    with progress_bar("simulate", quiet=quiet) as progress:
        result, _ = simulate_photons_over_tiles(
            las, out, params, vertices=_vertices(line, polyline), azimuth=azimuth,
            centre=None if centre is None else _pair(centre, "x,y"), diameters=diameters,
            realisations=realisations, seed=seed, crs=crs,
            layout=fmt or ("mabel" if instrument == "mabel" else "atl03"),
            photon_table=photon_table, report=report, progress=progress)
    first = diameters[0] if diameters else params.diameter  # filled from the instrument
    sim = result.simulations[float(first or 0.0)]
    if quiet:
        return
    t = result.table
    # the seed-002 rule classifies every photon: with background it is not the seed's case
    flag = (" (the lowest/highest-photon rule applied to all photons, background noise "
            "included: the rule assumes none)" if params.background_rate_mhz > 0 else "")
    for _, r in t.iterrows():
        click.echo(
            f"canopyblocks: {r['diameter']:g} m footprint, {int(r['realisations'])} "
            f"realisations, {int(r['n_shots'])} shots: ground bias {r['ground_bias']:+.2f} m "
            f"rms {r['ground_rms']:.2f} m; canopy top bias {r['top_bias']:+.2f} m "
            f"rms {r['top_rms']:.2f} m{flag}", err=True)
    click.echo(f"canopyblocks: {len(sim.photon_columns(0)['h']):,} photons over "
               f"{sim.length:.0f} m -> {out}", err=True)


def _waveform_sensor(ctx: click.Context, las: tuple[str, ...], sensor: str,
                     azimuth: float | None, line: str | None, polyline: str | None,
                     centre: str | None, seed: int, crs: str | None, output: str,
                     report: str | None, shot_spacing: float | None = None,
                     dual_noise: float | None = None,
                     esfl_noise: float | None = None) -> None:
    """``--sensor gedi|esfl|dual``: one core call writing the HDF5 (and the report)."""
    from ..workflows.params import DualAlsParams, FlashSimParams, GediSimParams
    from ..workflows.simulate import simulate_sensor_over_tiles

    params: object = None
    if shot_spacing is not None:   # the footprint spacing of GEDI; the others have theirs
        if sensor != "gedi":
            raise click.BadParameter(f"applies to --sensor icesat2 and gedi, not {sensor}",
                                     param_hint="--shot-spacing")
        params = GediSimParams(spacing=shot_spacing)
    if dual_noise is not None:
        if sensor != "dual":
            raise click.BadParameter(f"applies to --sensor dual only, not {sensor}",
                                     param_hint="--dual-noise")
        params = DualAlsParams(noise=dual_noise)
    if esfl_noise is not None:
        if sensor != "esfl":
            raise click.BadParameter(f"applies to --sensor esfl only, not {sensor}",
                                     param_hint="--esfl-noise")
        params = FlashSimParams(noise_sd=esfl_noise)

    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    with progress_bar("simulate", quiet=quiet) as progress:
        track, summary = simulate_sensor_over_tiles(
            list(las), sensor, output, vertices=_vertices(line, polyline),
            azimuth=float(azimuth or 0.0),
            centre=None if centre is None else _pair(centre, "x,y"), seed=seed, crs=crs,
            report_dir=report, params=params, progress=progress)
    if quiet:
        return
    study = summary.get("study")
    if sensor == "gedi" and study is not None:
        for r in study.itertuples():  # type: ignore[attr-defined]
            click.echo(f"canopyblocks: simulated GEDI {r.metric:<6} vs truth ({r.truth}) "
                       f"n={r.n} bias={r.bias:+.2f} rmse={r.rmse:.2f}", err=True)
    click.echo(f"canopyblocks: {summary['footprints']} {sensor} footprints over "
               f"{track.length:.0f} m -> {output}", err=True)


def _background_rate(rate: float, light: str | None, noise_rate: float | None, *,
                     quiet: bool) -> float:
    """The background rate (MHz) from ``--background-rate``, ``--night``/``--day`` or the
    deprecated ``--noise-rate`` (given to SimParams as is, which converts and checks it)."""
    from ..workflows.params import BACKGROUND_PRESETS_MHZ

    given = [name for name, on in (("--background-rate", rate != 0.0),
                                   (f"--{light}", light is not None),
                                   ("--noise-rate", noise_rate is not None)) if on]
    if len(given) > 1:
        raise click.UsageError(f"give the background noise once; got {' and '.join(given)}")
    if noise_rate is not None and not quiet:
        click.echo("canopyblocks: --noise-rate is deprecated: use --background-rate in MHz "
                   "(1 MHz = 0.0067 photons per shot per metre)", err=True)
    if light is not None:
        return BACKGROUND_PRESETS_MHZ[light]
    return rate


def _parse(value: str, n: int, what: str) -> tuple[float, ...]:
    """:func:`parse_floats` of a given (not None) option value: ``n`` floats."""
    parts = _floats(value, n, what)
    if parts is None:  # parse_floats returns None only for None
        raise click.BadParameter(f"expected {what}; got {value!r}")
    return parts


def _pair(value: str, what: str) -> tuple[float, float]:
    """An ``x,y`` option value as two floats (metres)."""
    x, y = _parse(value, 2, what)
    return x, y


def _vertices(line: str | None, polyline: str | None) -> list[tuple[float, float]] | None:
    """The track's vertices (metres) from ``--line x0,y0,x1,y1`` or ``--polyline
    'x0,y0;x1,y1;...'``; None when neither is given (then ``--azimuth``)."""
    if line is not None:
        x0, y0, x1, y1 = _parse(line, 4, "x0,y0,x1,y1")
        return [(x0, y0), (x1, y1)]
    if polyline is None:
        return None
    verts = [_pair(part, "'x0,y0;x1,y1;...'") for part in polyline.split(";")]
    if len(verts) < 2:
        raise click.BadParameter(f"a polyline needs at least two vertices; got {polyline!r}")
    return verts


def register(group: click.Group) -> None:
    """Add ``simulate`` to ``group``."""
    group.add_command(simulate_cmd)
