"""Shared CLI pieces: the options several commands share and :func:`run_main`.

:func:`run_main` ties the concerns together: logging (``log_setup``), progress bars
(``progress_bars``), Ctrl-C and SIGTERM (``signals``), exit codes and one-line errors
(``exits``)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

import click

from ..errors import CanopyBlocksError
from ..options import ESTIMATOR_PRESETS, OPTIONS, RECOMMENDED_PRESET
from .exits import (
    EXIT_BAD_INPUT,
    EXIT_BUG,
    EXIT_OK,
    EXIT_OK_NO_WORK,
    EXIT_SIGINT,
    EXIT_SIGTERM,
    _error,
    _os_error_message,
)
from .log_setup import _quiet_numpy, is_quiet, setup_logging
from .options import option
from .progress_bars import progress_bar, summary
from .signals import (
    _ABORTED,
    _INTERRUPTED,
    _STATE,
    _forget_native_interrupt,
    _interrupted_message,
    _quiet_unraisable_interrupts,
    _signals_handled,
)
from .vocabulary import ChoiceWithOld

__all__ = ["lengths_option", "channel_option", "preset_option", "PRESET_CHOICES",
           "explicit_value", "WIDTH_HELP", "min_signal_conf_option", "vertical_options",
           "parse_floats", "parse_channel", "sensor_option", "SIMULATED_SENSORS", "run_main", "setup_logging", "progress_bar", "summary",
           "is_quiet", "EXIT_OK", "EXIT_BAD_INPUT", "EXIT_BUG", "EXIT_SIGINT", "EXIT_SIGTERM"]

F = TypeVar("F", bound=Callable[..., Any])


# ---- option definitions shared by several commands, built from the one vocabulary
# (canopyblocks.options; rasterio's rio keeps them in one place too)
def lengths_option(default: str) -> Callable[[F], F]:
    """``--length`` (repeatable, metres) -> ``lengths: tuple[float, ...]``."""
    return option("--length", "lengths",
                  help=f"Block length, m; repeat for several (default {default}).")


#: What ``simulate`` and ``run`` simulate: ICESat-2 photons or a waveform sensor's file.
SIMULATED_SENSORS: tuple[str, ...] = ("icesat2", "gedi", "esfl", "dual")


def sensor_option(help_text: str) -> Callable[[F], F]:
    """``--sensor``: what to simulate, the same names and default in every command."""
    return click.option("--sensor", type=click.Choice(list(SIMULATED_SENSORS)),
                        default="icesat2", show_default=True, help=help_text)


#: The block estimator presets every command offers, the default first (declared once in
#: ``canopyblocks.options``; ``blocks.estimators.PRESETS`` holds what each computes).
PRESET_CHOICES: tuple[str, ...] = ESTIMATOR_PRESETS
DEFAULT_PRESET = RECOMMENDED_PRESET
PRESET_HELP = OPTIONS["--preset"].help

#: ``--width`` help: the rule of ``reference.sensor_width`` (the same numbers; checked by
#: tests/test_defaults_walk.py).
WIDTH_HELP = OPTIONS["--width"].help


def preset_option(extra_help: str = "", *, dest: str = "preset",
                  old_values: tuple[str, ...] = ()) -> Callable[[F], F]:
    """``--preset``: the block estimators, the same names and default in every command;
    ``old_values`` are deprecated values still accepted (not shown)."""
    return option("--preset", dest, extra_help=extra_help,
                  type=ChoiceWithOld(ESTIMATOR_PRESETS, old_values))


def explicit_value(ctx: click.Context, name: str, value: Any) -> Any:
    """``value`` when the user gave option ``name`` (parameter name), None when it is the
    option's default."""
    from click.core import ParameterSource

    return None if ctx.get_parameter_source(name) == ParameterSource.DEFAULT else value


channel_option = option("--channel")
min_signal_conf_option = option("--min-signal-conf", type=click.IntRange(-2, 4))


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


def run_main(group: click.Group, argv: list[str] | None) -> int:
    """Run ``group``; map the project's errors to exit 2 with a one-line message.

    Usage errors and bad input (including an unwritable output and too little memory)
    end with exactly one line ``canopyblocks: error: ...`` on stderr (warnings may
    precede it) and exit status 2.  Ctrl-C (SIGINT) and SIGTERM end with one line and
    exit status 130 / 143; the line says which outputs, if any, were completed before
    the signal (a cancelled operation removes its partial files).  Anything else is a bug
    and keeps its traceback (exit status 1).
    """
    from ..atomic import journal_mark
    from ..workflows.backends import keep_freed_memory

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
