"""Real servers on the loopback address only (127.0.0.1, a free port): an S3 store (moto's
server application) and a static HTTP server with range requests.  Both count the requests
and the body bytes they send, so a test or a benchmark can see what a read fetched.

Used by tests/test_remote_read.py, tests/test_copc.py, bench/bench_remote.py and
bench/bench_copc_remote.py.
"""

from __future__ import annotations

import http.server
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

LOOPBACK = "127.0.0.1"


@dataclass
class Tally:
    """Requests and body bytes a server sent (thread-safe)."""

    requests: int = 0
    range_requests: int = 0
    nbytes: int = 0
    #: the distinct (path, first byte, size) answered: what a reader asked for, whatever
    #: the transport asked again after a stall
    spans: set[tuple[str, int, int]] = field(default_factory=set)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add(self, nbytes: int, ranged: bool, span: tuple[str, int, int] | None = None) -> None:
        with self._lock:
            self.requests += 1
            self.range_requests += int(ranged)
            self.nbytes += nbytes
            if span is not None:
                self.spans.add(span)

    @property
    def distinct_bytes(self) -> int:
        """Bytes of the distinct ranges answered (each counted once)."""
        with self._lock:
            return sum(n for _, _, n in self.spans)

    def reset(self) -> None:
        with self._lock:
            self.requests = self.range_requests = self.nbytes = 0
            self.spans.clear()


