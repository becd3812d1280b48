"""CLI command ``calibrate``: the paper's cut-offs, or a bias calibration of block heights."""

from __future__ import annotations

from typing import Any

import click

from ..options import SURVEY_SOURCES_HELP
from .common import (
    channel_option,
    explicit_value,
    lengths_option,
    min_signal_conf_option,
    parse_channel,
    preset_option,
    vertical_options,
)
from .options import option
from .progress_bars import progress_bar
from .sources import SurveySource


@click.command("calibrate")
@click.argument("photons", type=click.Path(dir_okay=False))
@click.option("--method", type=click.Choice(["cutoffs", "bias"]), default="cutoffs",
              show_default=True, help="cutoffs: fit the paper's top/ground window cut-offs "
              "(as the paper did); bias: fit an additive (or linear) correction of Hmax/H90 per "
              "length and beam strength for the chosen estimators.")
@click.option("--dtm", type=click.Path(dir_okay=False), help="Terrain GeoTIFF.")
@click.option("--dsm-max", type=click.Path(dir_okay=False), help="Maximum-surface GeoTIFF.")
@click.option("--dsm-p90", type=click.Path(dir_okay=False),
              help="90th-percentile surface GeoTIFF.")
@click.option("--reference", type=click.Choice(["corridor", "footprint"]), default="corridor",
              show_default=True, help="--method bias: corridor rasters or the "
              "footprint-matched airborne points (--points).")
@click.option("--points", multiple=True, type=SurveySource(),
              help=f"The airborne survey for --reference footprint: {SURVEY_SOURCES_HELP}.")
@click.option("--beam", "beams", multiple=True,
              help="ATL03 beam (repeatable; cutoffs: the first; bias: default every beam).")
@channel_option
@lengths_option(default="10, 25, 50")
@min_signal_conf_option
@preset_option("--method bias: the estimators the calibration is for; --method cutoffs "
               "calibrates the paper's method's cut-offs whatever the default.")
@click.option("--noise", type=click.Choice(["sigma", "conf", "density", "atl08", "none"]),
              default=None, help="--method bias: noise filter overriding the preset's (without "
              "--preset: replacing the paper's).")
@click.option("--ground-estimator", type=click.Choice(["paper", "surface"]), default=None)
@click.option("--top-estimator", type=click.Choice(["paper", "p95", "p98", "p99", "p100"]),
              default=None)
@click.option("--kind", type=click.Choice(["additive", "linear"]), default="additive",
              show_default=True, help="--method bias: correction form.")
@option("--width")
@option("--crs", help="Metric CRS of the photons' x/y (default: the DTM's).")
@vertical_options
@click.option("--photon-vcrs", default=None,
              help="Vertical datum of the photon heights (default: the file's; ATL03/MABEL "
                   "WGS84 ellipsoid).")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="cutoffs: the calibration table (.csv, .parquet or .gpkg); bias: the "
                   "calibration JSON (a CSV summary is written beside it).")
