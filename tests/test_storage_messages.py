"""Messages that name the real cause when a file is read over the network, against real
servers on the loopback address (tests/loopback_servers.py): a tile URL, https to a plain
http server, a server without byte ranges under ``batch``, a server that stops answering
in the middle of a read (ATL03 and GEDI)."""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import pytest

from canopyblocks.cli import main
from loopback_servers import RangeHTTPServer

ATL03 = "icesat2/vegr_atl03_clip.h5"
GEDI_ZIP = "gedi/GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.zip"


def error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("canopyblocks: error:")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture()
def served(tmp_path: Path, sample) -> Path:
    root = tmp_path / "served"
    (root / "norange").mkdir(parents=True)
    shutil.copy(sample(ATL03), root / "atl03.h5")
    shutil.copy(sample(ATL03), root / "norange" / "atl03.h5")
    shutil.copy(sample("als/lidR_Topography.laz"), root / "tile.laz")
    with zipfile.ZipFile(sample(GEDI_ZIP)) as z:
        name = z.namelist()[0]
        (root / "gedi.h5").write_bytes(z.read(name))
    return root


@pytest.fixture()
def quick_retries(monkeypatch: pytest.MonkeyPatch) -> None:
    import canopyblocks.readers.remote as remote

    monkeypatch.setattr(remote, "RETRIES", 0)
    monkeypatch.setattr(remote, "BACKOFF", 0.0)
    monkeypatch.setenv("CANOPYBLOCKS_TIMEOUT", "10")


def test_a_tile_url_is_named_as_given_not_as_a_missing_path(served, tmp_path, capsys) -> None:
    with RangeHTTPServer(served) as s:
        url = f"{s.url}/tile.laz"
        assert main(["-q", "run", url, "--simulate", "-o", str(tmp_path / "out")]) == 2
    line = error_line(capsys)
    assert url in line and "http:/1" not in line, line
    assert "no such file" not in line and "download the tile" in line, line
    assert not (tmp_path / "out").exists()


def test_https_to_a_plain_http_server_says_so(served, tmp_path, capsys, quick_retries) -> None:
    with RangeHTTPServer(served) as s:
        url = s.url.replace("http://", "https://") + "/atl03.h5"
        assert main(["-q", "blocks", url, "-o", str(tmp_path / "b.csv")]) == 2
    line = error_line(capsys)
    assert url in line and "does not speak https" in line and "http:// URL" in line, line
    assert "SSL" not in line and "Client" not in line, f"a library's class named: {line}"


def test_batch_on_a_server_without_byte_ranges_names_it(served, tmp_path, sample,
                                                         capsys) -> None:
    out = tmp_path / "batch"
    with RangeHTTPServer(served) as s:
        url = f"{s.url}/norange/atl03.h5"
        code = main(["-q", "batch", url, "--tiles", str(sample("als/lidR_Topography.laz")),
                     "-o", str(out)])
    assert code == 2
    line = error_line(capsys)
    assert url in line and "does not support byte ranges" in line, line
    assert "crosses" not in line and "StorageError" not in line, line
    assert not out.exists(), "an empty output folder was left behind"


@pytest.mark.parametrize("what", ["atl03", "gedi"])
def test_a_server_that_stops_answering_is_named(what, served, tmp_path, capsys,
                                                quick_retries) -> None:
    """The server stops after its third answer (while the file's beams are listed): the
    message is the server's failure, never "no usable photons" nor "not a GEDI file"."""
    from canopyblocks.readers.remote import clear_cache

    name = "atl03.h5" if what == "atl03" else "gedi.h5"
    cmd = "blocks" if what == "atl03" else "waveforms"
    clear_cache()
    with RangeHTTPServer(served, fail_after=3) as s:
        url = f"{s.url}/{name}"
        assert main(["-q", cmd, url, "-o", str(tmp_path / "o.gpkg")]) == 2
    line = error_line(capsys)
    # the server's failure: its 503, or its silence when it stopped mid-answer
    assert url in line and ("503" in line or "no answer" in line), line
    for bad in ("no usable photons", "not a GEDI", "no photons", "damaged"):
        assert bad not in line, line
