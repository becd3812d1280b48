"""Shared CLI pieces: logging set-up, progress bars, error -> exit-code mapping, options."""

from __future__ import annotations

import logging
import math
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import click

from ..errors import CanopyBlocksError, CanopyBlocksWarning
from ..progress import Progress

__all__ = ["lengths_option", "channel_option", "min_signal_conf_option", "vertical_options",
           "parse_floats", "parse_channel", "run_main", "setup_logging", "progress_bar", "EXIT_OK", "EXIT_BAD_INPUT", "EXIT_BUG"]

F = TypeVar("F", bound=Callable[..., Any])

EXIT_OK = 0
EXIT_BUG = 1
EXIT_BAD_INPUT = 2


# ---- option definitions shared by several commands (rasterio's rio keeps them in one place too)
def lengths_option(default: str) -> Callable[[F], F]:
    """``--length`` (repeatable, metres) -> ``lengths: tuple[float, ...]``."""
    return click.option("--length", "lengths", multiple=True, type=float,
                        help=f"Block length, m; repeat for several (default {default}).")


channel_option = click.option("--channel", default=None,
                              help="MABEL channel number, or 'most' (the default).")
min_signal_conf_option = click.option(
    "--min-signal-conf", type=click.IntRange(-2, 4), default=None,
    help="ATL03: keep photons with land signal_conf_ph >= this before the noise filter.")


def vertical_options(f: F) -> F:
    """``--geoid`` and ``--offset``: how ellipsoidal photon heights meet the reference datum."""
    f = click.option("--offset", type=float, default=None,
                     help="Constant N = h_photon - H_reference, m (0 when they share a "
                          "datum), instead of a geoid raster.")(f)
    return click.option("--geoid", type=click.Path(dir_okay=False), default=None,
                        help="Geoid height raster N (m above the ellipsoid): "
                             "H = h_photon - N.")(f)


def parse_floats(value: str | None, n: int, what: str,
                 option: str | None = None) -> tuple[float, ...] | None:
    """Parse ``"a,b,..."`` into ``n`` finite floats (None stays None); a usage error otherwise.

    ``option`` (e.g. ``"--bbox"``) is named in the message.
    """
    if value is None:
        return None
    try:
        parts = tuple(float(v) for v in value.split(","))
    except ValueError:
        parts = ()
    if len(parts) != n or not all(math.isfinite(v) for v in parts):
        raise click.BadParameter(f"expected {what} (finite numbers); got {value!r}",
                                 param_hint=option)
    return parts


def parse_channel(value: str | None) -> int | str | None:
    """A MABEL channel option: a number, ``"most"`` or None."""
    if value is None or value == "most":
        return value
    try:
        return int(value)
    except ValueError:
        raise click.BadParameter(f"expected a channel number or 'most'; got {value!r}",
                                 param_hint="--channel") from None


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


_INTERRUPTED = threading.Event()


@contextmanager
def _ctrl_c_cancels() -> Iterator[None]:
    """While inside: the first Ctrl-C (SIGINT) asks the running operation to cancel.

    A KeyboardInterrupt raised at an arbitrary byte code can land in a garbage-collector
    callback, where Python ignores it and the run goes on to "succeed".  Instead the
    signal sets a flag that :class:`Progress` checks; the operation then stops at its
    next check (at most a fraction of a second away: PDAL runs are polled), removing
    its partial outputs.  A second Ctrl-C interrupts at once.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        if _INTERRUPTED.is_set():
            raise KeyboardInterrupt
        _INTERRUPTED.set()

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextmanager
def progress_bar(label: str, *, quiet: bool = False) -> Iterator[Progress]:
    """A :class:`Progress` that drives a tqdm bar on stderr (nothing when quiet/not a tty).

    Ctrl-C inside the block cancels the operation through the Progress.
    """
    with _ctrl_c_cancels():
        if quiet:
            yield Progress(cancelled=_INTERRUPTED.is_set)
            return
        with _tqdm_progress(label) as progress:
            yield progress


@contextmanager
def _tqdm_progress(label: str) -> Iterator[Progress]:
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
        yield Progress(callback=cb, cancelled=_INTERRUPTED.is_set)
    finally:
        bar.close()


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _error(message: object) -> None:
    """The single ``canopyblocks: error: ...`` line of a failed run."""
    click.echo(f"canopyblocks: error: {_one_line(str(message))}", err=True)


def run_main(group: click.Group, argv: list[str] | None) -> int:
    """Run ``group``; map the project's errors to exit 2 with a one-line message.

    Usage errors, bad input, cancellation and Ctrl-C all end with exactly one line
    ``canopyblocks: error: ...`` on stderr (warnings may precede it) and exit status 2;
    anything else is a bug and keeps its traceback (exit status 1).
    """
    _INTERRUPTED.clear()
    try:
        group.main(args=argv, prog_name="canopyblocks", standalone_mode=False)
    except click.exceptions.Abort:
        _error("aborted; no output was written")
        return EXIT_BAD_INPUT
    except click.UsageError as exc:  # usage errors: click's message, on one line
        path = exc.ctx.command_path if exc.ctx is not None else "canopyblocks"
        _error(f"{exc.format_message()} (see '{path} --help')")
        return EXIT_BAD_INPUT
    except click.ClickException as exc:
        _error(exc.format_message())
        return EXIT_BAD_INPUT
    except CanopyBlocksError as exc:
        if _INTERRUPTED.is_set():  # e.g. PDAL, which got the Ctrl-C too, failed first
            _error("interrupted (Ctrl-C); no output was written")
        else:
            _error(exc)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        _error("interrupted (Ctrl-C); no output was written")
        return EXIT_BAD_INPUT
    except click.exceptions.Exit as exc:
        return int(exc.exit_code)
    return EXIT_OK
