"""Shared CLI pieces: logging set-up, progress bars, error -> exit-code mapping, options."""

from __future__ import annotations

import logging
import math
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import click

from ..errors import CanopyBlocksError, CanopyBlocksWarning
from ..progress import Progress

__all__ = ["lengths_option", "channel_option", "min_signal_conf_option", "vertical_options",
           "parse_floats", "parse_channel", "run_main", "setup_logging", "progress_bar", "summary",
           "is_quiet", "EXIT_OK", "EXIT_BAD_INPUT", "EXIT_BUG", "EXIT_SIGINT", "EXIT_SIGTERM"]

F = TypeVar("F", bound=Callable[..., Any])

EXIT_OK = 0
EXIT_BUG = 1
EXIT_BAD_INPUT = 2
EXIT_SIGINT = 130  # 128 + SIGINT: interrupted by Ctrl-C
EXIT_SIGTERM = 143  # 128 + SIGTERM: stopped by kill, timeout, SLURM, a container


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


def _echo_above_bar(line: str) -> None:
    """One line on stderr, above a running progress bar (not glued to its end)."""
    try:
        from tqdm import tqdm
    except ImportError:
        click.echo(line, err=True)
        return
    if getattr(tqdm, "_instances", None):
        tqdm.write(line, file=sys.stderr)
    else:
        click.echo(line, err=True)


class _StderrHandler(logging.StreamHandler):
    """A handler writing to whatever ``sys.stderr`` is now (test capture, redirections);
    a warning said once is not said again in the same run (every fold or track would
    repeat it)."""

    def __init__(self) -> None:
        super().__init__()
        self._said: set[str] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.WARNING:
            text = record.getMessage()
            if text in self._said:
                return False
            self._said.add(text)
        return bool(super().filter(record))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            _echo_above_bar(self.format(record))
        except Exception:  # logging must never raise
            self.handleError(record)

    @property
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, value: Any) -> None:
        pass


def setup_logging(verbose: int, quiet: bool) -> None:
    """Attach a stderr handler to the package logger (the library itself stays silent)."""
    level = logging.WARNING if quiet or verbose == 0 else (
        logging.INFO if verbose == 1 else logging.DEBUG)
    logger = logging.getLogger("canopyblocks")
    logger.setLevel(level)
    if not any(getattr(h, "_canopyblocks_cli", False) for h in logger.handlers):
        h = _StderrHandler()
        h.setFormatter(_CliFormatter())
        h._canopyblocks_cli = True  # type: ignore[attr-defined]
        logger.addHandler(h)

    said: set[str] = set()

    def _show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        text = str(message)
        if text in said:  # the same warning from every fold or track: say it once
            return
        said.add(text)
        _echo_above_bar(f"canopyblocks: warning: {text}")

    warnings.showwarning = _show  # one line per warning, never a source excerpt
    warnings.simplefilter("default", CanopyBlocksWarning)
    _quiet_numpy()


