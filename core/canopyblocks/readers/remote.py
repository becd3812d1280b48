"""Granules in object storage: ``s3://`` and ``https://`` URLs and open file objects.

A granule may be a local path, an ``s3://bucket/key`` or ``https://...`` URL, or an open
binary file object (what ``earthaccess.open`` returns).  :func:`open_source` turns a URL into
a :class:`RemoteFile`, a read-only, seekable file object that HDF5 reads through h5py's
``fileobj`` driver; it fetches byte ranges only, so the readers' subset reads (the segment
index first, then the photon rows inside the study area) fetch only the chunks they need.

* Transport: ``fsspec`` with ``s3fs`` (credentials from the standard chain: the AWS
  variables, ``AWS_PROFILE``/``~/.aws``, an instance role; for a bucket of NASA's archives
  without any of these, Earthdata's temporary keys through ``earthaccess`` where installed;
  the endpoint from ``AWS_ENDPOINT_URL``) or its HTTP file system (range requests, with
  ``aiohttp``): the optional ``cloud`` extra.
* Caching is modest: small reads (HDF5's metadata, a chunk or two) go through an LRU cache
  of ``BLOCK`` bytes per block (at most ``MAX_BLOCKS`` blocks); reads of a block or more go
  straight to storage.  Many chunks at once (:meth:`RemoteFile.fetch`) are coalesced
  (neighbours within ``MAX_GAP`` bytes) and fetched concurrently.
* Why fsspec and not h5coro: h5coro reads HDF5 with its own parser of a subset of the format;
  the readers here stand on h5py (the chunk index, filters, HDF5's own check of the first
  chunk), so a URL goes through the very code a local file does and gives the same numbers.
* Transient failures (a dropped or timed-out connection, HTTP 5xx, throttling) are retried
  ``RETRIES`` times with exponential back-off; every failure ends as one
  :class:`StorageError` line (a :class:`~canopyblocks.errors.FileFormatError`) naming the
  URL (without its query string, where signed links keep their secrets) and what to do,
  in words of what the server did: no byte ranges, a short answer, closed in the middle of
  an answer, no answer within the time-out.
* Time-out: ``READ_TIMEOUT`` seconds (``CANOPYBLOCKS_TIMEOUT`` in the environment sets
  another), the same over ``s3://`` and ``https://``; a server that says nothing for that
  long is reported at once, not tried again.
"""

from __future__ import annotations

import io
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from ..errors import DependencyError, FileFormatError
from .earthdata import _EARTHDATA, earthdata_credentials
from .remote_guard import Stuck, guarded_call
from .tls_errors import tls_failed as _tls
from .tls_errors import tls_message

__all__ = ["StorageError", "is_url", "is_file_object", "source_arg", "source_label",
           "source_name", "RemoteFile", "open_source", "list_granules", "clear_cache",
           "missing_message", "timeout_seconds", "BLOCK", "MAX_BLOCKS", "MAX_GAP", "RETRIES"]

#: Bytes per cached block (HDF5 metadata and small reads).
BLOCK = 1 << 15
#: Cached blocks, all granules of the process together (BLOCK * MAX_BLOCKS = 32 MiB).
MAX_BLOCKS = 1024
#: Ranges closer than this are fetched in one request.
MAX_GAP = 1 << 16
#: Largest coalesced request (bigger ones are split so that they run concurrently).
MAX_REQUEST = 1 << 23
#: Tries after the first for a transient failure; back-off ``BACKOFF * 2**k`` seconds.
RETRIES = 4
BACKOFF = 0.5
#: Seconds to wait for a connection, and for the next bytes of an answer.
CONNECT_TIMEOUT = 20.0
READ_TIMEOUT = 60.0

_SCHEMES = ("s3://", "http://", "https://")
TIMEOUT_ENV = "CANOPYBLOCKS_TIMEOUT"
#: Exception names of an answer cut short (the connection closed in its middle).
_CUT_WORDS = ("Payload", "ContentLength", "IncompleteRead", "ServerDisconnected")


class StorageError(FileFormatError):
    """Object storage failed (not found, access denied, no credentials, connection lost):
    one line naming the URL (never a secret) and what to do."""


class _RangesIgnored(Exception):
    """The server answered a range request with more bytes than asked (the whole object)."""