# ---------------------------------------------------------------------------- HTTP
class _RangeHandler(http.server.BaseHTTPRequestHandler):
    server: _HTTPServer
    protocol_version = "HTTP/1.1"

    def log_message(self, *args: Any) -> None:  # quiet
        pass

    def _file(self) -> Path | None:
        rel = self.path.split("?", 1)[0].lstrip("/")
        p = (self.server.root / rel).resolve()
        if self.server.root not in p.parents or not p.is_file():
            return None
        return p

    def _refuse(self) -> bool:
        rel = self.path.split("?", 1)[0].lstrip("/")
        if rel.startswith("private/"):
            self.send_error(403, "Forbidden")
            return True
        if rel.startswith("drop/"):  # the connection dropped: no answer at all
            self.close_connection = True
            self.connection.close()
            return True
        if rel.startswith("slow/"):  # a server that never answers in time
            time.sleep(self.server.delay)
            self.close_connection = True
            return True
        return False

    def _collect(self) -> None:
        """The garbage handed over becomes unreachable here, in this thread; a collection
        starts now if automatic collections are on (as the first allocation would)."""
        import gc

        self.server.garbage.clear()
        self.server.collections.append(gc.isenabled())
        if gc.isenabled():
            gc.collect()

    def do_HEAD(self) -> None:
        if self._refuse():
            return
        p = self._file()
        if p is None:
            self.send_error(404, "Not Found")
            return
        self.send_response(200)
        self.send_header("Content-Length", str(p.stat().st_size))
        self.send_header("Accept-Ranges", "bytes")
        self.end_headers()

    def do_GET(self) -> None:
        if self._refuse():
            return
        if not self.server.claim():  # the store went down
            self.send_error(503, "Service Unavailable")
            return
        p = self._file()
        if p is None:
            self.send_error(404, "Not Found")
            return
        size = p.stat().st_size
        rng = self.headers.get("Range")
        a, b = 0, size - 1
        if rng and rng.startswith("bytes="):
            lo, _, hi = rng[6:].partition("-")
            a = int(lo) if lo else max(0, size - int(hi))
            b = min(size - 1, int(hi)) if (hi and lo) else size - 1
        rel = self.path.split("?", 1)[0].lstrip("/")
        if rel.startswith("collect/") and a > 0 and self.server.garbage:
            self._collect()
        if rel.startswith("norange/"):  # a server without byte ranges: the whole object
            rng, a, b = None, 0, size - 1
        with p.open("rb") as fh:
            fh.seek(a)
            body = fh.read(max(0, b - a + 1))
        if rel.startswith("short/") and rng and len(body) > 1:  # a 206 with a short body
            body, b = body[:len(body) // 2], a + len(body) // 2 - 1
        if rel.startswith("capped/") and rng and len(body) > self.server.cap:
            body, b = body[:self.server.cap], a + self.server.cap - 1  # a proxy's limit
        if rel.startswith("cut/") and len(body) > 1:  # closed in the middle of the answer
            self.send_response(206 if rng else 200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body[:len(body) // 2])
            self.wfile.flush()
            self.close_connection = True
            self.connection.shutdown(2)
            return
        self.send_response(206 if rng else 200)
        if rng:
            self.send_header("Content-Range", f"bytes {a}-{a + len(body) - 1}/{size}")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Accept-Ranges", "bytes")
        self.end_headers()
        self.wfile.write(body)
        self.server.tally.add(len(body), bool(rng), (rel, a, len(body)))


class _HTTPServer(http.server.ThreadingHTTPServer):
    daemon_threads = True
    root: Path
    tally: Tally
    delay: float = 2.0
    fail_after: float = float("inf")
    cap: int = 40_000
    claimed: int = 0
    garbage: list[Any]
    _claim_lock = threading.Lock()

    def claim(self) -> bool:
        """One more GET to answer, if fewer than ``fail_after`` were (concurrent GETs
        counted as they arrive, so that exactly ``fail_after`` are answered)."""
        with self._claim_lock:
            if self.claimed >= self.fail_after:
                return False
            self.claimed += 1
            return True
    collections: list[bool]


class RangeHTTPServer:
    """Files under ``root`` at ``http://127.0.0.1:<port>/<name>``; ``private/...`` answers
    403, ``drop/...`` closes the connection without an answer, ``slow/...`` answers nothing
    for ``delay`` seconds, ``norange/...`` ignores byte ranges (the whole object, 200),
    ``short/...`` answers a range with half its bytes (a short 206), ``cut/...`` closes the
    connection half-way through an answer, others 404 when missing; after ``fail_after`` answered GETs every
    GET gets 503 (a store that goes down in the middle of a read).  ``collect/...`` drops the
    objects in ``garbage`` at the first range not starting at byte 0 (HDF5 reading, past
    the signature check) and collects them in the server's thread if collections are on
    (``collections`` records whether they were)."""

    def __init__(self, root: Path, fail_after: float = float("inf")) -> None:
        self.server = _HTTPServer((LOOPBACK, 0), _RangeHandler)
        self.server.fail_after = fail_after
        self.server.garbage = self.garbage = []
        self.server.collections = self.collections = []
        self.server.root = Path(root).resolve()
        self.server.tally = self.tally = Tally()
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}"

    def __enter__(self) -> RangeHTTPServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.shutdown()
        self.server.server_close()
        self._thread.join()


# ---------------------------------------------------------------------------- S3
_DENIED = b"""<?xml version="1.0" encoding="UTF-8"?>
<Error><Code>AccessDenied</Code><Message>Access Denied</Message></Error>"""
_SLOW = b"""<?xml version="1.0" encoding="UTF-8"?>
<Error><Code>SlowDown</Code><Message>Please reduce your request rate.</Message></Error>"""


class S3Server:
    """moto's S3 application served by werkzeug on 127.0.0.1 (a free port), with a counter.

    Requests signed with the access key ``DENIED`` get ``403 AccessDenied`` (a key the
    store does not accept); ``fail_next_gets`` range GETs answer ``503 SlowDown`` first (a
    busy store: the client must try again).
    """

    def __init__(self) -> None:
        from moto.moto_server.werkzeug_app import (
            DomainDispatcherApplication,
            MotoRequestHandler,
            create_backend_app,
        )
        from werkzeug.serving import make_server

        self.tally = Tally()
        self.fail_next_gets = 0
        self._busy_lock = threading.Lock()
        app = DomainDispatcherApplication(create_backend_app)
        class Quiet(MotoRequestHandler):  # type: ignore[misc,valid-type]
            def log(self, *args: Any, **kwargs: Any) -> None:
                pass

        self.server = make_server(LOOPBACK, 0, self._wrap(app), threaded=True,
                                  request_handler=Quiet)
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def _busy(self) -> bool:
        """True (and one fewer to fail) while ``fail_next_gets`` GETs are still to fail."""
        with self._busy_lock:
            if self.fail_next_gets <= 0:
                return False
            self.fail_next_gets -= 1
            return True

    def _wrap(self, app: Callable[..., Iterable[bytes]]) -> Callable[..., Iterable[bytes]]:
        def counted(environ: dict, start_response: Callable[..., Any]) -> Iterable[bytes]:
            auth = environ.get("HTTP_AUTHORIZATION", "")
            ranged = "HTTP_RANGE" in environ
            if "Credential=DENIED/" in auth:
                body = b"" if environ.get("REQUEST_METHOD") == "HEAD" else _DENIED
                start_response("403 Forbidden", [("Content-Type", "application/xml"),
                                                 ("Content-Length", str(len(body)))])
                return [body]
            if ranged and environ.get("REQUEST_METHOD") == "GET" and self._busy():
                start_response("503 Slow Down", [("Content-Type", "application/xml"),
                                                 ("Content-Length", str(len(_SLOW)))])
                return [_SLOW]
            body = b"".join(app(environ, start_response))
            if environ.get("REQUEST_METHOD") == "GET":
                self.tally.add(len(body), ranged)
            return [body]
        return counted

    @property
    def endpoint(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}"

    def put(self, bucket: str, key: str, path: Path) -> str:
        """Upload ``path`` as ``s3://bucket/key`` (creating the bucket); the URL."""
        import boto3

        s3 = boto3.client("s3", endpoint_url=self.endpoint, region_name="us-east-1",
                          aws_access_key_id="testing", aws_secret_access_key="testing")
        try:
            s3.create_bucket(Bucket=bucket)
        except s3.exceptions.BucketAlreadyOwnedByYou:
            pass
        s3.upload_file(str(path), bucket, key)
        return f"s3://{bucket}/{key}"

    def __enter__(self) -> S3Server:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.shutdown()
        self.server.server_close()
        self._thread.join()


def use_s3_server(monkeypatch: Any, endpoint: str, tmp: Path, secret: str = "testing") -> None:
    """Point the standard credential chain at a loopback S3 server (``monkeypatch``: pytest's):
    a test key, the server as endpoint, nothing from the user's ~/.aws and no
    instance-metadata lookup (that would leave the loopback address)."""
    for var in ("AWS_PROFILE", "AWS_SESSION_TOKEN", "AWS_ENDPOINT_URL_S3"):
        monkeypatch.delenv(var, raising=False)
    for var, value in (("AWS_ACCESS_KEY_ID", "testing"), ("AWS_SECRET_ACCESS_KEY", secret),
                       ("AWS_DEFAULT_REGION", "us-east-1"), ("AWS_ENDPOINT_URL", endpoint),
                       ("AWS_EC2_METADATA_DISABLED", "true"),
                       ("AWS_SHARED_CREDENTIALS_FILE", str(tmp / "no-credentials")),
                       ("AWS_CONFIG_FILE", str(tmp / "no-config"))):
        monkeypatch.setenv(var, value)


# ---------------------------------------------------------------------------- a long track
def write_track_granule(path: Path, length_km: float, per_metre: float = 2.0,
                        beams: tuple[str, ...] = ("gt1l", "gt2l", "gt3l"), seed: int = 3,
                        lat0: float = 41.5, lon0: float = -106.57) -> Path:
    """An ATL03 granule of ``length_km`` of forest track per beam (``per_metre`` photons per
    metre), written as real v006 granules are: every dataset in gzip chunks of 10,000 rows
    (shuffle on integers).  The track runs north, about 1 m of latitude per metre."""
    import h5py
    import numpy as np

    from canopyblocks.outputs.h5_layouts import Atl03Background, Atl03BeamData, write_atl03

    rng = np.random.default_rng(seed)
    n = int(length_km * 1000 * per_metre)
    data = {}
    for i, b in enumerate(beams):
        s = np.sort(rng.random(n)) * length_km * 1000.0
        u = rng.random(n)
        h = 2400.0 + 40.0 * np.sin(s / 700.0) + np.where(
            u < 0.45, rng.normal(0, 0.3, n),
            np.where(u < 0.85, rng.random(n) * 25.0, rng.uniform(-60, 90, n)))
        # bckgrd_atlas every 50 shots: the rate of the uniform 15 % (0.3 photons/m over
        # 150 m of height: 0.002 photons/m^2 = 0.21 MHz at 0.7 m a shot)
        tb = np.arange(0.0, length_km * 1000.0 / 7000.0 + 0.005, 0.005)
        data[b] = Atl03BeamData(delta_time=s / 7000.0, lat=lat0 + s * 9.0e-6,
                                lon=lon0 + i * 1e-3 + s * 1.0e-7, h=h, s=s,
                                background=Atl03Background(tb, np.full(tb.size, 0.21e6)))
    raw = path.with_suffix(".raw.h5")
    write_atl03(raw, data)
    tmp = path.with_suffix(".tmp")
    with h5py.File(raw, "r") as src, h5py.File(tmp, "w") as dst:
        def copy(name: str, obj: object) -> None:
            if isinstance(obj, h5py.Dataset):
                kw: dict = {}
                if obj.ndim >= 1 and obj.shape[0] > 0:
                    kw = {"compression": "gzip", "compression_opts": 6,
                          "chunks": (min(10_000, obj.shape[0]), *obj.shape[1:]),
                          "shuffle": np.dtype(obj.dtype).kind in "iu"}
                d = dst.create_dataset(name, data=obj[()], **kw)
                for k, v in obj.attrs.items():
                    d.attrs[k] = v
            elif isinstance(obj, h5py.Group):
                g = dst.require_group(name)
                for k, v in obj.attrs.items():
                    g.attrs[k] = v
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        src.visititems(copy)
    raw.unlink()
    tmp.rename(path)
    return path