@click.pass_context
def calibrate_cmd(ctx: click.Context, photons: str, method: str, dtm: str | None,
                  dsm_max: str | None, dsm_p90: str | None, reference: str,
                  points: tuple[str, ...], beams: tuple[str, ...], channel: str | None,
                  lengths: tuple[float, ...], min_signal_conf: int | None, preset: str,
                  noise: str | None, ground_estimator: str | None,
                  top_estimator: str | None, kind: str, width: float | None, crs: str | None,
                  geoid: str | None, offset: float | None, photon_vcrs: str | None,
                  output: str | None) -> None:
    """Calibrate block heights of PHOTONS against airborne-lidar references.

    --method cutoffs: blocks are computed with the paper's cut-offs, their corridor
    reference values read from the rasters, and for each length the (top, ground)
    fractions that best match are searched (the paper calibrated its cut-offs this way).
    The RMSE columns are held out: cut-offs fitted on even blocks are scored on odd
    blocks and vice versa.

    --method bias: a correction of Hmax and H90 per block length and beam strength for
    the chosen estimators (--preset), with its held-out error; apply it with
    `canopyblocks blocks ... --preset P --calibration cal.json`.
    """
    from ..errors import InputError
    from ..workflows.params import BlockParams

    if output is not None:
        if method == "bias":
            if not output.lower().endswith(".json"):
                raise InputError(f"-o {output}: a bias calibration is written as JSON; "
                                 "name it *.json")
            from ..atomic import check_writable

            check_writable(output)
        else:
            from ..workflows.inputs import check_output_path

            check_output_path(output)  # fail before the work, not after it
    params = BlockParams(lengths=tuple(lengths) or (10.0, 25.0, 50.0),
                         min_signal_conf=min_signal_conf)
    given_preset: str | None = explicit_value(ctx, "preset", preset)
    quiet = bool(ctx.obj and ctx.obj.get("quiet"))
    if method == "bias":
        _bias(photons, params, quiet=quiet, dtm=dtm, dsm_max=dsm_max, dsm_p90=dsm_p90,
              reference=reference, points=points, beams=beams, channel=channel,
              preset=given_preset, noise=noise, ground_estimator=ground_estimator,
              top_estimator=top_estimator, min_signal_conf=min_signal_conf, kind=kind,
              width=width, crs=crs, geoid=geoid, offset=offset,
              photon_vcrs=photon_vcrs, output=output)
        return
    if dtm is None or dsm_max is None or dsm_p90 is None:
        raise InputError("--method cutoffs needs --dtm, --dsm-max and --dsm-p90")
    if given_preset not in (None, "paper") or noise not in (None, "sigma") or \
            ground_estimator not in (None, "paper") or top_estimator not in (None, "paper"):
        raise InputError("--method cutoffs calibrates the paper's cut-offs; other estimators "
                         "are calibrated with --method bias")
    from ..workflows.calibrate import calibrate_reference_rasters

    with progress_bar("calibrate", quiet=quiet) as progress:
        cal = calibrate_reference_rasters(
            photons, params, dtm=dtm, dsm_max=dsm_max, dsm_p90=dsm_p90,
            width=width, beam=beams[0] if beams else None,
            channel=parse_channel(channel), crs=crs, geoid=geoid, offset=offset,
            progress=progress)
    # the table is the command's result: on stdout, unless -q and it went to a file
    for row in ([] if quiet and output is not None else cal.table.itertuples()):
        click.echo(f"{row.length:>5g} m: top {row.top_cutoff:.3f} (paper {row.default_top_cutoff:.3f})"
                   f"  ground {row.ground_cutoff:.3f} (paper {row.default_ground_cutoff:.3f})"
                   f"  held-out Hmax RMSE {row.rmse_hmax_default:.2f} -> "
                   f"{row.rmse_hmax_calibrated:.2f} m (n={row.n_holdout})")
    if output is not None:
        from ..workflows.calibrate import write_cutoff_calibration

        write_cutoff_calibration(cal, output)
    if not quiet:
        click.echo("canopyblocks: use them one length at a time (the paper's method, which "
                   "the cut-offs are for), e.g.", err=True)
        for row in cal.table.itertuples():
            click.echo("  " + blocks_command(photons, row.length, row.top_cutoff,
                                             row.ground_cutoff, beam=beams[0] if beams else None,
                                             channel=channel, min_signal_conf=min_signal_conf),
                       err=True)


def blocks_command(photons: str, length: float, top: float, ground: float, *,
                   beam: str | None, channel: str | None, min_signal_conf: int | None) -> str:
    """The ``blocks`` command that computes the calibrated blocks of one length: the
    paper's method (the cut-offs are its windows) with the photons' options of the
    calibration."""
    import shlex

    words = ["canopyblocks", "blocks", photons, "--preset", "paper", "--length", f"{length:g}"]
    for name, value in (("--beam", beam), ("--channel", channel),
                        ("--min-signal-conf", min_signal_conf)):
        if value is not None:
            words += [name, str(value)]
    words += ["--top-cutoff", repr(float(top)), "--ground-cutoff", repr(float(ground)),
              "-o", f"blocks_{length:g}m.gpkg"]
    return shlex.join(words)


def _bias(photons: str, params: object, *, quiet: bool, output: str | None,
          preset: str | None, noise: str | None, ground_estimator: str | None,
          top_estimator: str | None, min_signal_conf: int | None, channel: str | None,
          photon_vcrs: str | None, **kw: Any) -> None:
    from ..options import ESTIMATOR_PRESETS
    from ..workflows.calibrate import calibrate_bias_file, write_bias_calibration
    from ..workflows.choices import estimators_from_options

    est = estimators_from_options(preset, noise, ground_estimator, top_estimator,
                                  min_signal_conf)
    with progress_bar("calibrate", quiet=quiet) as progress:
        cal = calibrate_bias_file(photons, params, est,  # type: ignore[arg-type]
                                  channel=parse_channel(channel),
                                  photon_vertical_crs=photon_vcrs, progress=progress, **kw)
    for row in ([] if quiet and output is not None else cal.table().itertuples()):
        click.echo(f"{row.metric:<5} {row.length:>5g} m {row.strength:<6}: "
                   f"{row.slope:.3f} x + {row.intercept:+.2f} m  held-out RMSE "
                   f"{row.holdout_rmse_before:.2f} -> {row.holdout_rmse_after:.2f} m "
                   f"(n={row.n})")
    if output is not None:
        write_bias_calibration(cal, output)
        if not quiet:
            click.echo(f"canopyblocks: apply it with `canopyblocks blocks PHOTONS --preset "
                       f"{est.name if est.name in ESTIMATOR_PRESETS else '...'} "
                       f"--calibration {output}`", err=True)


def register(group: click.Group) -> None:
    """Add ``calibrate`` to ``group``."""
    group.add_command(calibrate_cmd)
