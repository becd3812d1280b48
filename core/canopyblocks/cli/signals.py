"""Ctrl-C and SIGTERM on the command line: cancel the running step, exit with one line."""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


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
        from ..atomic import committing

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


_ABORTED = "aborted"  # internal: click's Abort, answered with _interrupted_message


def _interrupted_message(mark: int, what: str) -> str:
    """``what``, and truthfully which complete outputs this run left (or that none)."""
    from ..atomic import written_since

    kept = written_since(mark)
    if not kept:
        return f"{what}; no output was written"
    names = ", ".join(str(p) for p in kept[:5]) + (f" and {len(kept) - 5} more"
                                                  if len(kept) > 5 else "")
    return f"{what} after these complete outputs were written: {names}"
