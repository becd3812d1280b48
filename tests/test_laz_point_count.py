"""A LAZ file's point count against its chunk table: a valid laspy-written file is read
whole; a header counting a chunk fewer than the file holds is refused in one line."""

from __future__ import annotations

import struct

import numpy as np
import pytest

laspy = pytest.importorskip("laspy")
pytest.importorskip("lazrs")

from canopyblocks.errors import FileFormatError  # noqa: E402
from canopyblocks.readers.las import read_las  # noqa: E402

N = 144_540  # three fixed-size chunks of 50,000, the last partial


def _write(path, point_format: int, version: str):
    rng = np.random.default_rng(7)
    h = laspy.LasHeader(point_format=point_format, version=version)
    h.scales, h.offsets = [0.01] * 3, [500_000, 4_000_000, 0]
    las = laspy.LasData(h)
    las.x = 500_000 + rng.random(N) * 500
    las.y = 4_000_000 + rng.random(N) * 500
    las.z = rng.random(N) * 30
    las.write(path)
    return las


@pytest.mark.parametrize("point_format, version", [(1, "1.2"), (6, "1.4")])
def test_laspy_written_laz_is_read_whole(tmp_path, point_format, version):
    p = tmp_path / f"pf{point_format}.laz"
    las = _write(p, point_format, version)
    pts = read_las(p, crs="EPSG:32612")
    assert len(pts.x) == N == len(laspy.read(p).points)
    np.testing.assert_allclose(np.sort(pts.z), np.sort(np.asarray(las.z)), atol=0.006)


def test_header_counting_a_chunk_too_few_is_refused(tmp_path):
    p = tmp_path / "under.laz"
    _write(p, 1, "1.2")
    raw = bytearray(p.read_bytes())
    raw[107:111] = struct.pack("<I", 90_000)  # legacy point count: 2 chunks' worth, not 3
    p.write_bytes(bytes(raw))
    with pytest.raises(FileFormatError, match="more points than the 90,000 its header") as e:
        read_las(p, crs="EPSG:32612")
    assert "3 chunks of 50,000" in str(e.value) and "\n" not in str(e.value)


def _refused_line(capsys, tile, out) -> str:
    """``rasters`` on ``tile``: exit 2, one line, no traceback, nothing written."""
    from canopyblocks.cli import main

    assert main(["-q", "rasters", str(tile), "--crs", "EPSG:32612", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("canopyblocks: error: ")]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "IoError" not in err and "fill whole buffer" not in err
    assert not out.exists()
    return lines[0]


@pytest.mark.parametrize("extra, held", [
    (5_000, "the LAZ data runs out about"),  # inside the last chunk's capacity
    (10_000, "the file holds at most 150,000 (its LAZ chunk table)"),  # beyond it
])
def test_laz_header_counting_more_points_than_the_file_holds(tmp_path, capsys, extra, held):
    p = tmp_path / "over.laz"
    _write(p, 1, "1.2")
    raw = bytearray(p.read_bytes())
    raw[107:111] = struct.pack("<I", N + extra)
    p.write_bytes(bytes(raw))
    line = _refused_line(capsys, p, tmp_path / "out")
    assert f"{p}: its header counts {N + extra:,} points, more than the file holds (" in line
    assert held in line and "write it again with a LAS tool" in line, line


def test_las_header_counting_more_points_says_what_to_do(tmp_path, capsys):
    p = tmp_path / "over.las"
    _write(p, 1, "1.2")
    raw = bytearray(p.read_bytes())
    raw[107:111] = struct.pack("<I", N + 5_000)
    p.write_bytes(bytes(raw))
    line = _refused_line(capsys, p, tmp_path / "out")
    assert f"its header counts {N + 5_000}" in line and f"hold {N} points" in line, line
    assert "copy or download it again" in line and "write it again with a LAS tool" in line