class _ShortAnswer(Exception):
    """The server answered a range request with fewer bytes than asked."""


def timeout_seconds() -> float:
    """Seconds to wait for a connection or the next bytes of an answer: ``READ_TIMEOUT``,
    or ``CANOPYBLOCKS_TIMEOUT`` from the environment (a positive number)."""
    raw = os.environ.get(TIMEOUT_ENV, "").strip()
    if not raw:
        return READ_TIMEOUT
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not (value > 0 and value < 1e6):
        from ..errors import InputError
        raise InputError(f"{TIMEOUT_ENV}={raw!r} must be a positive number of seconds")
    return value


def missing_message(value: object) -> str:
    """The one line for a path that does not exist: ``<path>: file does not exist``, or,
    for a URL of a scheme the readers do not take (``ftp://``), that scheme named."""
    import re

    text = os.fspath(value) if isinstance(value, os.PathLike) else str(value)
    m = re.match(r"^([A-Za-z][A-Za-z0-9+.-]*)://", text.strip())
    if m and not is_url(text):
        return (f"{source_label(text)}: {m.group(1)}:// is not a source canopyblocks reads; "
                "use a local path, an s3:// or an https:// URL (download the file first)")
    return f"{text}: file does not exist"


def is_url(value: object) -> bool:
    """True for a str ``s3://``, ``http://`` or ``https://`` URL."""
    return isinstance(value, str) and value.strip().lower().startswith(_SCHEMES)


def is_file_object(value: object) -> bool:
    """True for an open binary file object (has ``read`` and ``seek``; not a path)."""
    return (not isinstance(value, (str, bytes, os.PathLike))
            and callable(getattr(value, "read", None)) and callable(getattr(value, "seek", None)))


def source_label(value: object) -> str:
    """How a granule is named in messages: a path as given, a URL without its query string or
    user name (signed links carry their secrets there), a file object by its path or URL."""
    if is_file_object(value):
        for attr in ("full_name", "path", "url", "name"):
            got = getattr(value, attr, None)
            if isinstance(got, str) and got:
                if attr == "path" and not is_url(got) and hasattr(value, "fs"):
                    proto = getattr(getattr(value, "fs", None), "protocol", None)
                    proto = proto[0] if isinstance(proto, (tuple, list)) else proto
                    if isinstance(proto, str) and proto not in ("file", "local"):
                        got = f"{proto}://{got}"
                return source_label(got)
        return f"<open file {type(value).__name__}>"
    text = os.fspath(value) if isinstance(value, os.PathLike) else str(value)
    if not is_url(text):
        return text
    parts = urlsplit(text.strip())
    host = parts.hostname or ""
    if parts.port:
        host = f"{host}:{parts.port}"
    return urlunsplit((parts.scheme, host, parts.path, "", ""))


def source_arg(value: Any) -> Any:
    """``value`` for a reader: a path-like as ``str`` (as the readers log it), a URL or a
    file object as given."""
    return value if is_file_object(value) else os.fspath(value)


def source_name(value: object) -> str:
    """The granule's file name (the last part of its path or URL)."""
    label = source_label(value).rstrip("/")
    return label.rsplit("/", 1)[-1] or label


# ---------------------------------------------------------------------------- transport
_FS_LOCK = threading.Lock()


def _need(module: str) -> Any:
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise DependencyError(
            f"reading granules from object storage needs {module}; install it with "
            "pip install 'canopyblocks[cloud]'") from None


