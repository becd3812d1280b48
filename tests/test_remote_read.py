"""Granules read from object storage: real servers on the loopback address only.

An S3 store (moto's S3 application served on 127.0.0.1, a free port) and a static HTTP
server with range requests (``tests/loopback_servers.py``), started by fixtures; no network.
The blocks of a granule read from ``s3://`` or ``https://`` (or an open file object) must be
identical to those of the local file; a bbox must fetch fewer bytes (counted by the server,
not by the client); every failure ends as one line naming the URL and what to do.
"""

from __future__ import annotations

import io
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("s3fs")
pytest.importorskip("aiohttp")
pytest.importorskip("moto")

from canopyblocks import BlockParams, blocks_from_file  # noqa: E402
from canopyblocks.errors import FileFormatError, InputError  # noqa: E402
from canopyblocks.readers import read_atl03, remote  # noqa: E402
from canopyblocks.readers.sniff import file_info  # noqa: E402
from loopback_servers import RangeHTTPServer, S3Server, write_track_granule  # noqa: E402

PARAMS = BlockParams(lengths=(25.0,))
ATL03 = "icesat2/vegr_atl03_clip.h5"
HARMONY = "icesat2/harmony_ATL03_gt1l.h5"
SECRET = "wJalrXUtnFEMI-not-a-real-secret"


@pytest.fixture(scope="module")
def granule_dir(tmp_path_factory, sample):
    root = tmp_path_factory.mktemp("store")
    for rel in (ATL03, HARMONY):
        shutil.copy(sample(rel), root / Path(rel).name)
    # 30 km of three beams at 2 photons/m in 10,000-row chunks: a bbox has chunks to skip
    write_track_granule(root / "ATL03_long.h5", 30.0, 2.0)
    (root / "private").mkdir()
    shutil.copy(sample(ATL03), root / "private" / "granule.h5")
    return root


@pytest.fixture(scope="module")
def s3_server(granule_dir):
    with S3Server() as server:
        for p in sorted(granule_dir.glob("*.h5")):
            server.put("granules", f"ATL03/{p.name}", p)
        yield server


@pytest.fixture
def s3_env(s3_server, monkeypatch, tmp_path):
    """The standard chain pointed at the loopback store; nothing from the user's ~/.aws and
    no instance-metadata lookup (that would leave the loopback address)."""
    for var in ("AWS_PROFILE", "AWS_SESSION_TOKEN", "AWS_ENDPOINT_URL_S3"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "testing")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", SECRET)
    monkeypatch.setenv("AWS_DEFAULT_REGION", "us-east-1")
    monkeypatch.setenv("AWS_ENDPOINT_URL", s3_server.endpoint)
    monkeypatch.setenv("AWS_EC2_METADATA_DISABLED", "true")
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "no-credentials"))
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "no-config"))
    monkeypatch.setattr(remote, "BACKOFF", 0.01)
    remote.clear_cache()
    s3_server.fail_next_gets = 0
    s3_server.tally.reset()
    return s3_server


@pytest.fixture(scope="module")
def http_server(granule_dir):
    with RangeHTTPServer(granule_dir) as server:
        yield server


@pytest.fixture
def http(http_server, monkeypatch):
    monkeypatch.setattr(remote, "BACKOFF", 0.01)
    remote.clear_cache()
    http_server.tally.reset()
    return http_server


def _same(a: pd.DataFrame, b: pd.DataFrame) -> None:
    assert len(a) > 0
    pd.testing.assert_frame_equal(a, b, check_exact=True)


# ------------------------------------------------------------------- the same numbers
@pytest.mark.parametrize("name", [Path(ATL03).name, Path(HARMONY).name])
def test_blocks_from_s3_identical_to_local(s3_env, sample, name):
    local = blocks_from_file(sample(f"icesat2/{name}"), PARAMS).blocks
    got = blocks_from_file(f"s3://granules/ATL03/{name}", PARAMS).blocks
    _same(got, local)
    assert s3_env.tally.range_requests == s3_env.tally.requests > 0  # ranges, not the file


def test_blocks_from_https_identical_to_local(http, sample):
    local = blocks_from_file(sample(ATL03), PARAMS).blocks
    got = blocks_from_file(f"{http.url}/{Path(ATL03).name}", PARAMS).blocks
    _same(got, local)
    assert http.tally.requests == http.tally.range_requests > 0


