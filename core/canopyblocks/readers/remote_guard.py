"""A hard limit on one call of an asynchronous filesystem (s3fs, fsspec's HTTP).

CPython 3.11's ``sock_connect`` can miss the moment a connection completes and wait forever,
under every aiohttp time-out (seen on loopback under load).  :func:`guarded_call` runs the
filesystem's coroutine on its own loop with a limit; past it, :class:`Stuck` is raised, which
:mod:`canopyblocks.readers.remote` counts as worth another try.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Stuck", "guarded_call"]


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