def _filesystem(url: str) -> Any:
    """The fsspec file system for ``url`` (one per scheme and credentials, reused)."""
    scheme = url.split("://", 1)[0].lower()
    with _FS_LOCK:
        if scheme == "s3":
            s3fs = _need("s3fs")
            env = os.environ
            endpoint = env.get("AWS_ENDPOINT_URL_S3") or env.get("AWS_ENDPOINT_URL") or None
            wait = timeout_seconds()
            kw: dict[str, Any] = {
                # one try inside botocore and s3fs (ours wrap it, with back-off): a silent
                # endpoint is given up after the time-out, as over https://
                "config_kwargs": {"retries": {"max_attempts": 1, "mode": "standard"},
                                  "connect_timeout": min(CONNECT_TIMEOUT, wait),
                                  "read_timeout": wait},
            }
            if endpoint:
                _check_endpoint(endpoint, source_label(url))
                kw["endpoint_url"] = endpoint
            if env.get("AWS_ACCESS_KEY_ID") and env.get("AWS_SECRET_ACCESS_KEY"):
                # the chain's first link, passed on so that a changed key gets a new client
                kw.update(key=env["AWS_ACCESS_KEY_ID"], secret=env["AWS_SECRET_ACCESS_KEY"],
                          token=env.get("AWS_SESSION_TOKEN") or None)
            elif env.get("AWS_PROFILE"):
                kw["profile"] = env["AWS_PROFILE"]
            else:  # a NASA archive's bucket: Earthdata's temporary keys, where earthaccess is
                kw.update(earthdata_credentials(url))
            fs = s3fs.S3FileSystem(**kw)
            fs.retries = 1  # s3fs's own loop (ours wraps it, with back-off)
            return fs
        aiohttp = _need("aiohttp")
        from fsspec.implementations.http import HTTPFileSystem

        wait = timeout_seconds()
        timeout = aiohttp.ClientTimeout(total=None, sock_connect=min(CONNECT_TIMEOUT, wait),
                                        sock_read=wait)
        return HTTPFileSystem(block_size=0, client_kwargs={"timeout": timeout})


def _check_endpoint(endpoint: str, label: str) -> None:
    """``AWS_ENDPOINT_URL`` must be an http(s) URL with a host."""
    parts = urlsplit(endpoint.strip())
    if parts.scheme.lower() not in ("http", "https") or not parts.hostname:
        raise StorageError(f"{label}: AWS_ENDPOINT_URL={endpoint!r} is not the URL of an S3 endpoint "
                           "(http(s)://host[:port]); correct it, or unset it for AWS itself")


def _chain(exc: BaseException) -> list[BaseException]:
    """``exc`` and the exceptions it was raised from (fsspec wraps a failed HEAD in a
    FileNotFoundError)."""
    out: list[BaseException] = []
    cur: BaseException | None = exc
    while cur is not None and all(cur is not e for e in out):
        out.append(cur)
        cur = cur.__cause__ or cur.__context__
    return out


def _status(exc: BaseException) -> int | None:
    """The HTTP status behind ``exc`` (or the exceptions it was raised from), if any."""
    for e in _chain(exc):
        if any(w in type(e).__name__ for w in _CUT_WORDS + ("TransferEncoding",)):
            continue  # aiohttp's code 400 there is its parser's, not the server's
        for attr in ("status", "status_code", "code"):
            v = getattr(e, attr, None)
            if isinstance(v, int) and 100 <= v < 600:
                return v
        resp = getattr(e, "response", None)
        if isinstance(resp, dict):
            v = resp.get("ResponseMetadata", {}).get("HTTPStatusCode")
            if isinstance(v, int):
                return v
    return None


_CONNECTION_WORDS = ("Connect", "Timeout", "Disconnect", "Payload", "Endpoint",
                     "ClientOSError", "IncompleteRead")


def _connection_lost(exc: BaseException) -> bool:
    return any(isinstance(e, (ConnectionError, TimeoutError, EOFError))
               or any(w in type(e).__name__ for w in _CONNECTION_WORDS) for e in _chain(exc))


def _timed_out(exc: BaseException) -> bool:
    return any(isinstance(e, TimeoutError) or "Timeout" in type(e).__name__
               for e in _chain(exc))


def _transient(exc: BaseException) -> bool:
    """A failure worth another try: connection dropped, a short answer, 5xx, throttling
    (not a time-out: a server silent that long is reported at once)."""
    chain = _chain(exc)
    if any("Credential" in type(e).__name__ or "ProfileNotFound" in type(e).__name__
           or isinstance(e, _RangesIgnored) or _tls(e) for e in chain):
        return False
    if any(isinstance(e, (_ShortAnswer, Stuck)) for e in chain):
        return True
    if _timed_out(exc) and _status(exc) is None:
        return False
    status = _status(exc)
    if status is not None:
        return status >= 500 or status in (408, 429)
    return _connection_lost(exc)