class _Interrupts:
    """What the signal handler knows: which signal came first, and what runs now.

    ``signum`` is the first SIGINT/SIGTERM of this run (None before any);
    ``operations`` counts the open :func:`progress_bar` blocks, where a signal first asks
    the operation to cancel (its :class:`Progress` raises
    :class:`~canopyblocks.errors.CancelledError` at its next check) and only after
    :data:`GRACE` seconds without an answer interrupts it (KeyboardInterrupt).
    """

    GRACE = 1.0
    """Seconds an operation has to notice a cancellation before it is interrupted."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.signum: int | None = None
        self.operations = 0
        self.raised_at = -math.inf
        self.timer: threading.Timer | None = None
        self.installed = False
        self.finishing = False
        self.noticed = False
        self.lock = threading.Lock()

    def reset(self) -> None:
        self.cancel_timer()
        self.event.clear()
        self.signum = None
        self.raised_at = -math.inf
        self.noticed = False

    def cancel_timer(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None

    def arm(self, delay: float) -> None:
        """Re-enter the handler ``delay`` seconds from now (from a helper thread)."""
        self.cancel_timer()
        t = threading.Timer(delay, self._fire)
        t.daemon = True
        self.timer = t
        t.start()

    def _fire(self) -> None:
        import _thread

        with self.lock:  # never after the handlers are restored (see _signals_handled)
            if self.installed and not self.finishing and not self.noticed:
                _thread.interrupt_main(signal.SIGINT)

    def handler(self, signum: int, frame: object) -> None:
        from ..outputs.atomic import committing

        first = self.signum is None
        if first:
            self.signum = signum
            self.event.set()
        if self.finishing:
            return
        if first and self.operations > 0:
            self.arm(self.GRACE)  # the operation's next Progress check cancels it
            return
        if committing():  # outputs are being renamed into place: let that finish
            self.arm(0.05)
            return
        now = time.monotonic()
        if now - self.raised_at < 3.0:
            # already interrupting: let the clean-up (temporary files, partial outputs)
            # run to its end instead of interrupting it in turn
            return
        self.raised_at = now
        raise KeyboardInterrupt

    def label(self) -> str:
        return "SIGTERM" if self.signum == signal.SIGTERM else "Ctrl-C"

    def exit_code(self) -> int:
        return 128 + int(self.signum if self.signum is not None else signal.SIGINT)


_STATE = _Interrupts()
_INTERRUPTED = _STATE.event  # set once SIGINT or SIGTERM arrived in this run


@contextmanager
def _signals_handled() -> Iterator[None]:
    """While inside: SIGINT and SIGTERM interrupt the run cleanly (see :class:`_Interrupts`).

    Installed by :func:`run_main` for a whole command (a SIGTERM from ``timeout``,
    ``kill``, SLURM or a container is handled like Ctrl-C: temporary and partial files are
    removed) and by :func:`progress_bar` when a command runs without :func:`run_main`.
    Only the main thread can install signal handlers; elsewhere this does nothing.  A
    signal the parent process ignores (SIGINT of a background job) stays ignored.
    """
    if _STATE.installed or threading.current_thread() is not threading.main_thread():
        yield
        return
    _STATE.reset()
    _STATE.finishing = False
    # a signal ignored by the parent stays ignored (e.g. SIGINT of a background job)
    previous = {s: signal.signal(s, _STATE.handler) for s in (signal.SIGINT, signal.SIGTERM)
                if signal.getsignal(s) is not signal.SIG_IGN}
    _STATE.installed = True
    try:
        yield
    finally:
        with _STATE.lock:
            _STATE.finishing = True
            _STATE.installed = False
            _STATE.cancel_timer()
        for s, h in previous.items():  # runs a signal still pending with our handler first
            signal.signal(s, h)


@contextmanager
def _ctrl_c_cancels() -> Iterator[None]:
    """While inside: the first Ctrl-C (SIGINT) or SIGTERM asks the running operation to cancel.

    A KeyboardInterrupt raised at an arbitrary byte code can land in a garbage-collector
    callback, where Python ignores it and the run goes on to "succeed".  Instead the
    signal sets a flag that :class:`Progress` checks; the operation then stops at its
    next check (at most a fraction of a second away: PDAL runs are polled), removing
    its partial outputs.  An operation that does not check within
    :attr:`_Interrupts.GRACE` seconds (a long numpy step, writing a file) is interrupted
    by a KeyboardInterrupt, as is any work outside an operation, and a second signal
    interrupts at once.
    """
    with _signals_handled():
        _STATE.operations += 1
        try:
            yield
        finally:
            _STATE.operations -= 1


def _cancelled() -> bool:
    """The Progress probe: True once a signal came; the operation then stops by itself."""
    if not _INTERRUPTED.is_set():
        return False
    with _STATE.lock:  # it noticed: no need to interrupt its clean-up
        _STATE.noticed = True
        _STATE.cancel_timer()
    return True


@contextmanager
def progress_bar(label: str, *, quiet: bool = False) -> Iterator[Progress]:
    """A :class:`Progress` that drives a tqdm bar on stderr (nothing when quiet/not a tty).

    Ctrl-C or SIGTERM inside the block cancels the operation through the Progress.
    """
    with _ctrl_c_cancels():
        if quiet:
            yield Progress(cancelled=_cancelled)
            return
        with _tqdm_progress(label) as progress:
            yield progress


def is_quiet() -> bool:
    """True when the running command was given ``-q`` (no summaries, warnings only)."""
    ctx = click.get_current_context(silent=True)
    while ctx is not None:
        if isinstance(ctx.obj, dict) and ctx.obj.get("quiet"):
            return True
        ctx = ctx.parent
    return False


def summary(message: str, *, err: bool = True) -> None:
    """Print a command's summary line (stderr by default); nothing under ``-q``."""
    if not is_quiet():
        click.echo(message, err=err)


