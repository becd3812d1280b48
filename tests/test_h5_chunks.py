"""Chunks inflated on threads (readers/h5_chunks.py) against HDF5's own read of the same
datasets: every value equal, and every case that is not the plain one left to HDF5 (which
names a damaged file) rather than decoded wrongly."""

from __future__ import annotations

import zlib

import h5py
import numpy as np
import pytest

from canopyblocks.errors import FileFormatError
from canopyblocks.readers import h5_chunks
from canopyblocks.readers._h5 import open_h5
from canopyblocks.readers.h5_chunks import read_chunks

RNG = np.random.default_rng(7)
N = 103_457  # 11 chunks of 10,000, the last one partial


def _write(path, name="v", data=None, **kw):  # noqa: ANN001, ANN202
    data = RNG.normal(0, 100, N) if data is None else data
    with h5py.File(path, "w", **kw.pop("file_kw", {})) as f:
        f.create_dataset(name, data=data, **({"chunks": (10_000,) + data.shape[1:],
                                             "compression": "gzip"} | kw))
    return data


def _inflaters():  # noqa: ANN202
    out = [("zlib", lambda raw, size: zlib.decompress(raw, 15, size))]
    try:
        import deflate
    except ImportError:
        return out
    return [*out, ("libdeflate", lambda raw, size: deflate.zlib_decompress(raw, size))]


@pytest.fixture(params=_inflaters(), ids=lambda p: p[0])
def inflater(request, monkeypatch):  # noqa: ANN001, ANN201
    monkeypatch.setattr(h5_chunks, "INFLATE", request.param)
    return request.param[0]


@pytest.mark.parametrize("lo,hi", [(0, N), (1, N - 1), (9_999, 50_001), (40_000, 80_000),
                                   (3, 40_003)])
def test_slices_equal_hdf5(tmp_path, inflater, lo, hi):  # noqa: ANN001
    data = _write(tmp_path / "a.h5")
    with h5py.File(tmp_path / "a.h5", "r") as f:
        got = read_chunks(f["v"], lo, hi)
        assert got is not None
        np.testing.assert_array_equal(got, f["v"][lo:hi])
    np.testing.assert_array_equal(got, data[lo:hi])


@pytest.mark.parametrize("dtype", ["<f4", ">f4", ">i8", "<u2", "i1"])
def test_dtypes_shuffle_and_conversion(tmp_path, inflater, dtype):  # noqa: ANN001
    data = (RNG.normal(0, 50, N)).astype(dtype)
    _write(tmp_path / "b.h5", data=data, shuffle=True)
    with h5py.File(tmp_path / "b.h5", "r") as f:
        got = read_chunks(f["v"], 0, N)
        assert got is not None and got.dtype.isnative
        np.testing.assert_array_equal(got, data)
        if np.dtype(dtype).kind == "f":
            wide = read_chunks(f["v"], 5, N, np.dtype("f8"))
            assert wide is not None and wide.dtype == np.float64
            np.testing.assert_array_equal(wide, data[5:].astype("f8"))


def test_two_d_column_through_h5file(tmp_path, inflater):  # noqa: ANN001
    data = RNG.integers(-2, 5, (N, 5)).astype("i1")
    _write(tmp_path / "c.h5", data=data)
    with h5py.File(tmp_path / "c.h5", "r") as f:
        got = read_chunks(f["v"], 100, N)
        assert got is not None
        np.testing.assert_array_equal(got, data[100:])
        one = read_chunks(f["v"], 9_999, N - 1, np.dtype("i2"), column=3)
        assert one is not None and one.shape == (N - 10_000,) and one.dtype == np.int16
        np.testing.assert_array_equal(one, data[9_999:N - 1, 3])
        assert read_chunks(f["v"], 0, N, column=5) is None
    with open_h5(tmp_path / "c.h5") as h:
        np.testing.assert_array_equal(h.read_column("v", 7, N - 3, 2, np.int16),
                                      data[7:N - 3, 2])


@pytest.mark.parametrize("case", ["fletcher32", "contiguous", "scaleoffset", "userblock",
                                  "unallocated", "few_chunks", "row_chunks"])
def test_not_plain_left_to_hdf5(tmp_path, case):  # noqa: ANN001
    p = tmp_path / "d.h5"
    data = RNG.normal(0, 1, N)
    if case == "fletcher32":
        _write(p, data=data, fletcher32=True)
    elif case == "contiguous":
        with h5py.File(p, "w") as f:
            f.create_dataset("v", data=data)
    elif case == "scaleoffset":
        data = RNG.integers(0, 1000, N)
        _write(p, data=data, scaleoffset=0)
    elif case == "userblock":
        _write(p, data=data, file_kw={"userblock_size": 512})
    elif case == "unallocated":
        with h5py.File(p, "w") as f:
            d = f.create_dataset("v", shape=(N,), dtype="f8", chunks=(10_000,),
                                 compression="gzip", fillvalue=-1.0)
            d[:30_000] = data[:30_000]
            d[60_000:] = data[60_000:]
        data = data.copy()
        data[30_000:60_000] = -1.0
    elif case == "few_chunks":
        _write(p, data=data, chunks=(N,))
    elif case == "row_chunks":
        data = RNG.normal(0, 1, (N, 4))
        _write(p, data=data, chunks=(10_000, 2))
    with h5py.File(p, "r") as f:
        assert read_chunks(f["v"], 0, N) is None
    with open_h5(p) as h:  # the reader still reads it, through HDF5
        np.testing.assert_array_equal(h.read("v"), data)