def _explain(exc: BaseException, label: str, tries: int) -> StorageError:
    """One line: the URL (no secrets) and what to do."""
    name = type(exc).__name__
    status = _status(exc)
    s3 = label.lower().startswith("s3://")
    chain = _chain(exc)
    special = _explain_special(chain, label, tries)
    if special is not None:
        return special
    if any("Credential" in type(e).__name__ for e in chain):
        return StorageError(
            f"{label}: no credentials for S3 were found; set AWS_ACCESS_KEY_ID and "
            "AWS_SECRET_ACCESS_KEY (or AWS_PROFILE / ~/.aws/credentials), or open NASA "
            "granules with earthaccess.open(...) and pass the file object")
    if status == 404 or (isinstance(exc, FileNotFoundError) and status is None
                         and not _connection_lost(exc)):
        return StorageError(
            f"{label}: not found (404); check the "
            + ("bucket and key" if s3 else "address") + " of the file")
    if isinstance(exc, PermissionError) or status in (401, 403):
        return StorageError(
            f"{label}: access denied ({status or 403}); "
            + ("check that the credentials (AWS_ACCESS_KEY_ID/AWS_SECRET_ACCESS_KEY, "
               "AWS_PROFILE, ~/.aws) may read this object, and AWS_ENDPOINT_URL"
               if s3 else "log in (earthaccess.login()) or renew the link, then run again"))
    if _transient(exc):
        lost = [type(e).__name__ for e in _chain(exc) if _connection_lost(e)]
        why = f"HTTP {status}" if status else (lost[-1] if lost else name)
        if any(w in why for w in _CUT_WORDS):
            why = "the server closed the connection in the middle of an answer"
        return StorageError(
            f"{label}: the connection failed after {tries} tries ({why}); check the "
            "network" + (" and AWS_ENDPOINT_URL" if s3 else "") + ", then run again")
    return StorageError(f"{label}: cannot read from storage ({name}"
                           + (f", HTTP {status}" if status else "") + ")")


def _explain_special(chain: list[BaseException], label: str, tries: int
                     ) -> StorageError | None:
    """What the server or the configuration did, for the failures with their own words."""
    s3 = label.lower().startswith("s3://")
    for e in chain:
        if _tls(e):
            return StorageError(tls_message(chain, label))
        if isinstance(e, _RangesIgnored):
            return StorageError(f"{label}: the server does not support byte ranges (it does "
                                f"not answer byte-range requests: {e}); download the file "
                                "and pass the local copy")
        if isinstance(e, _ShortAnswer):
            return StorageError(f"{label}: the server's answers were short ({e}), {tries} "
                                "tries; the object may be changing or the server faulty: "
                                "run again later, or download the file and pass the local copy")
        if "ProfileNotFound" in type(e).__name__:
            return StorageError(f"{label}: the AWS profile "
                                f"{os.environ.get('AWS_PROFILE', '')!r} (AWS_PROFILE) is not "
                                "in ~/.aws/config or ~/.aws/credentials; correct or unset "
                                "AWS_PROFILE")
        if type(e).__name__ == "ValueError" and "endpoint" in str(e).lower():
            return StorageError(f"{label}: AWS_ENDPOINT_URL is not the URL of an S3 endpoint "
                                f"({e}); correct it, or unset it for AWS itself")
    if any(_timed_out(e) for e in chain) and _status(chain[0]) is None:
        return StorageError(
            f"{label}: no answer within {timeout_seconds():g} s (the time-out; "
            f"{TIMEOUT_ENV} sets another); check the network"
            + (" and AWS_ENDPOINT_URL" if s3 else "") + ", then run again")
    return None


# ---------------------------------------------------------------------------- the file
#: Blocks of objects in storage, shared by every open in this process (LRU, MAX_BLOCKS).
_BLOCKS: OrderedDict[tuple[str, int, int, int], bytes] = OrderedDict()
#: Sizes of the objects opened (one HEAD per object and process).
_SIZES: dict[str, int] = {}
_CACHE_LOCK = threading.Lock()


def clear_cache() -> None:
    """Forget the cached blocks and sizes (an object changed in storage, or a test)."""
    with _CACHE_LOCK:
        _BLOCKS.clear()
        _SIZES.clear()
        _EARTHDATA.clear()