@contextmanager
def _tqdm_progress(label: str) -> Iterator[Progress]:
    from tqdm import tqdm

    # a pseudo-terminal without a size (script, some CI and IDE consoles) reports 0
    # columns and rows, and tqdm then draws nothing: give it 80 x 24
    try:
        size = os.get_terminal_size(sys.stderr.fileno())
        cols, rows = size.columns, size.lines
    except (OSError, ValueError, AttributeError):
        cols = rows = 0
    bar = tqdm(total=1000, desc=label, unit="", leave=False, file=sys.stderr,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining} {postfix}",
               disable=None, ncols=None if cols > 0 else 80,
               nrows=None if rows > 0 else 24)

    def cb(fraction: float, message: str) -> None:
        n = int(round(fraction * 1000))
        if n > bar.n:
            bar.update(n - bar.n)
        if message:
            bar.set_postfix_str(message, refresh=False)

    try:
        yield Progress(callback=cb, cancelled=_cancelled)
    finally:
        bar.close()


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _error(message: object) -> None:
    """The single ``canopyblocks: error: ...`` line of a failed run."""
    click.echo(f"canopyblocks: error: {_one_line(str(message))}", err=True)


_NUMPY_NOISE = (r"invalid value encountered", r"divide by zero encountered",
                r"Mean of empty slice", r"All-NaN (slice|axis) encountered",
                r"Degrees of freedom <= 0")
"""numpy's RuntimeWarnings about NaN arithmetic: the core flags such results itself."""


def _quiet_numpy() -> None:
    for pattern in _NUMPY_NOISE:
        warnings.filterwarnings("ignore", message=pattern, category=RuntimeWarning)
    # a second, older mpl_toolkits on the path (Debian's, shared with QGIS) makes
    # matplotlib warn that it cannot import Axes3D; no plot of ours is 3-D
    warnings.filterwarnings("ignore", message=r"Unable to import Axes3D")


def run_main(group: click.Group, argv: list[str] | None) -> int:
    """Run ``group``; map the project's errors to exit 2 with a one-line message.

    Usage errors and bad input (including an unwritable output and too little memory)
    end with exactly one line ``canopyblocks: error: ...`` on stderr (warnings may
    precede it) and exit status 2.  Ctrl-C (SIGINT) and SIGTERM end with one line and
    exit status 130 / 143; the line says which outputs, if any, were completed before
    the signal (a cancelled operation removes its partial files).  Anything else is a bug
    and keeps its traceback (exit status 1).
    """
    from ..batch.backends import keep_freed_memory
    from ..outputs.atomic import journal_mark

    keep_freed_memory()
    mark = journal_mark()
    with warnings.catch_warnings(), _signals_handled(), _quiet_unraisable_interrupts():
        _quiet_numpy()
        try:
            try:
                code, message = _invoke(group, argv)
            finally:
                _STATE.finishing = True  # from here on a signal is only recorded
        except KeyboardInterrupt:
            code, message = EXIT_BAD_INPUT, None
        if _INTERRUPTED.is_set() and code != EXIT_OK_NO_WORK:
            _error(_interrupted_message(mark, f"interrupted ({_STATE.label()})"))
            _forget_native_interrupt()
            return _STATE.exit_code()
        if message is _ABORTED:
            message = _interrupted_message(mark, "aborted")
        if message is not None:
            _error(message)
        return EXIT_OK if code == EXIT_OK_NO_WORK else code


