"""A request that every aiohttp time-out lets wait forever ends at the hard limit and is tried
again (CPython 3.11's sock_connect race, seen on loopback under load)."""

from __future__ import annotations

import asyncio
import time

import pytest

fsspec_asyn = pytest.importorskip("fsspec.asyn")


class _SlowFS(fsspec_asyn.AsyncFileSystem):
    """An asynchronous filesystem whose first ``stuck`` reads never answer."""

    protocol = "slowtest"

    def __init__(self, stuck: int, **kw: object) -> None:
        super().__init__(**kw)
        self.stuck = stuck
        self.calls = 0

    async def _cat_file(self, path: str, start: int | None = None, end: int | None = None,
                        **kw: object) -> bytes:
        self.calls += 1
        if self.calls <= self.stuck:
            await asyncio.sleep(3600)
        return b"abcdefgh"[start:end]


def test_a_stuck_call_ends_at_the_limit() -> None:
    from canopyblocks.readers.remote_guard import Stuck, guarded_call

    fs = _SlowFS(stuck=1, skip_instance_cache=True)
    t0 = time.monotonic()
    with pytest.raises(Stuck):
        guarded_call(fs, "cat_file", 0.5, "x", start=0, end=4)
    assert time.monotonic() - t0 < 5
    assert guarded_call(fs, "cat_file", 0.5, "x", start=2, end=5) == b"cde"


def test_a_stuck_call_is_worth_another_try() -> None:
    from canopyblocks.readers import remote
    from canopyblocks.readers.remote_guard import Stuck

    assert remote._transient(Stuck("no answer within 80 s"))
