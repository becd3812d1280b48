"""Shared CLI pieces: logging set-up, progress bars, error -> exit-code mapping, options."""

from __future__ import annotations

import logging
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

import click

from ..errors import CancelledError, CanopyBlocksError, CanopyBlocksWarning
from ..progress import Progress

__all__ = ["parse_floats", "parse_channel", "run_main", "setup_logging", "progress_bar", "EXIT_OK", "EXIT_BAD_INPUT", "EXIT_BUG"]

EXIT_OK = 0
EXIT_BUG = 1
EXIT_BAD_INPUT = 2


def parse_floats(value: str | None, n: int, what: str) -> tuple[float, ...] | None:
    """Parse ``"a,b,..."`` into ``n`` floats (None stays None); a usage error otherwise."""
    if value is None:
        return None
    try:
        parts = tuple(float(v) for v in value.split(","))
    except ValueError:
        parts = ()
    if len(parts) != n:
        raise click.BadParameter(f"expected {what}; got {value!r}")
    return parts


def parse_channel(value: str | None) -> int | str | None:
    """A MABEL channel option: a number, ``"most"`` or None."""
    if value is None or value == "most":
        return value
    try:
        return int(value)
    except ValueError:
        raise click.BadParameter(f"expected a channel number or 'most'; got {value!r}") from None


class _CliFormatter(logging.Formatter):
    """``canopyblocks: warning: message`` for warnings and errors, plain text for info."""

    def format(self, record: logging.LogRecord) -> str:
        level = f"{record.levelname.lower()}: " if record.levelno >= logging.WARNING else ""
        return f"canopyblocks: {level}{record.getMessage()}"


def setup_logging(verbose: int, quiet: bool) -> None:
    """Attach a stderr handler to the package logger (the library itself stays silent)."""
    level = logging.WARNING if quiet or verbose == 0 else (
        logging.INFO if verbose == 1 else logging.DEBUG)
    logger = logging.getLogger("canopyblocks")
    logger.setLevel(level)
    if not any(getattr(h, "_canopyblocks_cli", False) for h in logger.handlers):
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(_CliFormatter())
        h._canopyblocks_cli = True  # type: ignore[attr-defined]
        logger.addHandler(h)

    def _show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        click.echo(f"canopyblocks: warning: {message}", err=True)

    warnings.showwarning = _show  # one line per warning, never a source excerpt
    warnings.simplefilter("default", CanopyBlocksWarning)


@contextmanager
def progress_bar(label: str, *, quiet: bool = False) -> Iterator[Progress]:
    """A :class:`Progress` that drives a tqdm bar on stderr (nothing when quiet/not a tty)."""
    if quiet:
        yield Progress()
        return
    from tqdm import tqdm

    bar = tqdm(total=1000, desc=label, unit="", leave=False, file=sys.stderr,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining} {postfix}",
               disable=None)

    def cb(fraction: float, message: str) -> None:
        n = int(round(fraction * 1000))
        if n > bar.n:
            bar.update(n - bar.n)
        if message:
            bar.set_postfix_str(message, refresh=False)

    try:
        yield Progress(callback=cb)
    finally:
        bar.close()


def run_main(group: click.Group, argv: list[str] | None) -> int:
    """Run ``group``; map the project's errors to exit 2 with a one-line message."""
    try:
        group.main(args=argv, prog_name="canopyblocks", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("canopyblocks: aborted", err=True)
        return EXIT_BAD_INPUT
    except click.ClickException as exc:  # usage errors: click's own message
        exc.show()
        return EXIT_BAD_INPUT
    except CancelledError as exc:
        click.echo(f"canopyblocks: {exc}", err=True)
        return EXIT_BAD_INPUT
    except CanopyBlocksError as exc:
        click.echo(f"canopyblocks: error: {exc}", err=True)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        click.echo("canopyblocks: interrupted; no output was written", err=True)
        return EXIT_BAD_INPUT
    except click.exceptions.Exit as exc:
        return int(exc.exit_code)
    return EXIT_OK
