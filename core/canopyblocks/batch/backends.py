"""Where units run: in this process, in a local process pool, or on a Dask cluster.

Each backend calls ``fn(item)`` for every item and hands each result to ``done`` as it
arrives (in completion order); the caller orders results itself.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from typing import Any, Literal

from ..errors import DependencyError, InputError

__all__ = ["Backend", "run_items", "BACKENDS", "default_workers", "DASK_WORKER_ENV"]

log = logging.getLogger(__name__)

Backend = Literal["serial", "processes", "dask"]
BACKENDS: tuple[str, ...] = ("serial", "processes", "dask")

#: Environment given to Dask workers started here. Dask's nanny sets
#: MALLOC_TRIM_THRESHOLD_=65536, which makes glibc return memory after every free; this
#: workload allocates and frees large numpy temporaries per unit and was measured 46 %
#: slower with it. The glibc default (dynamic threshold) is restored.
DASK_WORKER_ENV: dict[str, str] = {"MALLOC_TRIM_THRESHOLD_": str(128 * 1024 * 1024)}


def default_workers() -> int:
    """The machine's cores (at least 1)."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else (os.cpu_count() or 1))


def run_items(fn: Callable[[Any], Any], items: Sequence[Any], *, backend: Backend = "serial",
              workers: int | None = None, scheduler: str | None = None,
              done: Callable[[Any], None] | None = None,
              cancelled: Callable[[], bool] | None = None) -> list[Any]:
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
    if backend == "processes":
        import concurrent.futures as cf
        import multiprocessing as mp

        with cf.ProcessPoolExecutor(max_workers=min(n, len(items)),
                                    mp_context=mp.get_context("spawn")) as pool:
            futs = {pool.submit(fn, it): i for i, it in enumerate(items)}
            for fut in cf.as_completed(futs):
                results[futs[fut]] = fut.result()
                report(results[futs[fut]])
                if stop():
                    for f in futs:
                        f.cancel()
                    break
        return results
    return _run_dask(fn, items, n, scheduler, report, stop, results)


def _run_dask(fn: Callable[[Any], Any], items: Sequence[Any], n: int, scheduler: str | None,
              report: Callable[[Any], None], stop: Callable[[], bool],
              results: list[Any]) -> list[Any]:
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise DependencyError("the dask backend needs distributed: pip install "
                              "'canopyblocks[dask]'") from None
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, env=DASK_WORKER_ENV,
                               silence_logs=logging.WARNING)
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        futs = client.map(fn, list(items), pure=False)
        index = {f.key: i for i, f in enumerate(futs)}
        for fut in as_completed(futs):
            results[index[fut.key]] = fut.result()
            report(results[index[fut.key]])
            if stop():
                client.cancel(futs)
                break
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return results