class RemoteFile(io.RawIOBase):
    """A read-only, seekable view of one object in storage, fetched by byte ranges.

    Parameters
    ----------
    fs : fsspec file system
    path : str
        The object's path for ``fs`` (a URL or ``bucket/key``).
    label : str
        Its name in messages (no secrets).

    Attributes
    ----------
    requests, nbytes : int
        Requests made and bytes received so far.
    error : FileFormatError or None
        The last failure (HDF5 reports a read failure by its own words; the reader door
        raises this one instead).
    """

    def __init__(self, fs: Any, path: str, label: str, size: int | None = None) -> None:
        super().__init__()
        self.fs, self.remote_path, self.label = fs, path, label
        self.requests = 0
        self.nbytes = 0
        self.error: FileFormatError | None = None
        self._pos = 0
        self._lock = threading.Lock()
        if size is None:
            with _CACHE_LOCK:
                size = _SIZES.get(path)
        self.size = int(size) if size is not None else self._size()
        with _CACHE_LOCK:
            _SIZES[path] = self.size

    # -- transport with retries
    def _retry(self, what: Callable[[], Any]) -> Any:
        for k in range(RETRIES + 1):
            try:
                return what()
            except StorageError as exc:  # already one line, and not worth another try
                self.error = exc
                raise
            except Exception as exc:  # noqa: BLE001 -- mapped to one line below
                if k < RETRIES and _transient(exc):
                    time.sleep(BACKOFF * 2 ** k)
                    continue
                self.error = _explain(exc, self.label, k + 1)
                raise self.error from None
        raise AssertionError("unreachable")

    def _call(self, method: str, *args: Any, **kw: Any) -> Any:
        """``fs.<method>(*args)`` within the time-out plus the connect time-out (remote_guard)."""
        return guarded_call(self.fs, method, timeout_seconds() + CONNECT_TIMEOUT, *args, **kw)

    def _size(self) -> int:
        info = self._retry(lambda: self._call("info", self.remote_path))
        if isinstance(info, dict) and info.get("type") == "directory":
            self.error = StorageError(
                f"{self.label}: is a prefix (a folder of objects), not a file; give one "
                "file's URL (batch takes a prefix and reads every granule under it)")
            raise self.error
        size = info.get("size") if isinstance(info, dict) else None
        if not isinstance(size, int):
            self.error = StorageError(
                f"{self.label}: the server does not tell the size of the file; it cannot "
                "be read by ranges (download it, then pass the local file)")
            raise self.error
        return size

    def fetch(self, ranges: Sequence[tuple[int, int]],
              max_gap: int = MAX_GAP) -> list[bytes]:
        """The bytes of each ``(start, end)`` range: neighbours closer than ``max_gap`` bytes
        coalesced into one request, the requests run concurrently."""
        if not ranges:
            return []
        order = sorted(range(len(ranges)), key=lambda i: ranges[i][0])
        groups: list[list[int]] = []
        for i in order:
            a, b = ranges[i]
            if groups:
                g = groups[-1]
                g0 = ranges[g[0]][0]
                g1 = max(ranges[j][1] for j in g)
                if a <= g1 + max_gap and max(b, g1) - g0 <= MAX_REQUEST:
                    g.append(i)
                    continue
            groups.append([i])
        spans = [(ranges[g[0]][0], max(ranges[j][1] for j in g)) for g in groups]
        blobs = self._get(spans)
        out: list[bytes] = [b""] * len(ranges)
        for g, (g0, _g1), blob in zip(groups, spans, blobs):
            view = memoryview(blob)
            for i in g:
                a, b = ranges[i]
                out[i] = bytes(view[a - g0:b - g0])
        return out

    def _get(self, spans: list[tuple[int, int]]) -> list[bytes]:
        def go() -> list[bytes]:
            if len(spans) == 1:
                got = [self._call("cat_file", self.remote_path, start=spans[0][0],
                                  end=spans[0][1])]
            else:
                got = self._call("cat_ranges", [self.remote_path] * len(spans),
                                 [s[0] for s in spans], [s[1] for s in spans],
                                 on_error="raise")
            for (a, b), blob in zip(spans, got):
                if isinstance(blob, BaseException):
                    raise blob
                if len(blob) > b - a:
                    raise _RangesIgnored(f"asked for {b - a:,} bytes, it sent {len(blob):,}")
                if len(blob) < b - a:
                    raise _ShortAnswer(f"{len(blob):,} of the {b - a:,} bytes asked for")
            return list(got)

        blobs: list[bytes] = self._retry(go)
        with self._lock:
            self.requests += len(spans)
            self.nbytes += sum(len(b) for b in blobs)
        return blobs

    # -- the io.RawIOBase interface HDF5 uses
    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: self.size}[whence]
        self._pos = max(0, base + int(offset))
        return self._pos

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        a = self._pos
        b = min(self.size, a + len(view))
        if b <= a:
            return 0
        if b - a >= BLOCK:  # large reads straight from storage, not through the cache
            data = self._get([(a, b)])[0]
        else:
            data = self._cached(a, b)
        view[:b - a] = data
        self._pos = b
        return b - a

    def _cached(self, a: int, b: int) -> bytes:
        """Bytes ``a:b`` through the block cache (shared by every open of this object in
        the process: a command opens a granule several times, its metadata is fetched once)."""
        first, last = a // BLOCK, (b - 1) // BLOCK
        keys = [(self.remote_path, self.size, BLOCK, k) for k in range(first, last + 1)]
        with _CACHE_LOCK:
            have = {key: _BLOCKS[key] for key in keys if key in _BLOCKS}
        missing = [key for key in keys if key not in have]
        if missing:
            spans = [(k * BLOCK, min(self.size, (k + 1) * BLOCK)) for *_, k in missing]
            have.update(zip(missing, self.fetch(spans)))
        with _CACHE_LOCK:
            for key in keys:
                _BLOCKS[key] = have[key]
                _BLOCKS.move_to_end(key)
            while len(_BLOCKS) > MAX_BLOCKS:
                _BLOCKS.popitem(last=False)
        joined = b"".join(have[key] for key in keys)
        return joined[a - first * BLOCK:b - first * BLOCK]


