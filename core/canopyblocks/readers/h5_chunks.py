"""Deflate-compressed HDF5 datasets read chunk by chunk, decompressed on several threads.

ATL03 and GEDI granules store every per-photon (per-shot) dataset in gzip chunks of ~10,000
values.  HDF5 inflates them one after the other on one thread, inside a library lock, so
reading a beam costs the inflation of every chunk in series.  Here HDF5 is asked only where
each chunk lies in the file; the compressed bytes are read with ``os.pread`` and inflated on
a small pool of threads (zlib releases the GIL), with libdeflate (the optional ``deflate``
package, ``pip install canopyblocks[fast]``) when it is installed -- about twice as fast as
zlib per chunk -- and the standard library's zlib otherwise.  Both give the same bytes.

Only the plain case is taken: a 1-D dataset, or a 2-D dataset chunked along its first axis
only, in a file opened with the default driver and no user block, whose filters are deflate
and optionally shuffle, every chunk allocated and none with a filter skipped.  Anything else
(and any failure: a short read, corrupt bytes) returns ``None`` so that the caller reads the
dataset through HDF5, which names the problem.  The first chunk is checked against HDF5's own
read, so a file whose chunk addresses are not what is assumed here is never decoded wrongly.
"""

from __future__ import annotations

import os
import zlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from ..errors import FileFormatError

__all__ = ["read_chunks", "inflate_threads", "INFLATE"]

_DEFLATE, _SHUFFLE = 1, 2
#: Largest number of chunks located one by one (``get_chunk_info`` is linear in the index
#: on HDF5 < 1.12.3, which has no ``chunk_iter``); more and HDF5 reads the dataset.
_MAX_INDEXED = 1024
#: Least number of chunks worth a thread pool.
_MIN_CHUNKS = 4
#: Chunks inflated by one task of the pool.
_BATCH = 16
#: Compressed bytes fetched at a time from object storage (then inflated on threads).
_FETCH_BYTES = 1 << 26


def _inflater() -> tuple[str, Callable[[bytes, int], bytes | bytearray]]:
    try:
        import deflate
    except ImportError:
        return "zlib", lambda raw, size: zlib.decompress(raw, 15, size)
    return "libdeflate", lambda raw, size: deflate.zlib_decompress(raw, size)


#: (name, function(compressed bytes, uncompressed size) -> bytes) used to inflate chunks.
INFLATE = _inflater()


