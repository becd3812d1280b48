"""Logging of the command line: one line per message on stderr, above a progress bar."""

from __future__ import annotations

import logging
import sys
import warnings
from pathlib import Path
from typing import Any

import click

from ..errors import CanopyBlocksWarning


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
        if issubclass(category, CanopyBlocksWarning) or _ours(filename):
            _echo_above_bar(f"canopyblocks: warning: {text}")
        else:  # another package's warning (e.g. requests on urllib3's version): its name
            _echo_above_bar(f"warning from {_package_of(filename)} "
                            f"({category.__name__}): {text}")

    warnings.showwarning = _show  # one line per warning, never a source excerpt
    warnings.simplefilter("default", CanopyBlocksWarning)
    _quiet_numpy()


def _ours(filename: object) -> bool:
    """True when a warning was raised from canopyblocks' own code."""
    parts = Path(str(filename)).parts
    return "canopyblocks" in parts or "qgis_plugin" in parts


def _package_of(filename: object) -> str:
    """The top-level package a warning came from (``site-packages/<name>/...``)."""
    parts = Path(str(filename)).parts
    for anchor in ("site-packages", "dist-packages"):
        if anchor in parts and parts.index(anchor) + 1 < len(parts):
            return Path(parts[parts.index(anchor) + 1]).stem
    return Path(str(filename)).stem or "another package"


def is_quiet() -> bool:
    """True when the running command was given ``-q`` (no summaries, warnings only)."""
    ctx = click.get_current_context(silent=True)
    while ctx is not None:
        if isinstance(ctx.obj, dict) and ctx.obj.get("quiet"):
            return True
        ctx = ctx.parent
    return False


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