def _fsspec_file(obj: Any) -> tuple[Any, str] | None:
    """(file system, path) of an fsspec file object (as earthaccess.open returns), if it is one."""
    fs, path = getattr(obj, "fs", None), getattr(obj, "path", None)
    if fs is None or not isinstance(path, str) or not callable(getattr(fs, "cat_file", None)):
        return None
    proto = getattr(fs, "protocol", None)
    protos = proto if isinstance(proto, (tuple, list)) else (proto,)
    if any(p in ("file", "local") for p in protos):
        return None
    return fs, path


def open_source(value: object) -> Any:
    """What h5py opens for ``value``: a local path unchanged; a :class:`RemoteFile` for an
    ``s3://``/``https://`` URL or an fsspec file object (ranges fetched through its own file
    system, credentials included); any other file object as given.

    Raises
    ------
    FileFormatError
        Not found, access denied, no credentials, connection failed (one line naming the URL).
    DependencyError
        ``s3fs``/``aiohttp`` missing (``pip install 'canopyblocks[cloud]'``).
    """
    if is_url(value):
        url = str(value).strip()
        label = source_label(url)
        fs = _filesystem(url)
        return RemoteFile(fs, url, label)
    if is_file_object(value):
        pair = _fsspec_file(value)
        if pair is not None:
            size = getattr(value, "size", None)
            return RemoteFile(pair[0], pair[1], source_label(value),
                              size if isinstance(size, int) else None)
        return value
    return value


def list_granules(prefix: str, suffixes: Sequence[str] = (".h5", ".hdf5", ".he5")) -> list[str]:
    """The granule URLs under an ``s3://bucket/prefix/`` (sorted), those ending in ``suffixes``.

    Raises
    ------
    FileFormatError
        The prefix cannot be listed (one line naming it and what to do).
    """
    label = source_label(prefix)
    fs = _filesystem(prefix)
    found: list[str] = []
    for k in range(RETRIES + 1):
        try:
            found = fs.find(prefix.strip())
            break
        except Exception as exc:  # noqa: BLE001
            if k < RETRIES and _transient(exc):
                time.sleep(BACKOFF * 2 ** k)
                continue
            raise _explain(exc, label, k + 1) from None
    return sorted(f"s3://{p}" if not is_url(p) else p for p in found
                  if p.lower().endswith(tuple(suffixes)))
