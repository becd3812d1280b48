"""LAS/LAZ reader on the real sample tiles, checked against laspy read directly."""

from __future__ import annotations

import shutil

import laspy
import numpy as np
import pytest

from canopyblocks.errors import CRSError, FileFormatError, InputError, NoUsableDataError
from canopyblocks.readers.las import LasPoints, las_crs, read_las

BCTS1 = "als/lasR_bcts_1.laz"
BCTS2 = "als/lasR_bcts_2.laz"


def test_real_tile_counts_and_crs(sample):
    pts = read_las(sample(BCTS1))
    # /work/shared/data/README.md: 532k points, EPSG:3005, heights 325-362 m
    assert len(pts) == 531_662
    assert pts.crs.to_epsg() == 3005
    assert 325.0 <= pts.z.min() < 326.0 and 358.0 < pts.z.max() <= 362.0
    assert set(np.unique(pts.classification)) == {1, 2}
    assert pts.return_number.min() >= 1 and pts.number_of_returns.max() <= 4
    # VerticalCSTypeGeoKey of the file is 5713 (CGVD28), its GeoASCII string says CGVD28
    assert pts.vertical_datum == "EPSG:5713"
    assert las_crs(sample(BCTS1)).to_epsg() == 3005


def test_two_tiles_and_bbox_against_laspy(sample):
    both = read_las([sample(BCTS1), sample(BCTS2)])
    assert len(both) == 531_662 + 823_945
    bbox = (885100.0, 629350.0, 885150.0, 629450.0)  # straddles the tile boundary y=629400
    sub = read_las([sample(BCTS1), sample(BCTS2)], bbox=bbox)
    expected = 0
    for f in (BCTS1, BCTS2):
        las = laspy.read(sample(f))
        x, y = np.asarray(las.x), np.asarray(las.y)
        expected += int(np.sum((x >= bbox[0]) & (x <= bbox[2]) & (y >= bbox[1]) & (y <= bbox[3])))
    assert len(sub) == expected > 1000
    assert sub.x.min() >= bbox[0] and sub.y.max() <= bbox[3]


def test_exclude_classes(sample):
    las = laspy.read(sample("als/pyfor_test.laz"))
    n7 = int(np.sum(np.asarray(las.classification) == 7))
    assert n7 > 0
    pts = read_las(sample("als/pyfor_test.laz"), exclude_classes=(7,))
    assert len(pts) == 217_222 - n7
    assert pts.crs.to_epsg() == 32617
    assert 7 not in set(np.unique(pts.classification))


def test_tiles_in_different_crs_refused(sample):
    with pytest.raises(CRSError, match="differs from the first tile"):
        read_las([sample(BCTS1), sample("als/pyfor_test.laz")])


def test_given_crs_conflicting_with_file(sample):
    with pytest.raises(CRSError, match="differs from the CRS given"):
        read_las(sample(BCTS1), crs=32610)


def _write_plain_las(path, n=50):
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500000.0, 5000000.0, 0.0])
    las = laspy.LasData(header)
    rng = np.random.default_rng(0)
    las.x = 500000 + rng.random(n) * 10
    las.y = 5000000 + rng.random(n) * 10
    las.z = rng.random(n)
    las.write(path)


def test_file_without_crs(tmp_path):
    p = tmp_path / "nocrs.las"
    _write_plain_las(p)
    assert las_crs(p) is None
    with pytest.raises(CRSError, match="states no CRS"):
        read_las(p)
    pts = read_las(p, crs="EPSG:32610")
    assert len(pts) == 50 and pts.crs.to_epsg() == 32610
    with pytest.raises(CRSError, match="not projected"):
        read_las(p, crs=4326)


