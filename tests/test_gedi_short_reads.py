"""A GEDI granule whose bytes do not all arrive is named for what happened, never "not a
GEDI file": over http, a server whose range answers are short (every one, or those above a
proxy's limit) or that holds a truncated copy; on disk, a file cut short.  ``canopyblocks
waveforms`` (in-process) exits 2 with one line, no traceback, and writes nothing.  Real
servers on the loopback address (tests/loopback_servers.py)."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest

pytest.importorskip("aiohttp")

from canopyblocks.cli import main  # noqa: E402
from loopback_servers import RangeHTTPServer  # noqa: E402

L1B_ZIP = "gedi/GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.zip"


@pytest.fixture(scope="module")
def l1b_bytes(sample) -> bytes:
    with zipfile.ZipFile(sample(L1B_ZIP)) as z:
        return z.read(z.namelist()[0])


@pytest.fixture()
def quick(monkeypatch: pytest.MonkeyPatch) -> None:
    import canopyblocks.readers.remote as remote

    monkeypatch.setattr(remote, "RETRIES", 1)
    monkeypatch.setattr(remote, "BACKOFF", 0.0)
    monkeypatch.setenv("CANOPYBLOCKS_TIMEOUT", "10")
    remote.clear_cache()


def _refused(args: list[str], out: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """Exit 2, one line naming the problem, nothing written; the line."""
    assert main(["-q", "waveforms", *args, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("canopyblocks: error: "), err
    assert "Traceback" not in err and "not a gedi" not in err.lower(), err
    assert not out.exists() and list(out.parent.glob("*.part*")) == [], err
    return lines[0]


@pytest.mark.parametrize("mode", ["short", "capped"])
def test_short_range_answers_are_named(mode, l1b_bytes, tmp_path, capsys, quick) -> None:
    root = tmp_path / "served"
    (root / mode).mkdir(parents=True)
    (root / mode / "GEDI01_B.h5").write_bytes(l1b_bytes)
    with RangeHTTPServer(root) as server:
        url = f"{server.url}/{mode}/GEDI01_B.h5"
        line = _refused([url], tmp_path / "out" / "fp.gpkg", capsys)
        asked = server.tally.requests
    assert url in line and "the server's answers were short" in line, line
    assert "of the" in line and "bytes asked for" in line, line
    assert asked >= 2  # tried again before saying so


def test_a_truncated_copy_in_storage_is_named(l1b_bytes, tmp_path, capsys, quick) -> None:
    root = tmp_path / "served"
    root.mkdir()
    (root / "GEDI01_B.h5").write_bytes(l1b_bytes[:len(l1b_bytes) // 2])
    with RangeHTTPServer(root) as server:
        url = f"{server.url}/GEDI01_B.h5"
        line = _refused([url], tmp_path / "out" / "fp.gpkg", capsys)
    assert url in line and "truncated" in line and "download it again" in line, line
    assert f"the server holds {len(l1b_bytes) // 2:,} of the {len(l1b_bytes):,} bytes" in line


@pytest.mark.parametrize("keep", [4, 1000, 0.5, 0.999])
def test_a_truncated_local_file_is_named(keep, l1b_bytes, tmp_path, capsys) -> None:
    n = keep if isinstance(keep, int) else int(len(l1b_bytes) * keep)
    p = tmp_path / "GEDI01_B_cut.h5"
    p.write_bytes(l1b_bytes[:n])
    line = _refused([str(p)], tmp_path / "out" / "fp.gpkg", capsys)
    assert str(p) in line and "download it again" in line, line
    if n >= 8:
        assert "truncated" in line, line
        assert f"it holds {n:,} of the {len(l1b_bytes):,} bytes" in line, line
    else:
        assert f"only {n} bytes" in line and "cut short" in line, line


@pytest.mark.parametrize("start, stop", [(0.6, 1.0), (0.475, 0.525), (0.1, 0.15), (0.7, 0.75)])
def test_a_zero_filled_file_of_full_size_is_named_damaged(start, stop, l1b_bytes, tmp_path,
                                                          capsys) -> None:
    """A preallocated download that stopped (its tail zeroed), or zeroed bytes inside: the
    file says it is damaged, never "not a GEDI file" nor "a subset without datasets"."""
    raw = bytearray(l1b_bytes)
    a, b = int(len(raw) * start), int(len(raw) * stop)
    raw[a:b] = bytes(b - a)
    p = tmp_path / "GEDI01_B_zeroed.h5"
    p.write_bytes(bytes(raw))
    line = _refused([str(p)], tmp_path / "out" / "fp.gpkg", capsys)
    assert f"{p}: the file is damaged (" in line and line.endswith("download it again"), line
    assert "subset" not in line and "HDF5 lists" not in line and "(OSError" not in line, line


def test_a_subset_without_datasets_and_a_foreign_hdf5_keep_their_own_words(
        l1b_bytes, tmp_path, capsys) -> None:
    """What HDF5 can read but is absent stays "subset" / "not a GEDI file"."""
    import h5py

    subset, other = tmp_path / "subset.h5", tmp_path / "other.h5"
    subset.write_bytes(l1b_bytes)
    with h5py.File(subset, "r+") as f:
        del f["BEAM0101/geolocation/elevation_bin0"]
    with h5py.File(other, "w") as f:
        f["x"] = [1, 2]
    line = _refused([str(subset), "--beam", "BEAM0101"], tmp_path / "o1" / "fp.gpkg", capsys)
    assert "was the subset made without these datasets?" in line and "damaged" not in line
    assert main(["-q", "waveforms", str(other), "-o", str(tmp_path / "o2" / "fp.gpkg")]) == 2
    assert "not a GEDI L1B/L2A/L2B file" in capsys.readouterr().err
