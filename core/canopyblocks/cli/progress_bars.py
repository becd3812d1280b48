"""Progress bars of the command line (tqdm on a terminal, nothing when quiet)."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import click

from ..progress import Progress
from .log_setup import is_quiet
from .signals import _cancelled, _ctrl_c_cancels


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