def _forget_native_interrupt() -> None:
    """Let the exit status be ours after an interrupt has been reported.

    When a KeyboardInterrupt passes through Python code that an extension module ran
    with the ``PyRun_*`` API, CPython 3.11 records it in ``_Py_UnhandledKeyboardInterrupt``
    and, at exit, kills the process with SIGINT whatever status ``sys.exit`` asked for
    (measured: 5 runs in 30 of ``rasters`` interrupted 0.3 s after start ended with -2
    after printing their one line, instead of exit status 130).  The interrupt has been
    handled here, so the record is cleared; on a Python without that symbol nothing
    changes.
    """
    import ctypes

    try:
        ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt").value = 0
    except (ValueError, AttributeError, OSError):
        pass


@contextmanager
def _quiet_unraisable_interrupts() -> Iterator[None]:
    """A KeyboardInterrupt that lands in a destructor or callback is not printed.

    Python cannot raise it there and prints "Exception ignored in ..." with a
    traceback instead; the run still stops (the signal's flag stays set), so the
    user sees only the one line of :func:`run_main`.
    """
    previous = sys.unraisablehook

    def hook(u: Any) -> None:
        if u.exc_type is not None and issubclass(u.exc_type, KeyboardInterrupt):
            return
        previous(u)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous


EXIT_OK_NO_WORK = -1  # internal: --help/--version and the like (nothing to interrupt)


_ABORTED = "aborted"  # internal: click's Abort, answered with _interrupted_message


def _interrupted_message(mark: int, what: str) -> str:
    """``what``, and truthfully which complete outputs this run left (or that none)."""
    from ..outputs.atomic import written_since

    kept = written_since(mark)
    if not kept:
        return f"{what}; no output was written"
    names = ", ".join(str(p) for p in kept[:5]) + (f" and {len(kept) - 5} more"
                                                  if len(kept) > 5 else "")
    return f"{what} after these complete outputs were written: {names}"


def _invoke(group: click.Group, argv: list[str] | None) -> tuple[int, str | None]:
    """Run the command; return its exit status and the error line to print (or None)."""
    try:
        group.main(args=argv, prog_name="canopyblocks", standalone_mode=False)
    except click.exceptions.Abort:  # click's name for a KeyboardInterrupt (or EOF at a prompt)
        return EXIT_BAD_INPUT, _ABORTED
    except click.UsageError as exc:  # usage errors: click's message, on one line
        path = exc.ctx.command_path if exc.ctx is not None else "canopyblocks"
        return EXIT_BAD_INPUT, f"{exc.format_message()} (see '{path} --help')"
    except click.exceptions.Exit as exc:
        return (EXIT_OK_NO_WORK if exc.exit_code == 0 else int(exc.exit_code)), None
    except click.ClickException as exc:
        return EXIT_BAD_INPUT, exc.format_message()
    except CanopyBlocksError as exc:
        return EXIT_BAD_INPUT, str(exc)
    except KeyboardInterrupt:
        return EXIT_BAD_INPUT, _ABORTED
    except MemoryError:
        return EXIT_BAD_INPUT, ("not enough memory for this run; use fewer or smaller "
                                "inputs, or parameters that make less data")
    except OSError as exc:  # the system refused a file operation (permissions, full disk)
        if _INTERRUPTED.is_set():
            return EXIT_BAD_INPUT, None
        return EXIT_BAD_INPUT, _os_error_message(exc)
    except Exception:
        if _INTERRUPTED.is_set():  # e.g. a library that the signal cut short
            return EXIT_BAD_INPUT, None
        raise
    return EXIT_OK, None


def _os_error_message(exc: OSError) -> str:
    name = exc.filename
    reason = exc.strerror or str(exc)
    if name is None:
        return f"{reason}; check the paths and their permissions, and the free disk space"
    return f"cannot use {name}: {reason}; check the path, its permissions and the free disk space"