def test_whole_long_granule_same_photons_as_local(s3_env, granule_dir):
    # many chunks per column: the concurrent chunk fetch and the threaded inflate
    url = "s3://granules/ATL03/ATL03_long.h5"
    a = read_atl03(url, "gt2l")
    b = read_atl03(granule_dir / "ATL03_long.h5", "gt2l")
    assert len(a) == 60_000
    for col in ("time", "lat", "lon", "h", "s", "x", "y"):
        assert np.array_equal(getattr(a, col), getattr(b, col)), col
    assert a.source == url


def test_file_objects_identical_to_local(s3_env, sample):
    """What earthaccess.open returns (an fsspec file) and a plain binary file object."""
    import s3fs

    local = blocks_from_file(sample(ATL03), PARAMS).blocks
    fs = s3fs.S3FileSystem(endpoint_url=s3_env.endpoint, key="testing", secret=SECRET)
    with fs.open("granules/ATL03/vegr_atl03_clip.h5", "rb") as fh:
        _same(blocks_from_file(fh, PARAMS).blocks, local)
    with io.BytesIO(Path(sample(ATL03)).read_bytes()) as fh:
        _same(blocks_from_file(fh, PARAMS).blocks, local)


@pytest.mark.filterwarnings("ignore:.*can differ from a run over the whole track")
def test_bbox_fetches_fewer_bytes_and_the_same_photons(s3_env, granule_dir):
    url = "s3://granules/ATL03/ATL03_long.h5"
    size = (granule_dir / "ATL03_long.h5").stat().st_size
    whole = blocks_from_file(url, PARAMS, workers=1).blocks
    whole_bytes = s3_env.tally.nbytes
    remote.clear_cache()
    s3_env.tally.reset()
    mid = 41.5 + 15_000 * 9.0e-6  # 15 km along the track (it runs north, 9e-6 deg/m)
    bbox = (-106.58, mid - 1_000 * 9.0e-6, -106.55, mid + 1_000 * 9.0e-6)  # 2 km of 30
    got = blocks_from_file(url, PARAMS, bbox=bbox, workers=1).blocks
    _same(got, blocks_from_file(granule_dir / "ATL03_long.h5", PARAMS, bbox=bbox).blocks)
    # 2 km of 30 km plus the classifier's context (2 x 480 m, read then cut away): the
    # photons of the 5 km chunks they touch per column, the segment index and the background
    # records (bckgrd_atlas, read whole: the rate of the whole track), and the first chunk
    # per column (the track's first photon: the origin of the full run's block grid); of a
    # track of six chunks, so the share is high (measured 0.95; 0.80 without the start)
    assert s3_env.tally.nbytes < 0.97 * size, (s3_env.tally.nbytes, size)
    assert s3_env.tally.nbytes < 0.97 * whole_bytes
    assert whole_bytes >= 0.8 * size  # the whole read really read the photons
    assert len(got) < len(whole) / 5


def test_info_from_url(http, sample):
    info = file_info(f"{http.url}/{Path(ATL03).name}")
    local = file_info(sample(ATL03))
    assert info["path"] == f"{http.url}/{Path(ATL03).name}"
    assert {k: v for k, v in info.items() if k != "path"} == \
        {k: v for k, v in local.items() if k != "path"}


def test_transient_503_is_retried(s3_env, sample):
    s3_env.fail_next_gets = 3  # the store is busy for three range requests
    got = blocks_from_file("s3://granules/ATL03/vegr_atl03_clip.h5", PARAMS).blocks
    _same(got, blocks_from_file(sample(ATL03), PARAMS).blocks)
    assert s3_env.fail_next_gets == 0


# ------------------------------------------------------------------- failures, one line
def _one_line(exc: pytest.ExceptionInfo[BaseException], url: str, *words: str,
              storage: bool = True) -> str:
    assert isinstance(exc.value, remote.StorageError) == storage, repr(exc.value)
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith(url), msg
    for w in words:
        assert w in msg, msg
    assert SECRET not in msg and "testing" not in msg, msg
    return msg


def test_s3_not_found(s3_env):
    url = "s3://granules/ATL03/ATL03_missing.h5"
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(url, PARAMS)
    _one_line(exc, url, "not found", "404", "bucket and key")


def test_https_not_found_keeps_the_signature_secret(http):
    url = f"{http.url}/ATL03_missing.h5"
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(f"{url}?X-Amz-Signature={SECRET}&token={SECRET}", PARAMS)
    _one_line(exc, url, "not found", "404")


