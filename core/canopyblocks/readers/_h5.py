"""The one place where h5py is touched: safe opening, reading and attribute decoding.

Every h5py/OS error (missing file, not HDF5, truncated file, missing group or
dataset, unreadable chunk) becomes a :class:`~canopyblocks.errors.FileFormatError`
that names the file and what is missing, so no h5py traceback reaches a user.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from ..errors import FileFormatError, InputError
from .h5_chunks import read_chunks

__all__ = ["H5File", "open_h5", "decode_attr", "HDF5_SIGNATURE", "DamagedFileError"]

log = logging.getLogger(__name__)

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"

_H5_ERRORS = (OSError, KeyError, RuntimeError, ValueError)


class DamagedFileError(FileFormatError):
    """An HDF5 file whose own structures cannot be read where it says they are (damaged,
    not a different product nor a subset): no reader should try it as another kind."""


def _import_h5py() -> Any:
    import h5py

    return h5py


def decode_attr(value: object) -> object:
    """Turn an HDF5 attribute value into a plain Python value.

    Real ICESat-2 files store strings three ways: fixed-length bytes scalars
    (``b'weak'``), variable-length strings in a one-element object array
    (``array(['weak'], dtype=object)``), and plain ``str``.  All become ``str``;
    one-element numeric arrays become Python scalars.
    """
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace").strip("\x00 ")
    if isinstance(value, np.ndarray):
        if value.size == 1:
            return decode_attr(value.reshape(-1)[0])
        return [decode_attr(v) for v in value.reshape(-1)]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, str):
        return value.strip("\x00 ")
    return value


def _looks_like_hdf5(path: Path) -> bool:
    """True when the HDF5 signature is at offset 0, 512, 1024, ... (user block)."""
    try:
        size = path.stat().st_size
        with path.open("rb") as fh:
            off = 0
            while off + 8 <= size and off <= 1 << 20:
                fh.seek(off)
                if fh.read(8) == HDF5_SIGNATURE:
                    return True
                off = 512 if off == 0 else off * 2
    except OSError:
        return False
    return False


class H5File:
    """An open HDF5 file whose every access raises :class:`FileFormatError` on failure.

    Use :func:`open_h5` to get one.  Paths inside the file are strings such as
    ``"gt1r/heights/h_ph"``.
    """

    def __init__(self, handle: Any, path: Path | str, product: str = "HDF5",
                 source: Any = None) -> None:
        self._f = handle
        self.path = path  # a URL (without its query string) for a granule in storage
        self.product = product
        self._source = source  # a readers.remote.RemoteFile, or None

    # ---------------------------------------------------------------- helpers
    def _fail(self, what: str, exc: BaseException | None = None) -> FileFormatError:
        remote = getattr(self._source, "error", None)
        if isinstance(remote, FileFormatError):  # storage failed, not the file
            return remote
        tail = f" ({type(exc).__name__}: {exc})" if exc is not None else ""
        return FileFormatError(f"{self.path}: {what}{tail}")

    def _storage_failed(self) -> None:
        """Raise the storage's error when a granule in storage failed to answer: a read
        error that says "absent" (False, empty) would name the file, not the server."""
        remote = getattr(self._source, "error", None)
        if isinstance(remote, FileFormatError):
            raise remote

    def has(self, name: str) -> bool:
        """True when group or dataset ``name`` exists (False on any read error)."""
        try:
            return name in self._f
        except (OSError, KeyError, RuntimeError, ValueError):
            self._storage_failed()
            return False

    def is_group(self, name: str) -> bool:
        """True when ``name`` exists and is a group."""
        return self._is_a(name, _import_h5py().Group)

    def is_dataset(self, name: str) -> bool:
        """True when ``name`` exists and is a dataset."""
        return self._is_a(name, _import_h5py().Dataset)

    def _is_a(self, name: str, kind: type) -> bool:
        """True when ``name`` exists and is a ``kind`` (False on any read error)."""
        try:
            return isinstance(self._f.get(name), kind)
        except (OSError, KeyError, RuntimeError, ValueError):
            self._storage_failed()
            return False

    def keys(self, group: str = "/") -> list[str]:
        """Member names of ``group`` (sorted); empty when it does not exist."""
        try:
            g = self._f[group]
            return sorted(g.keys()) if hasattr(g, "keys") else []
        except (OSError, KeyError, RuntimeError, ValueError):
            self._storage_failed()
            return []

    def unreadable(self, name: str = "/") -> str | None:
        """The first group or object on the way to ``name`` that the file lists but HDF5
        cannot read (a damaged file), or None when each part is readable or not listed
        (absent: another product, or a subset made without it)."""
        h5py = _import_h5py()
        group = "/"
        for part in [p for p in name.split("/") if p]:
            try:
                listed = part in list(self._f[group].keys())
            except _H5_ERRORS:
                self._storage_failed()
                return group
            if not listed:
                return None
            group = f"{group.rstrip('/')}/{part}"
            try:
                if not isinstance(self._f[group], h5py.Group):
                    return None
            except _H5_ERRORS:
                self._storage_failed()
                return group
        try:
            list(self._f[group].keys())
        except _H5_ERRORS:
            self._storage_failed()
            return group
        return None

    def damaged(self, where: str) -> DamagedFileError:
        """The refusal of a file whose HDF5 structures at ``where`` cannot be read."""
        what = ("HDF5 cannot read the list of what it holds" if where == "/" else
                f"it lists {where.lstrip('/')} but HDF5 cannot read it")
        return DamagedFileError(
            f"{self.path}: the file is damaged ({what}: its HDF5 structures or data were "
            "overwritten, as by an interrupted download or copy); download it again")

    def _dataset(self, name: str, what: str = "") -> Any:
        h5py = _import_h5py()
        try:
            obj = self._f.get(name)
        except (OSError, KeyError, RuntimeError, ValueError) as exc:
            raise self._fail(f"cannot open dataset /{name}", exc) from None
        if obj is None and (where := self.unreadable(name)) is not None:
            raise self.damaged(where)
        if not isinstance(obj, h5py.Dataset):
            kind = "is a group, not a dataset" if obj is not None else "is missing"
            extra = f" ({what})" if what else ""
            raise self._fail(
                f"dataset /{name}{extra} {kind}; this {self.product} file is incomplete or "
                "not the expected product"
            )
        return obj

    @property
    def _fetch(self) -> Any:
        """Byte ranges of the granule in storage, coalesced and concurrent (None: local)."""
        return getattr(self._source, "fetch", None)

    def shape(self, name: str) -> tuple[int, ...]:
        """Shape of dataset ``name``."""
        return tuple(int(n) for n in self._dataset(name).shape)

    def dtype(self, name: str) -> np.dtype:
        """dtype of dataset ``name``."""
        return np.dtype(self._dataset(name).dtype)

    def read(self, name: str, sel: Any = None, *, dtype: Any = None, what: str = "") -> np.ndarray:
        """Read dataset ``name`` (optionally a slice ``sel``) as a numpy array.

        Parameters
        ----------
        name : str
            Path inside the file.
        sel : slice, tuple or index array, optional
            Selection passed to h5py (read only that part).
        dtype : numpy dtype, optional
            Convert after reading.
        what : str
            Description used in the error message.
        """
        ds = self._dataset(name, what)
        direct = self._read_direct(ds, name, sel, dtype)
        if direct is not None:
            return direct
        try:
            arr = np.asarray(ds[()] if sel is None else ds[sel])
        except (OSError, RuntimeError, ValueError, TypeError, KeyError) as exc:
            raise self._fail(
                f"cannot read /{name}: the file is truncated or corrupt", exc
            ) from None
        return arr.astype(dtype, copy=False) if dtype is not None else arr

    @staticmethod
    def _lossless(src: np.dtype, dst: np.dtype) -> bool:
        """HDF5 can convert ``src`` to ``dst`` while reading, with the same values."""
        same_kind = (src.kind in "biuf" and dst.kind == src.kind) or (
            src.kind in "bu" and dst.kind == "i")
        return bool(same_kind and np.can_cast(src, dst, "safe"))

    def _read_direct(self, ds: Any, name: str, sel: Any, dtype: Any) -> np.ndarray | None:
        """A 1-D numeric dataset (or a step-1 slice of it) read straight into a new array
        of ``dtype`` (HDF5 converts losslessly, e.g. float32 -> float64, on the fly):
        no intermediate copy.  None when that does not apply."""
        shape = ds.shape
        if shape is None or len(shape) != 1 or not (sel is None or isinstance(sel, slice)):
            return None  # (h5py.Empty datasets have no shape)
        src = np.dtype(ds.dtype)
        dst = src if dtype is None else np.dtype(dtype)
        if not self._lossless(src, dst):
            return None
        lo, hi, step = (sel if sel is not None else slice(None)).indices(int(shape[0]))
        if step != 1:
            return None
        chunked = read_chunks(ds, lo, hi, dst, fetch=self._fetch)
        if chunked is not None:
            return chunked
        out = np.empty(max(0, hi - lo), dtype=dst)
        if out.size:
            try:
                ds.read_direct(out, np.s_[lo:hi], np.s_[0:hi - lo])
            except (OSError, RuntimeError, ValueError, TypeError, KeyError):
                return None  # the plain read decides (and names the problem)
        return out

    def read_column(self, name: str, lo: int, hi: int, column: int, dtype: Any = None, *,
                    what: str = "") -> np.ndarray:
        """``read(name, np.s_[lo:hi], dtype=dtype)[:, column]`` of a 2-D dataset, as a
        contiguous array, read through a small reusable buffer (much faster than an
        HDF5 hyperslab of one column, and no full-size temporary)."""
        ds = self._dataset(name, what)
        shape = tuple(int(v) for v in (ds.shape or ()))
        src = np.dtype(ds.dtype)
        dst = src if dtype is None else np.dtype(dtype)
        if (len(shape) != 2 or not self._lossless(src, dst) or not 0 <= lo <= hi <= shape[0]
                or not 0 <= column < shape[1]):
            arr = self.read(name, np.s_[lo:hi], dtype=dtype, what=what)
            if arr.ndim != 2 or not 0 <= column < arr.shape[1]:
                raise self._fail(f"dataset /{name} has shape {shape}, expected (n, k) with "
                                 f"k > {column}; the file is not the expected product")
            return np.ascontiguousarray(arr[:, column])
        chunked = read_chunks(ds, lo, hi, dst, column, fetch=self._fetch)
        if chunked is not None:
            return chunked
        out = np.empty(hi - lo, dtype=dst)
        step = max(1, (1 << 22) // max(1, shape[1] * dst.itemsize))
        buf = np.empty((min(step, max(1, hi - lo)), shape[1]), dtype=dst)
        try:
            for a in range(lo, hi, step):
                b = min(hi, a + step)
                ds.read_direct(buf, np.s_[a:b], np.s_[0:b - a])
                out[a - lo:b - lo] = buf[:b - a, column]
        except (OSError, RuntimeError, ValueError, TypeError, KeyError) as exc:
            raise self._fail(
                f"cannot read /{name}: the file is truncated or corrupt", exc
            ) from None
        return out

    def attr(self, name: str, key: str, default: object = None) -> object:
        """Decoded attribute ``key`` of object ``name`` (``"/"`` = root), or ``default``."""
        try:
            obj = self._f[name]
            if key not in obj.attrs:
                return default
            return decode_attr(obj.attrs[key])
        except (OSError, KeyError, RuntimeError, ValueError, TypeError):
            self._storage_failed()
            return default

    def attrs(self, name: str = "/") -> dict[str, object]:
        """All decoded attributes of ``name`` (empty on error)."""
        try:
            obj = self._f[name]
            return {k: decode_attr(obj.attrs[k]) for k in obj.attrs}
        except (OSError, KeyError, RuntimeError, ValueError, TypeError):
            self._storage_failed()
            return {}

    def scalar(self, name: str, default: object = None) -> object:
        """First element of a small dataset (e.g. ``orbit_info/sc_orient``), or ``default``."""
        if not self.is_dataset(name):
            return default
        try:
            return decode_attr(self.read(name).reshape(-1)[:1])
        except FileFormatError:
            return default


@contextlib.contextmanager
def open_h5(path: str | os.PathLike[str] | IO[bytes], product: str = "HDF5"
            ) -> Iterator[H5File]:
    """Open ``path`` read-only as an :class:`H5File`.

    ``path`` may also be an ``s3://`` or ``https://`` URL or an open binary file object
    (such as ``earthaccess.open`` returns): HDF5 then reads it by byte ranges
    (:mod:`canopyblocks.readers.remote`).

    Raises
    ------
    FileFormatError
        When the file does not exist, is not HDF5, or cannot be opened
        (truncated, corrupt); for a URL also not found, access denied, no credentials or
        the connection lost; the message names the file.
    """
    kind = "an HDF5 file" if product == "HDF5" else f"an HDF5 {product} file"
    from .remote import is_file_object, is_url
    if is_url(path) or is_file_object(path):
        from .remote_guard import no_collection
        # no collection while HDF5 reads through the source: it would wait for h5py's lock
        with no_collection(), _open_remote(path, kind) as (handle, label, source):
            yield H5File(handle, label, product, source)
        return
    if not isinstance(path, (str, os.PathLike)):
        from ..arguments import describe
        raise InputError(f"expected the path of {kind} (str or Path), got {describe(path)}")
    p = Path(path)
    if not p.exists():
        from .remote import missing_message
        raise FileFormatError(missing_message(path))
    if p.is_dir():
        raise FileFormatError(f"{p}: is a folder, expected {kind}")
    if not _looks_like_hdf5(p):
        size = p.stat().st_size
        tiny = f"only {size} bytes: empty or cut short; download it again" if size < 8 else \
            "no HDF5 signature"
        raise FileFormatError(f"{p}: not an HDF5 file ({tiny}); expected {kind}")
    h5py = _import_h5py()
    try:
        handle = h5py.File(p, "r")
    except (OSError, RuntimeError, ValueError) as exc:
        raise FileFormatError(_open_failed(p, exc)) from None
    try:
        yield H5File(handle, p, product)
    finally:
        with contextlib.suppress(Exception):
            handle.close()


def _open_failed(label: object, exc: BaseException, remote: bool = False) -> str:
    """The line for a file HDF5 cannot open: cut short (HDF5 says how many bytes it holds
    of how many its header promises) or corrupt, and what to do."""
    import re

    m = re.search(r"truncated file: eof = (\d+).*stored_eof = (\d+)", str(exc))
    if m is None:
        return (f"{label}: cannot open as HDF5, the file is truncated or corrupt ({exc}); "
                "download it again")
    has, promised = int(m.group(1)), int(m.group(2))
    where = "the server holds" if remote else "it holds"
    return (f"{label}: cannot open as HDF5, the file is truncated or corrupt ({where} "
            f"{has:,} of the {promised:,} bytes its header promises: cut short, as by an "
            "interrupted download or copy); download it again")


def _signature_at(fh: Any, size: int | None) -> bool:
    off = 0
    while (size is None or off + 8 <= size) and off <= 1 << 20:
        fh.seek(off)
        if fh.read(8) == HDF5_SIGNATURE:
            return True
        if size is None and off > 0:
            return False
        off = 512 if off == 0 else off * 2
    return False


@contextlib.contextmanager
def _open_remote(value: Any, kind: str) -> Iterator[tuple[Any, str, Any]]:
    """(h5py file, label, source) of a URL or a file object; a failure of the storage
    raised as its own one-line message, whatever HDF5 or a reader made of it."""
    from ..errors import CanopyBlocksError
    from .remote import open_source, source_label

    label = source_label(value)
    source = open_source(value)
    size = getattr(source, "size", None)
    try:
        ok = _signature_at(source, size if isinstance(size, int) else None)
    except FileFormatError:
        raise
    except (OSError, ValueError) as exc:
        raise FileFormatError(f"{label}: cannot read ({type(exc).__name__}: {exc})") from None
    if not ok:
        raise FileFormatError(f"{label}: not an HDF5 file (no HDF5 signature); expected {kind}")
    source.seek(0)
    h5py = _import_h5py()
    try:
        handle = h5py.File(source, "r")
    except (OSError, RuntimeError, ValueError) as exc:
        err = getattr(source, "error", None)
        if isinstance(err, FileFormatError):
            raise err from None
        raise FileFormatError(_open_failed(label, exc, remote=True)) from None
    try:
        yield handle, label, source
    except CanopyBlocksError:
        err = getattr(source, "error", None)
        if isinstance(err, FileFormatError):
            raise err from None
        raise
    finally:
        with contextlib.suppress(Exception):
            handle.close()