def test_missing_truncated_and_empty(tmp_path, sample):
    with pytest.raises(FileFormatError, match="no such file"):
        read_las(tmp_path / "absent.laz")
    bad = tmp_path / "cut.laz"
    data = sample(BCTS1).read_bytes()
    bad.write_bytes(data[: len(data) // 3])
    with pytest.raises(FileFormatError, match="cut.laz"):
        read_las(bad)
    junk = tmp_path / "junk.las"
    junk.write_bytes(b"not a las file at all" * 10)
    with pytest.raises(FileFormatError, match="junk.las"):
        read_las(junk)
    with pytest.raises(NoUsableDataError, match="no points"):
        read_las(sample(BCTS1), bbox=(0, 0, 1, 1))
    with pytest.raises(InputError, match="bbox"):
        read_las(sample(BCTS1), bbox=(10, 0, 1, 1))
    copy = tmp_path / "copy.laz"
    shutil.copy(sample(BCTS1), copy)
    assert len(read_las(copy, bbox=(885022, 629157, 885050, 629200))) > 0


def test_from_arrays_validates():
    with pytest.raises(InputError, match="equal length"):
        LasPoints.from_arrays([0, 1], [0], [0, 1], crs=32610)
    with pytest.raises(CRSError):
        LasPoints.from_arrays([0], [0], [0], crs=4326)


def test_rows_refer_to_the_files(sample):
    """``row`` numbers points across the files before cropping: stable under a bbox."""
    bbox = (885100.0, 629350.0, 885150.0, 629450.0)
    sub = read_las([sample(BCTS1), sample(BCTS2)], bbox=bbox)
    first = laspy.read(sample(BCTS1))
    second = laspy.read(sample(BCTS2))
    n1 = len(first.points)
    z_all = np.concatenate([np.asarray(first.z), np.asarray(second.z)])
    x_all = np.concatenate([np.asarray(first.x), np.asarray(second.x)])
    assert np.array_equal(z_all[sub.row], sub.z) and np.array_equal(x_all[sub.row], sub.x)
    assert sub.row.min() < n1 <= sub.row.max()
    assert np.array_equal(sub.subset(sub.z > 340).row, sub.row[sub.z > 340])


def _with_header_extent(src, dst, mins, maxs):
    import struct

    data = bytearray(src.read_bytes())
    # LAS public header: max x, min x, max y, min y at byte 179 (doubles)
    struct.pack_into("<4d", data, 179, maxs[0], mins[0], maxs[1], mins[1])
    dst.write_bytes(bytes(data))
    return dst


def test_las_bounds_are_the_points_not_a_lying_header(sample, tmp_path):
    """simulate places its track by las_bounds: a header extent that lies used to give
    'the survey is smaller than the footprint' or 'no points in the file'."""
    import warnings

    import laspy

    from canopyblocks.errors import FileFormatError
    from canopyblocks.readers.las import las_bounds

    src = sample("als/lidR_MixedConifer.laz")
    las = laspy.read(src)
    truth = (las.x.min(), las.y.min(), las.x.max(), las.y.max())
    assert las_bounds(src) == pytest.approx(truth, abs=1e-6)
    tiny = _with_header_extent(src, tmp_path / "tiny.laz", truth[:2],
                               (truth[0] + 1, truth[1] + 1))
    with pytest.raises(FileFormatError, match="header says the points lie in"):
        las_bounds(tiny)
    assert las_bounds(tiny, verify=False)[2] == pytest.approx(truth[0] + 1)
    for name, mins, maxs in (("nan", (float("nan"),) * 2, (float("nan"),) * 2),
                             ("swapped", truth[2:], truth[:2])):
        bad = _with_header_extent(src, tmp_path / f"{name}.laz", mins, maxs)
        with warnings.catch_warnings(record=True) as ws:
            warnings.simplefilter("always")
            got = las_bounds(bad, verify=False)
        assert got == pytest.approx(truth, abs=1e-6)
        assert any("cannot be right" in str(w.message) for w in ws)
        with pytest.warns(UserWarning, match="cannot be right"):
            pts = read_las(bad, bbox=(truth[0], truth[1], truth[0] + 20, truth[1] + 20))
        assert len(pts) > 0  # a header that cannot be right skips no tile