def test_s3_access_denied(s3_env, monkeypatch):
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "DENIED")  # a key the store refuses
    url = "s3://granules/ATL03/vegr_atl03_clip.h5"
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(url, PARAMS)
    _one_line(exc, url, "access denied", "403", "AWS_ACCESS_KEY_ID")


def test_https_forbidden(http):
    url = f"{http.url}/private/granule.h5"
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(url, PARAMS)
    _one_line(exc, url, "access denied", "403", "earthaccess.login()")


def test_s3_missing_credentials(s3_env, monkeypatch):
    monkeypatch.delenv("AWS_ACCESS_KEY_ID")
    monkeypatch.delenv("AWS_SECRET_ACCESS_KEY")
    url = "s3://granules/ATL03/vegr_atl03_clip.h5"
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(url, PARAMS)
    _one_line(exc, url, "no credentials", "AWS_ACCESS_KEY_ID", "earthaccess")


def test_https_dropped_connection(http):
    url = f"{http.url}/drop/granule.h5"
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(url, PARAMS)
    _one_line(exc, url, "connection failed", f"after {remote.RETRIES + 1} tries",
              "check the network")


def test_https_timed_out(http, monkeypatch):
    import time

    monkeypatch.setenv("CANOPYBLOCKS_TIMEOUT", "0.3")  # the server keeps silent for 2 s
    url = f"{http.url}/slow/granule.h5"
    t0 = time.monotonic()
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(url, PARAMS)
    assert time.monotonic() - t0 < 1.5  # given up after the time-out, not tried again
    _one_line(exc, url, "no answer within 0.3 s", "CANOPYBLOCKS_TIMEOUT")


def test_store_down_in_the_middle_of_a_read(granule_dir, monkeypatch, tmp_path):
    monkeypatch.setattr(remote, "BACKOFF", 0.01)
    remote.clear_cache()
    out = tmp_path / "blocks.parquet"
    with RangeHTTPServer(granule_dir, fail_after=12) as server:
        url = f"{server.url}/ATL03_long.h5"
        with pytest.raises(FileFormatError) as exc:
            blocks_from_file(url, PARAMS, output=out, workers=1)
        assert server.tally.requests == 12  # it had read part of the granule
    _one_line(exc, url, "connection failed", "HTTP 503", "run again")
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_s3_store_gone(s3_env, monkeypatch):
    # a port nothing listens on (bound, then closed): the connection is refused
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{port}")
    url = "s3://granules/ATL03/vegr_atl03_clip.h5"
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(url, PARAMS)
    _one_line(exc, url, "connection failed", "AWS_ENDPOINT_URL")


def test_not_hdf5_and_bad_argument(http, granule_dir):
    (granule_dir / "notes.h5").write_text("not a granule")
    url = f"{http.url}/notes.h5"
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(url, PARAMS)
    _one_line(exc, url, "not an HDF5 file", storage=False)
    with pytest.raises(InputError):
        blocks_from_file(12, PARAMS)  # type: ignore[arg-type]


# ------------------------------------------------------------------- the command line
def _cli(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    import os

    full = dict(os.environ, **(env or {}))
    return subprocess.run([sys.executable, "-m", "canopyblocks", "-q", *args],
                          capture_output=True, text=True, timeout=300, env=full)


def _aws(server: S3Server, key: str = "testing") -> dict[str, str]:
    import os

    return {"AWS_ACCESS_KEY_ID": key, "AWS_SECRET_ACCESS_KEY": SECRET,
            "AWS_DEFAULT_REGION": "us-east-1", "AWS_ENDPOINT_URL": server.endpoint,
            "AWS_EC2_METADATA_DISABLED": "true",
            "AWS_SHARED_CREDENTIALS_FILE": os.devnull, "AWS_CONFIG_FILE": os.devnull}


def test_cli_blocks_from_s3_identical_to_local(s3_env, sample, tmp_path):
    env = _aws(s3_env)
    out_s3, out_local = tmp_path / "s3.parquet", tmp_path / "local.parquet"
    r = _cli("blocks", "s3://granules/ATL03/vegr_atl03_clip.h5", "-o", str(out_s3), env=env)
    assert r.returncode == 0, r.stderr
    r = _cli("blocks", str(sample(ATL03)), "-o", str(out_local), env=env)
    assert r.returncode == 0, r.stderr
    _same(pd.read_parquet(out_s3), pd.read_parquet(out_local))
    r = _cli("info", "s3://granules/ATL03/vegr_atl03_clip.h5", env=env)
    assert r.returncode == 0 and "ATL03" in r.stdout, r.stderr


def test_cli_failures_one_line_nothing_written(s3_env, tmp_path):
    out = tmp_path / "blocks.parquet"
    for url, key, words in (
            ("s3://granules/ATL03/ATL03_missing.h5", "testing", ("not found",)),
            ("s3://granules/ATL03/vegr_atl03_clip.h5", "DENIED", ("access denied",))):
        r = _cli("blocks", url, "-o", str(out), env=_aws(s3_env, key))
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"canopyblocks: error: {url}: "), lines
        assert all(w in lines[0] for w in words) and SECRET not in r.stderr, lines
        assert list(tmp_path.iterdir()) == []  # nothing half-written


