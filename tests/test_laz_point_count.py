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
