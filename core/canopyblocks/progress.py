"""Progress reporting and cancellation, passed into long operations as callables.

The CLI wraps a progress bar, the QGIS plugin wraps ``QgsProcessingFeedback``;
the core only calls :meth:`Progress.update` and :meth:`Progress.check`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from .errors import CancelledError

__all__ = ["Progress", "ProgressCallback", "CancelCallback", "as_progress"]

ProgressCallback = Callable[[float, str], None]
"""Called with a fraction done in [0, 1] and a short message."""

CancelCallback = Callable[[], bool]
"""Returns True when the user asked to cancel."""


@dataclass
class Progress:
    """Progress sink and cancellation probe.

    Parameters
    ----------
    callback : callable, optional
        ``callback(fraction, message)``, fraction in [0, 1].
    cancelled : callable, optional
        Returns True when the operation should stop.
    start, span : float
        This object reports into the sub-range ``[start, start + span]`` of its
        parent's range; see :meth:`sub`.
    """

    callback: ProgressCallback | None = None
    cancelled: CancelCallback | None = None
    start: float = 0.0
    span: float = 1.0

    def update(self, fraction: float, message: str = "") -> None:
        """Report ``fraction`` (0..1) of this object's range done; raise if cancelled."""
        self.check()
        self.report(fraction, message)

    def report(self, fraction: float, message: str = "") -> None:
        """Report ``fraction`` (0..1) done without checking for cancellation.

        For the end of an operation whose outputs are already written: cancelling
        then would have nothing left to stop.
        """
        if self.callback is not None:
            f = min(max(float(fraction), 0.0), 1.0)
            self.callback(self.start + self.span * f, message)

    def check(self) -> None:
        """Raise :class:`~canopyblocks.errors.CancelledError` when cancellation was asked."""
        if self.cancelled is not None and self.cancelled():
            raise CancelledError("cancelled by the user; no output was written")

    def sub(self, start: float, end: float) -> Progress:
        """A child reporting into ``[start, end]`` (fractions of this object's range)."""
        return Progress(
            self.callback,
            self.cancelled,
            self.start + self.span * start,
            self.span * (end - start),
        )


def as_progress(progress: Progress | ProgressCallback | None) -> Progress:
    """Normalise ``None``, a bare callback, or a :class:`Progress` into a :class:`Progress`."""
    if progress is None:
        return Progress()
    if isinstance(progress, Progress):
        return progress
    if not callable(progress):
        from .errors import InputError
        raise InputError(f"progress must be a Progress, a callable(fraction, message) or "
                         f"None; got {type(progress).__name__} {str(progress)[:40]!r}")
    return Progress(callback=progress)