def test_corrupt_chunk_is_refused_not_decoded(tmp_path, inflater):  # noqa: ANN001
    """Bytes damaged inside the fifth chunk: the threads give up and HDF5's read names the
    file -- no value of the damaged chunk comes back."""
    if not hasattr(h5py.h5d.DatasetID, "chunk_iter"):
        pytest.skip("h5py built on HDF5 before 1.12.3 has no chunk_iter to find the chunk")
    p = tmp_path / "e.h5"
    _write(p)
    with h5py.File(p, "r") as f:
        infos = []
        f["v"].id.chunk_iter(infos.append)
        c = sorted(infos, key=lambda i: i.chunk_offset)[4]
        assert read_chunks(f["v"], 0, N) is not None
    with open(p, "r+b") as fh:
        fh.seek(c.byte_offset + c.size // 2)
        b = fh.read(16)
        fh.seek(c.byte_offset + c.size // 2)
        fh.write(bytes(x ^ 0x5A for x in b))
    with h5py.File(p, "r") as f:
        assert read_chunks(f["v"], 0, N) is None
    with open_h5(p) as h, pytest.raises(FileFormatError, match="e.h5"):
        h.read("v")


def test_real_gedi_datasets_equal_hdf5(gedi_l1b, gedi_l2a):  # noqa: ANN001
    """The real GEDI L1B and L2A subsets (tests/data): every chunked dataset the threads
    take equals HDF5's read, whole and from an odd row on."""
    taken = 0
    for path in (gedi_l1b, gedi_l2a):
        with h5py.File(path, "r") as f:
            found: list[str] = []

            def chunked(n: str, o: object, found: list[str] = found) -> None:
                if isinstance(o, h5py.Dataset) and o.ndim in (1, 2) and o.chunks is not None:
                    found.append(n)
            f.visititems(chunked)
            for n in found:
                ds = f[n]
                for lo in (0, min(3, ds.shape[0])):
                    got = read_chunks(ds, lo, ds.shape[0])
                    if got is not None:
                        taken += 1
                        np.testing.assert_array_equal(got, ds[lo:])
    assert taken > 0


def test_many_tasks_equal_hdf5(tmp_path, inflater):  # noqa: ANN001
    """41 chunks: several tasks of the thread pool, each a batch of chunks."""
    data = RNG.normal(0, 1, 401_234)
    with h5py.File(tmp_path / "f.h5", "w") as f:
        f.create_dataset("v", data=data, chunks=(10_000,), compression="gzip", shuffle=True)
    with h5py.File(tmp_path / "f.h5", "r") as f:
        for lo, hi in ((0, data.size), (123_456, 398_765)):
            got = read_chunks(f["v"], lo, hi)
            assert got is not None
            np.testing.assert_array_equal(got, data[lo:hi])


@pytest.mark.parametrize("dtype,shape", [("i1", (N, 5)), ("<i4", (N,)), ("<u4", (N,)),
                                         ("<f8", (N,))])
def test_v006_layout_equals_hdf5(tmp_path, inflater, dtype, shape):  # noqa: ANN001
    """ATL03 v006 as written: gzip level 6 on every dataset, extendible (chunk index of a
    dataset with an unlimited dimension), the shuffle filter on the integer ones -- the
    2-D ``signal_conf_ph`` among them (see tests/data/icesat2/harmony_ATL03_gt1l.h5)."""
    data = RNG.integers(-3, 120, shape).astype(dtype)
    shuffle = np.dtype(dtype).kind in "iu"
    _write(tmp_path / "v6.h5", data=data, compression_opts=6, shuffle=shuffle,
           maxshape=(None, *shape[1:]))
    with h5py.File(tmp_path / "v6.h5", "r") as f:
        assert f["v"].shuffle == shuffle and f["v"].compression_opts == 6
        got = read_chunks(f["v"], 17, N)
        assert got is not None
        np.testing.assert_array_equal(got, data[17:])
        if len(shape) == 2:
            col = read_chunks(f["v"], 0, N - 5, np.dtype("i2"), column=1)
            assert col is not None
            np.testing.assert_array_equal(col, data[:N - 5, 1])
