"""Exit codes of the command line and the one-line error messages it prints."""

from __future__ import annotations

import click

EXIT_OK = 0
EXIT_BUG = 1
EXIT_BAD_INPUT = 2
EXIT_SIGINT = 130  # 128 + SIGINT: interrupted by Ctrl-C
EXIT_SIGTERM = 143  # 128 + SIGTERM: stopped by kill, timeout, SLURM, a container


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _error(message: object) -> None:
    """The single ``canopyblocks: error: ...`` line of a failed run."""
    click.echo(f"canopyblocks: error: {_one_line(str(message))}", err=True)


EXIT_OK_NO_WORK = -1  # internal: --help/--version and the like (nothing to interrupt)


def _os_error_message(exc: OSError) -> str:
    name = exc.filename
    reason = exc.strerror or str(exc)
    if name is None:
        return f"{reason}; check the paths and their permissions, and the free disk space"
    return f"cannot use {name}: {reason}; check the path, its permissions and the free disk space"
