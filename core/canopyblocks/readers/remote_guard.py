"""Guards for reads from storage: a hard limit on one call, no collection during HDF5's reads.

* CPython 3.11's ``sock_connect`` can miss the moment a connection completes and wait
  forever, under every aiohttp time-out.  :func:`guarded_call` runs the filesystem's
  coroutine on its own loop with a limit; past it, :class:`Stuck` is raised, which
  :mod:`canopyblocks.readers.remote` counts as worth another try.
* h5py holds one lock for every HDF5 call, also while HDF5 reads a granule in storage
  through its file object (which waits for the transport's thread, or for a server's).  A
  garbage collection that starts in that other thread and frees an h5py object waits for
  that lock: the read waits for the thread, the thread for the read, until the time-out
  (measured: most reads of a granule from a server in the same process stalled for the
  whole time-out, one in six failed).  :func:`no_collection` keeps automatic collections
  off while a granule in storage is open (reference counting still frees the rest).
"""

from __future__ import annotations

import contextlib
import gc
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["Stuck", "guarded_call", "no_collection"]

_GC_LOCK = threading.Lock()
#: [granules open under no_collection, whether collections were on before the first]
_GC_STATE: list[Any] = [0, False]


@contextlib.contextmanager
def no_collection() -> Iterator[None]:
    """No automatic garbage collection, in any thread, until the last of the nested or
    concurrent blocks ends (then as before the first)."""
    with _GC_LOCK:
        if _GC_STATE[0] == 0:
            _GC_STATE[1] = gc.isenabled()
            gc.disable()
        _GC_STATE[0] += 1
    try:
        yield
    finally:
        with _GC_LOCK:
            _GC_STATE[0] -= 1
            if _GC_STATE[0] == 0 and _GC_STATE[1]:
                gc.enable()


class Stuck(Exception):
    """A request past every time-out and the hard limit (a connection left waiting)."""


def guarded_call(fs: Any, method: str, limit: float, *args: Any, **kw: Any) -> Any:
    """``fs.<method>(*args, **kw)``; on an asynchronous filesystem at most ``limit`` seconds
    (then :class:`Stuck`); a synchronous one is called as it is."""
    coro = getattr(fs, "_" + method, None)
    if not getattr(fs, "async_impl", False) or coro is None or getattr(fs, "loop", None) is None:
        return getattr(fs, method)(*args, **kw)
    from fsspec.asyn import sync
    from fsspec.exceptions import FSTimeoutError

    try:
        return sync(fs.loop, coro, *args, timeout=limit, **kw)
    except FSTimeoutError:
        raise Stuck(f"no answer within {limit:g} s (a connection left waiting)") from None
