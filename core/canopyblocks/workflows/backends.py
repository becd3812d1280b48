"""Where units run: in this process, in a local process pool, or on a Dask cluster.

Each backend calls ``fn(item)`` for every item and hands each result to ``done`` as it
arrives (in completion order); the caller orders results itself.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Literal

from ..errors import DependencyError, InputError

__all__ = ["Backend", "run_items", "BACKENDS", "default_workers", "keep_freed_memory",
           "DASK_WORKER_ENV"]

log = logging.getLogger(__name__)

Backend = Literal["serial", "processes", "dask"]
BACKENDS: tuple[str, ...] = ("serial", "processes", "dask")

#: Environment given to Dask workers started here. Dask's nanny sets
#: MALLOC_TRIM_THRESHOLD_=65536, which makes glibc return memory after every free; this
#: workload allocates and frees large numpy temporaries per unit and was measured 46 %
#: slower with it. The glibc default (dynamic threshold) is restored.
DASK_WORKER_ENV: dict[str, str] = {"MALLOC_TRIM_THRESHOLD_": str(128 * 1024 * 1024)}


def keep_freed_memory() -> bool:
    """Have glibc keep freed memory for reuse in this process (and the processes it forks).

    numpy's large temporaries are otherwise returned to the system when freed and the next
    one is faulted in again page by page; measured on three 2 M-photon beams read and
    blocked in turn, keeping them is 10 % faster for the same peak (``M_TRIM_THRESHOLD``
    1 GiB, ``M_MMAP_THRESHOLD`` 32 MiB, glibc's maximum).  Returns False where there is no
    glibc (nothing changes).
    """
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(mallopt(m_trim_threshold, 1 << 30)) and bool(mallopt(m_mmap_threshold, 32 << 20))


def default_workers() -> int:
    """The machine's cores (at least 1)."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else (os.cpu_count() or 1))


def run_items(fn: Callable[[Any], Any], items: Sequence[Any], *, backend: Backend = "serial",
              workers: int | None = None, scheduler: str | None = None,
              done: Callable[[Any], None] | None = None,
              cancelled: Callable[[], bool] | None = None,
              start: Literal["spawn", "fork", "forkserver"] = "spawn",
              tmpdir: str | None = None) -> list[Any]:
    """Run ``fn`` over ``items``; results in the order of ``items``.

    Parameters
    ----------
    backend : "serial", "processes" or "dask"
    workers : int, optional
        Processes (or Dask workers of a local cluster); default the machine's cores.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); with it no local
        cluster is started (dask-jobqueue, Kubernetes and the like work unchanged).
    done : callable, optional
        Called with each result as it completes.
    cancelled : callable, optional
        Polled between completions; True stops scheduling and cancels what is pending.
    start : "spawn", "fork" or "forkserver"
        How the ``processes`` backend starts its workers: ``spawn`` (a fresh interpreter
        that imports what ``fn`` needs, about 1 s each) or ``fork`` (a copy of this process
        with its imports; Linux only, and only when no HDF5 file is open here).
    tmpdir : str, optional
        A folder the caller owns and removes: workers (processes, or the workers of a
        local Dask cluster, with their scratch space) make their temporary files there,
        so that nothing is left in the system's temporary folder when a worker is killed.
    """
    if backend not in BACKENDS:
        raise InputError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
    n = workers or default_workers()
    if n < 1:
        raise InputError(f"workers must be >= 1, got {workers}")
    results: list[Any] = [None] * len(items)
    report = done or (lambda r: None)
    stop = cancelled or (lambda: False)
    if backend == "serial" or not items:
        for i, it in enumerate(items):
            if stop():
                break
            results[i] = fn(it)
            report(results[i])
        return results
    if tmpdir is not None and scheduler is None:
        fn = functools.partial(_in_tempdir, fn=fn, tmpdir=tmpdir)
    if backend == "processes":
        return _run_processes(fn, items, n, start, report, stop, results)
    return _run_dask(fn, items, n, scheduler, report, stop, results, tmpdir)


def _in_tempdir(item: Any, *, fn: Callable[[Any], Any], tmpdir: str) -> Any:
    """``fn(item)`` with :mod:`tempfile` making its files in ``tmpdir`` (in a worker)."""
    import tempfile

    os.makedirs(tmpdir, exist_ok=True)
    previous = tempfile.tempdir
    tempfile.tempdir = tmpdir
    try:
        return fn(item)
    finally:
        tempfile.tempdir = previous


def _run_processes(fn: Callable[[Any], Any], items: Sequence[Any], n: int, start: str,
                   report: Callable[[Any], None], stop: Callable[[], bool],
                   results: list[Any]) -> list[Any]:
    """The local process pool.

    Workers ignore Ctrl-C and end at SIGTERM after their clean-up (:func:`_worker_signals`:
    partial outputs and temporary folders removed, PDAL stopped): this process handles
    both and, on a cancellation (``stop`` is polled every 0.2 s, also while a unit runs) or
    any exception here (a unit's error, Ctrl-C, SIGTERM turned into an exception by the
    command line), terminates them and waits for their clean-up instead of letting them
    finish their units.  (``concurrent.futures`` was measured to hang, or to print a
    traceback at exit, when its workers are interrupted with the process group.)
    """
    import multiprocessing as mp

    if start not in mp.get_all_start_methods():
        start = "spawn"
    pool = mp.get_context(start).Pool(processes=min(n, len(items)),
                                      initializer=_worker_signals)
    try:
        pending = pool.imap_unordered(_indexed_call,
                                      [(fn, i, item) for i, item in enumerate(items)])
        for _ in range(len(items)):
            while True:
                if stop():
                    break
                try:
                    i, result = pending.next(timeout=0.2)
                except mp.TimeoutError:
                    continue
                results[i] = result
                report(result)
                break
            if stop():
                break
    except BaseException:
        pool.terminate()
        pool.join()
        raise
    if stop():
        pool.terminate()
    else:
        pool.close()
    pool.join()
    return results


def _worker_signals() -> None:
    """In a worker: Ctrl-C is the parent's to handle; SIGTERM (the parent's
    ``Pool.terminate``, or ``kill`` of the process group) ends an idle worker at once and a
    busy one through a ``SystemExit`` (:func:`_indexed_call`), so that its context managers
    run (atomic outputs and temporary folders removed, PDAL stopped) and it exits without a
    traceback."""
    import signal
    import sys

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    sys.unraisablehook = _quiet_exit_in_callback


def _quiet_exit_in_callback(unraisable: Any) -> None:
    """The SIGTERM's ``SystemExit`` landed in a callback (a weakref's, a ``__del__``),
    where Python ignores it: say nothing (the worker ends when its unit returns, or at the
    alarm)."""
    import sys

    if isinstance(unraisable.exc_value, SystemExit):
        return
    sys.__unraisablehook__(unraisable)


#: Seconds a worker has for its clean-up after SIGTERM before SIGALRM ends it.
_CLEANUP_GRACE_S = 30
#: Set in a worker by SIGTERM: the unit it runs is the last.
_terminating = False


def _exit_at_sigterm(signum: int, frame: object) -> None:
    """End a worker at SIGTERM through a ``SystemExit``, with two backstops.

    Python ignores an exception raised where it cannot propagate (a ``__del__``, a
    weak-reference or C callback: "Exception ignored in ..."), and a signal handler runs
    at whatever line the worker is on.  A swallowed ``SystemExit`` left the worker alive,
    SIGTERM ignored, blocked on the pool's queue, and the parent's ``Pool.terminate``
    waiting for it for ever (seen in the test suite, and as ``waveforms --workers 2`` on a
    damaged L1B hanging).  So the worker also ends when its unit returns
    (:func:`_indexed_call`), an idle worker ends at SIGTERM's default action, and
    SIGALRM's default action ends it after :data:`_CLEANUP_GRACE_S` whatever it does.
    """
    import signal

    global _terminating
    _terminating = True
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # once: the clean-up is not interrupted
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.alarm(_CLEANUP_GRACE_S)
    raise SystemExit(128 + signum)


def _indexed_call(job: tuple[Callable[[Any], Any], int, Any]) -> tuple[int, Any]:
    """``fn(item)`` in a worker, SIGTERM raising ``SystemExit`` only while it runs (idle,
    with nothing to clean up, the worker ends at SIGTERM's default action)."""
    import signal

    fn, i, item = job
    previous = signal.signal(signal.SIGTERM, _exit_at_sigterm)
    try:
        result = fn(item)
    finally:
        if _terminating:  # the SIGTERM's SystemExit was swallowed inside the unit
            raise SystemExit(143)  # noqa: B012 - the unit is over; nothing to return to
        signal.signal(signal.SIGTERM, previous)
    return i, result


@contextlib.contextmanager
def _workers_ignore_ctrl_c() -> Iterator[None]:
    """Start processes that ignore Ctrl-C (SIGINT), as the process pool's workers do.

    A signal ignored when a process starts stays ignored in it (also by Python and by
    asyncio, which install their handler only over the default one), so the local Dask
    workers are started with SIGINT ignored here; Ctrl-C of the process group then
    reaches only this process, which cancels the work and closes the cluster (the workers
    printed a KeyboardInterrupt traceback each).  Outside the main thread, or where
    signals cannot be set, nothing changes.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _run_dask(fn: Callable[[Any], Any], items: Sequence[Any], n: int, scheduler: str | None,
              report: Callable[[Any], None], stop: Callable[[], bool],
              results: list[Any], tmpdir: str | None = None) -> list[Any]:
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise DependencyError("the dask backend needs distributed: pip install "
                              "'canopyblocks[dask]'") from None
    import dask

    with (dask.config.set({"temporary-directory": tmpdir}) if tmpdir is not None
          else contextlib.nullcontext()):
        return _dask_session(fn, items, n, scheduler, report, stop, results, tmpdir,
                             Client, LocalCluster, as_completed)


def _dask_session(fn: Callable[[Any], Any], items: Sequence[Any], n: int,
                  scheduler: str | None, report: Callable[[Any], None],
                  stop: Callable[[], bool], results: list[Any], tmpdir: str | None,
                  Client: Any, LocalCluster: Any, as_completed: Any) -> list[Any]:  # noqa: N803
    cluster = None
    if scheduler is None:
        extra = {} if tmpdir is None else {"local_directory": tmpdir}
        # a unit's failure comes back in its result (run_unit never raises); what the
        # workers log is the cluster's own bookkeeping, e.g. a cancelled task or heartbeats
        # failing while a cancelled batch closes the cluster under a busy worker
        with _workers_ignore_ctrl_c():
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address=None, env=DASK_WORKER_ENV,
                                   silence_logs=logging.CRITICAL, **extra)
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        futs = client.map(fn, list(items), pure=False)
        index = {f.key: i for i, f in enumerate(futs)}
        pending = as_completed(futs)
        while not pending.is_empty():
            if stop():
                client.cancel(futs)
                break
            batch = pending.next_batch(block=False)
            if not batch:
                import time

                time.sleep(0.2)
                continue
            for fut in batch:
                results[index[fut.key]] = fut.result()
                report(results[index[fut.key]])
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return results