# ------------------------------------------------------------------- many granules
def test_batch_inputs_from_a_list_and_a_prefix(s3_env, tmp_path):
    from canopyblocks.workflows.batch.units import list_inputs

    listing = tmp_path / "granules.txt"
    listing.write_text("# granules of the study area\n"
                       "s3://granules/ATL03/vegr_atl03_clip.h5\n\n"
                       "s3://granules/ATL03/harmony_ATL03_gt1l.h5\n", encoding="utf-8")
    assert list_inputs([str(listing)], (".h5",)) == [
        "s3://granules/ATL03/harmony_ATL03_gt1l.h5", "s3://granules/ATL03/vegr_atl03_clip.h5"]
    assert list_inputs(["s3://granules/ATL03/"], (".h5",)) == [
        f"s3://granules/ATL03/{n}" for n in ("ATL03_long.h5", "harmony_ATL03_gt1l.h5",
                                             "vegr_atl03_clip.h5")]


def test_cli_batch_takes_urls(s3_env, tmp_path):
    """click does not refuse a URL as a missing file; an empty prefix is said in one line."""
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    url = "s3://granules/nothing-here/"
    r = _cli("batch", url, "--tiles", str(tiles), "-o", str(tmp_path / "out"),
             env=_aws(s3_env))
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and url in lines[0] and "no input files" in lines[0], lines
    assert "does not exist" not in r.stderr


def test_nasa_bucket_keys_from_earthaccess(s3_env, sample, monkeypatch):
    """No AWS keys, a bucket of NASA's archive: Earthdata's temporary keys through
    earthaccess (here a stand-in module handing out keys the loopback store accepts)."""
    import types

    asked: list[str] = []
    fake = types.ModuleType("earthaccess")
    fake.__auth__ = types.SimpleNamespace(authenticated=True)  # type: ignore[attr-defined]

    def get_s3_credentials(daac: str) -> dict[str, str]:
        asked.append(daac)
        return {"accessKeyId": "testing", "secretAccessKey": SECRET, "sessionToken": "t",
                "expiration": "later"}

    fake.get_s3_credentials = get_s3_credentials  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "earthaccess", fake)
    s3_env.put("nsidc-cumulus-prod-protected", "ATLAS/ATL03/006/vegr_atl03_clip.h5",
               sample(ATL03))
    monkeypatch.delenv("AWS_ACCESS_KEY_ID")
    monkeypatch.delenv("AWS_SECRET_ACCESS_KEY")
    url = "s3://nsidc-cumulus-prod-protected/ATLAS/ATL03/006/vegr_atl03_clip.h5"
    _same(blocks_from_file(url, PARAMS).blocks, blocks_from_file(sample(ATL03), PARAMS).blocks)
    assert asked == ["NSIDC"]  # once: the keys are kept for the hour they last
    # earthaccess without a login: the standard chain decides, and says what to do
    remote.clear_cache()
    fake.__auth__ = types.SimpleNamespace(authenticated=False)  # type: ignore[attr-defined]
    fake.login = lambda strategy: None  # type: ignore[attr-defined]
    with pytest.raises(FileFormatError) as exc:
        blocks_from_file(url, PARAMS)
    _one_line(exc, url, "no credentials", "earthaccess")


def test_gedi_footprints_from_https_identical_to_local(gedi_l1b, monkeypatch):
    from canopyblocks.workflows.waveforms import footprints_from_l1b

    monkeypatch.setattr(remote, "BACKOFF", 0.01)
    remote.clear_cache()
    with RangeHTTPServer(gedi_l1b.parent) as server:
        url = f"{server.url}/{gedi_l1b.name}"
        got = footprints_from_l1b(url)[0]
        assert server.tally.requests == server.tally.range_requests > 0
    local = footprints_from_l1b(gedi_l1b)[0]
    assert len(local) == 300
    _same(got, local)
