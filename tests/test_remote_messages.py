"""What a server or the configuration did, in the project's words: a server without byte
ranges, a short range answer, a connection closed half-way, an endpoint that never answers
(the same time-out over s3:// as https://), an AWS profile that does not exist, an endpoint
that is not a URL, a prefix where a granule is expected, an ftp:// URL.  Loopback servers
(``tests/loopback_servers.py``); short time-outs (``CANOPYBLOCKS_TIMEOUT``)."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import pytest

pytest.importorskip("s3fs")
pytest.importorskip("aiohttp")
pytest.importorskip("moto")

from canopyblocks import BlockParams, blocks_from_file  # noqa: E402
from canopyblocks.errors import CanopyBlocksError  # noqa: E402
from canopyblocks.readers import remote  # noqa: E402
from canopyblocks.readers.sniff import file_info  # noqa: E402
from loopback_servers import RangeHTTPServer, S3Server  # noqa: E402

PARAMS = BlockParams(lengths=(25.0,))
CLIP = "icesat2/vegr_atl03_clip.h5"


@pytest.fixture(scope="module")
def server(tmp_path_factory, sample):
    root = tmp_path_factory.mktemp("odd_store")
    for sub in ("norange", "short", "cut"):
        (root / sub).mkdir()
        shutil.copy(sample(CLIP), root / sub / "granule.h5")
    with RangeHTTPServer(root) as s:
        yield s


@pytest.fixture
def quick(monkeypatch, tmp_path):
    monkeypatch.setattr(remote, "BACKOFF", 0.01)
    monkeypatch.setattr(remote, "RETRIES", 1)
    monkeypatch.setenv("CANOPYBLOCKS_TIMEOUT", "0.5")
    for var in ("AWS_PROFILE", "AWS_SESSION_TOKEN", "AWS_ENDPOINT_URL_S3"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "testing")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "testing-secret")
    monkeypatch.setenv("AWS_DEFAULT_REGION", "us-east-1")
    monkeypatch.setenv("AWS_EC2_METADATA_DISABLED", "true")
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "no-credentials"))
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "no-config"))
    remote.clear_cache()


def _refused(source: str, *words: str, seconds: float = 5.0) -> str:
    t0 = time.monotonic()
    with pytest.raises(CanopyBlocksError) as exc:
        blocks_from_file(source, PARAMS)
    assert time.monotonic() - t0 < seconds
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(remote.source_label(source)), msg
    for w in words:
        assert w in msg, msg
    return msg


@pytest.mark.parametrize("kind, words", [
    ("norange", ("does not support byte ranges", "download")),
    ("short", ("answers were short", "of the")),
    ("cut", ("closed the connection in the middle of an answer",)),
])
def test_what_the_server_did(server, quick, kind, words):
    msg = _refused(f"{server.url}/{kind}/granule.h5", *words)
    assert "EOFError" not in msg and "HTTP 400" not in msg and "usable photons" not in msg


def test_s3_endpoint_that_never_answers_ends_at_the_time_out(server, quick, monkeypatch):
    monkeypatch.setenv("AWS_ENDPOINT_URL", server.url)  # s3://slow/...: HEAD /slow/... sleeps
    _refused("s3://slow/granule.h5", "no answer within 0.5 s", "CANOPYBLOCKS_TIMEOUT",
             seconds=4.0)


def test_https_that_never_answers_same_time_out(server, quick):
    _refused(f"{server.url}/slow/granule.h5", "no answer within 0.5 s", seconds=4.0)


def test_aws_profile_not_found(server, quick, monkeypatch):
    monkeypatch.delenv("AWS_ACCESS_KEY_ID")
    monkeypatch.delenv("AWS_SECRET_ACCESS_KEY")
    monkeypatch.setenv("AWS_PROFILE", "nosuchprofile")
    monkeypatch.setenv("AWS_ENDPOINT_URL", server.url)
    msg = _refused("s3://granules/ATL03/granule.h5", "'nosuchprofile'", "AWS_PROFILE")
    assert "(ProfileNotFound)" not in msg


def test_endpoint_not_a_url(quick, monkeypatch):
    monkeypatch.setenv("AWS_ENDPOINT_URL", "not a url")
    msg = _refused("s3://granules/ATL03/granule.h5", "AWS_ENDPOINT_URL", "not the URL")
    assert "(ValueError)" not in msg


def test_a_prefix_is_not_a_granule(quick, monkeypatch, sample):
    with S3Server() as s3:
        s3.put("granules", "ATL03/vegr_atl03_clip.h5", Path(sample(CLIP)))
        monkeypatch.setenv("AWS_ENDPOINT_URL", s3.endpoint)
        for url in ("s3://granules/ATL03/", "s3://granules/ATL03"):
            remote.clear_cache()
            msg = _refused(url, "is a prefix", "one file's URL")
            assert "not an HDF5 file" not in msg
            with pytest.raises(CanopyBlocksError, match="is a prefix"):
                file_info(url)


def test_ftp_is_named_as_an_unsupported_scheme(tmp_path):
    url = "ftp://example.org/data/ATL03_x.h5"
    with pytest.raises(CanopyBlocksError) as exc:
        blocks_from_file(url, PARAMS)
    msg = str(exc.value)
    assert msg.startswith(url) and "ftp:// is not a source" in msg, msg
    assert "ftp:/example" not in msg and "does not exist" not in msg


def test_bad_time_out_value(server, quick, monkeypatch):
    monkeypatch.setenv("CANOPYBLOCKS_TIMEOUT", "soon")
    with pytest.raises(CanopyBlocksError, match="CANOPYBLOCKS_TIMEOUT='soon'"):
        blocks_from_file(f"{server.url}/norange/granule.h5", PARAMS)
