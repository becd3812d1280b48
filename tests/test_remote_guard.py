"""A request that every aiohttp time-out lets wait forever ends at the hard limit and is tried
again (CPython 3.11's sock_connect race, seen on loopback under load); no garbage collection
starts in another thread while HDF5 reads a granule from storage."""

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


def test_no_collection_in_another_thread_while_hdf5_reads(tmp_path, sample, monkeypatch) -> None:
    """A collection in another thread (the transport's, a server's) that frees an h5py object
    waits for h5py's lock, which HDF5 holds while it waits for that thread's answer: with
    collections on, the read stalls for the whole time-out (and over s3:// fails).  Here
    the h5py objects become garbage in the server's thread in the middle of the read."""
    import gc
    import shutil

    h5py = pytest.importorskip("h5py")
    pytest.importorskip("aiohttp")
    from canopyblocks.readers import read_atl03, remote
    from loopback_servers import RangeHTTPServer

    granule = sample("icesat2/vegr_atl03_clip.h5")
    (tmp_path / "collect").mkdir()
    shutil.copy(granule, tmp_path / "collect" / "granule.h5")
    monkeypatch.setenv("CANOPYBLOCKS_TIMEOUT", "3")
    monkeypatch.setattr(remote, "BACKOFF", 0.01)
    remote.clear_cache()
    assert gc.isenabled()
    with RangeHTTPServer(tmp_path) as server:
        for _ in range(3):
            cycle: list = [h5py.File(granule, "r")]
            cycle.append(cycle)
            server.garbage.append(cycle)
        del cycle
        got = read_atl03(f"{server.url}/collect/granule.h5", "gt1r")
        assert server.garbage == []  # dropped in the middle of the read
        assert server.collections == [False]  # and no collection could start there
    assert gc.isenabled()  # on again once the granule is closed
    assert gc.collect() >= 3  # the cycles, collected here
    want = read_atl03(granule, "gt1r")
    assert len(got) == len(want) > 0 and (got.h == want.h).all()
