"""The ``canopyblocks`` command line: a thin click front-end over the core.

Each command family lives in its own module with a ``register(group)`` function.
"""

from __future__ import annotations

import click

from .. import __version__
from . import (
    batch,
    blocks,
    calibrate,
    chain,
    coregister,
    footprint_validation,
    reference,
    segments,
    simulate,
    validate,
    waveforms,
)
from .common import run_main


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="canopyblocks")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bars, warnings only.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: bool) -> None:
    """Canopy height and ground from lidar profiles -- per along-track block from
    photon-counting lidar (ICESat-2 ATL03, MABEL), per footprint from full-waveform lidar
    (GEDI L1B) -- validated against airborne lidar."""
    from .log_setup import setup_logging

    ctx.ensure_object(dict)
    ctx.obj["quiet"] = quiet
    setup_logging(verbose, quiet)


for _module in (blocks, reference, validate, footprint_validation, coregister, calibrate,
                simulate, chain, batch, waveforms, segments):
    _module.register(cli)


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point; returns the exit status (0 ok, 2 bad input, 1 bug)."""
    return run_main(cli, argv)


__all__ = ["cli", "main"]