def inflate_threads() -> int:
    """Threads that inflate chunks: the cores this process may use (at most 4)."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    return max(1, min(4, n))


def _filters_ok(ds: Any) -> bool | None:
    """True: deflate (+ shuffle first); None: not the plain case."""
    try:
        plist = ds.id.get_create_plist()
        codes = [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]
    except Exception:  # noqa: BLE001 -- any h5py oddity: HDF5 reads it
        return None
    if codes == [_DEFLATE]:
        return False
    if codes == [_SHUFFLE, _DEFLATE]:
        return True
    return None


def _chunk_table(ds: Any, n_rows: int, rows: int) -> list[tuple[int, int, int]] | None:
    """(first row, byte offset, size) of every chunk of ``rows`` rows, in row order; None
    when not plain (a chunk missing, a filter skipped)."""
    dsid = ds.id
    infos: list[Any] = []
    try:
        if hasattr(dsid, "chunk_iter"):
            dsid.chunk_iter(infos.append)
        else:
            n = int(dsid.get_num_chunks())
            if n > _MAX_INDEXED:
                return None
            infos = [dsid.get_chunk_info(i) for i in range(n)]
    except Exception:  # noqa: BLE001
        return None
    if any(int(c.filter_mask) != 0 for c in infos):
        return None
    table = sorted((int(c.chunk_offset[0]), int(c.byte_offset), int(c.size)) for c in infos)
    if [t[0] for t in table] != list(range(0, n_rows, rows)):
        return None
    return table


def read_chunks(ds: Any, lo: int, hi: int, dtype: np.dtype | None = None,
                column: int | None = None, *,
                fetch: Callable[[list[tuple[int, int]]], list[bytes]] | None = None
                ) -> np.ndarray | None:
    """Rows ``lo:hi`` of dataset ``ds`` (an open h5py dataset), inflated on threads.

    Parameters
    ----------
    ds : h5py.Dataset
    lo, hi : int
        Row range (``0 <= lo <= hi <= len(ds)``).
    dtype : numpy dtype, optional
        Convert to it (the caller has checked that the conversion is lossless).
    column : int, optional
        Of a 2-D dataset only this column (a 1-D array; no full-width copy is made).
    fetch : callable, optional
        For a file HDF5 reads through a file object (a granule in object storage):
        ``fetch([(start, end), ...]) -> [bytes, ...]`` gives the bytes of byte ranges
        (coalesced and concurrent, :meth:`canopyblocks.readers.remote.RemoteFile.fetch`);
        the chunks are fetched ``_FETCH_BYTES`` at a time, then inflated on threads.

    Returns
    -------
    ndarray or None
        The rows, or None when the dataset is not the plain case (read it through HDF5).
    """
    shape = tuple(int(v) for v in (ds.shape or ()))
    chunks = ds.chunks
    if (len(shape) not in (1, 2) or chunks is None or tuple(chunks[1:]) != shape[1:]
            or not 0 <= lo <= hi <= shape[0]
            or (column is not None and (len(shape) != 2 or not 0 <= column < shape[1]))):
        return None
    f = ds.file
    driver = getattr(f, "driver", None)
    if getattr(f, "userblock_size", 1) != 0 or not (
            driver == "sec2" or (driver == "fileobj" and fetch is not None)):
        return None
    shuffle = _filters_ok(ds)
    if shuffle is None:
        return None
    src = np.dtype(ds.dtype)
    if src.kind not in "biuf" or src.hasobject:
        return None
    rows = int(chunks[0])
    first, last = lo // rows, -(-hi // rows)
    if last - first < _MIN_CHUNKS:
        return None
    table = _chunk_table(ds, shape[0], rows)
    if table is None:
        return None
    per_row = int(np.prod(shape[1:], dtype=np.int64))
    size = rows * per_row * src.itemsize
    dst = src.newbyteorder("=") if dtype is None else np.dtype(dtype)
    # converted chunk by chunk (float32 -> float64, big- -> little-endian): no full-length
    # array of the file's type
    pick = (slice(None),) if column is None else (slice(None), column)
    out = np.empty((hi - lo, *shape[1:]) if column is None else (hi - lo,), dtype=dst)
    _name, inflate = INFLATE
    fetched: dict[int, bytes] = {}
    if fetch is not None:
        fd = -1
    else:
        try:
            fd = os.open(f.filename, os.O_RDONLY)
        except OSError:
            return None

    def chunk(i: int) -> None:
        start, offset, nbytes = table[i]
        raw = fetched.pop(i) if fetch is not None else os.pread(fd, nbytes, offset)
        if len(raw) != nbytes:
            raise ValueError("short read")
        data = np.frombuffer(inflate(raw, size), np.uint8)
        if data.size != size:
            raise ValueError("chunk of the wrong size")
        if shuffle:
            data = data.reshape(src.itemsize, -1).T.reshape(-1)
        values = data.view(src).reshape(rows, *shape[1:])
        a, b = max(lo, start), min(hi, start + rows)
        out[a - lo:b - lo] = values[a - start:b - start][pick]

    stop = [last]  # the end of the chunks fetched so far

    def batch(i0: int) -> None:  # a batch of chunks per task: futures cost ~20 us each
        for i in range(i0, min(stop[0], i0 + _BATCH)):
            chunk(i)

    def prefetch(i0: int, i1: int) -> None:
        if fetch is not None:
            want = range(i0, i1)
            for i, raw in zip(want, fetch([(table[i][1], table[i][1] + table[i][2])
                                           for i in want])):
                fetched[i] = raw

    try:
        prefetch(first, first + 1)
        chunk(first)
        n_check = min(hi, (first + 1) * rows) - lo
        check = np.empty((n_check, *shape[1:]), dtype=src)
        ds.read_direct(check, np.s_[lo:lo + n_check])
        if check[pick].astype(dst).tobytes() != out[:n_check].tobytes():
            return None
        pool = ThreadPoolExecutor(inflate_threads())
        try:
            i0 = first + 1
            while i0 < last:  # (local files: one step; storage: _FETCH_BYTES at a time)
                i1 = last
                if fetch is not None:
                    sizes = np.cumsum([table[i][2] for i in range(i0, last)])
                    i1 = i0 + max(1, int(np.searchsorted(sizes, _FETCH_BYTES)))
                    prefetch(i0, i1)
                stop[0] = i1
                for _ in pool.map(batch, range(i0, i1, _BATCH)):
                    pass
                i0 = i1
        finally:  # Ctrl-C: the chunks not started are dropped
            pool.shutdown(wait=True, cancel_futures=True)
    except FileFormatError:
        raise  # storage failed (after its retries): said once, in its own words
    except Exception:  # noqa: BLE001 -- short file, corrupt bytes: HDF5 decides
        return None
    finally:
        if fd >= 0:
            os.close(fd)
    return out
