"""One reader of a LAS/LAZ file's CRS (issue 23, item 3), checked against PDAL.

PDAL reads a LAS 1.2 file's GeoTIFF keys, vertical part and units included; laspy's
``parse_crs`` reads only the horizontal key.  ``las_file_crs`` must say what PDAL says
(the yardstick: ``pdal info --summary``), and every path (read_las for simulate and the
footprint reference, the rasters, run) must refuse heights in feet and label the vertical
datum the same way.  Also here: heights that cannot be on Earth (item 4).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from badinputs.damage import write_cloud_geokeys
from canopyblocks.errors import CRSError, NoUsableDataError
from canopyblocks.readers.las import las_crs, read_las
from canopyblocks.readers.las_crs import las_file_crs
from canopyblocks.readers.las_summary import las_summary

TILES = ("lasR_bcts_1", "lasR_bcts_2", "lidR_MixedConifer", "lidR_Topography", "pyfor_test")
UTM12 = 26912  # lidR_MixedConifer's horizontal CRS


def _pdal_srs(pdal_bin: str, path: Path) -> dict:
    out = subprocess.run([pdal_bin, "info", "--summary", str(path)], capture_output=True,
                         text=True, check=True, timeout=120)
    return json.loads(out.stdout)["summary"].get("srs") or {}


def _pdal_vertical_epsg(srs: dict) -> int | None:
    text = (srs.get("vertical") or "").strip()
    if not text:
        return None
    v = pyproj.CRS.from_wkt(text)
    return v.to_epsg() if v.name.lower() != "unknown" else None


@pytest.fixture(scope="module")
def conifer(sample) -> dict:
    las = laspy.read(sample("als/lidR_MixedConifer.laz"))
    return {"x": np.asarray(las.x), "y": np.asarray(las.y), "z": np.asarray(las.z),
            "c": np.asarray(las.classification)}


def _tile(tmp_path: Path, pts: dict, keys: list[tuple[int, int]], name: str = "t.las",
          z: np.ndarray | None = None, version: str = "1.2") -> Path:
    return write_cloud_geokeys(tmp_path / name, pts["x"], pts["y"],
                               pts["z"] if z is None else z, pts["c"], keys, version=version)


@pytest.mark.parametrize("name", TILES)
def test_bundled_tiles_read_as_pdal_reads_them(name, sample, pdal_bin) -> None:
    path = sample(f"als/{name}.laz")
    srs = _pdal_srs(pdal_bin, path)
    got = las_file_crs(path)
    want_h = pyproj.CRS.from_wkt(srs["horizontal"])
    assert got.horizontal is not None and got.horizontal.equals(want_h, ignore_axis_order=True)
    want_v = _pdal_vertical_epsg(srs)
    assert got.vertical_name == (f"EPSG:{want_v}" if want_v else "unknown")
    assert las_crs(path).equals(want_h, ignore_axis_order=True)


def test_cgvd28_tile_labelled_by_read_las(sample) -> None:
    # PDAL reads lasR_bcts as NAD83 / BC Albers + CGVD28 height (EPSG:5713) from its keys
    pts = read_las(sample("als/lasR_bcts_1.laz"))
    assert pts.vertical_datum == "EPSG:5713"
    assert las_file_crs(sample("als/lasR_bcts_1.laz")).crs.to_epsg() is None  # compound
    assert "CGVD28" in las_file_crs(sample("als/lasR_bcts_1.laz")).crs.name


@pytest.mark.parametrize("keys,unit", [
    ([(1024, 1), (3072, UTM12), (3076, 9001), (4096, 6360), (4099, 9003)], "US survey foot"),
    ([(1024, 1), (3072, UTM12), (4099, 9002)], "foot"),  # unit key only, no vertical CRS
])
def test_heights_in_feet_refused_by_every_path(keys, unit, conifer, tmp_path, pdal_bin) -> None:
    ft = 1200.0 / 3937.0
    path = _tile(tmp_path, conifer, keys, z=conifer["z"] / ft)
    srs = _pdal_srs(pdal_bin, path)
    assert srs["units"]["vertical"] == unit  # the yardstick: PDAL reads feet
    assert las_file_crs(path).vertical_unit[0] == unit
    with pytest.raises(CRSError, match="foot") as e:
        read_las(path)  # simulate and the footprint reference read through here
    assert str(path) in str(e.value)
    from canopyblocks.reference.rasters import make_reference_rasters

    with pytest.raises(CRSError, match="foot"):
        make_reference_rasters([path], tmp_path / "r", pdal=pdal_bin)
    assert not (tmp_path / "r").exists()


def test_simulate_refuses_feet_from_geotiff_keys(conifer, tmp_path) -> None:
    from canopyblocks.cli import main

    ft = 1200.0 / 3937.0
    path = _tile(tmp_path, conifer, [(1024, 1), (3072, UTM12), (4096, 6360), (4099, 9003)],
                 z=conifer["z"] / ft)
    out = tmp_path / "sim.h5"
    assert main(["-q", "simulate", str(path), "--realisations", "1", "-o", str(out)]) == 2
    assert not out.exists()


def test_vertical_datum_from_keys_matches_pdal(conifer, tmp_path, pdal_bin) -> None:
    path = _tile(tmp_path, conifer, [(1024, 1), (3072, UTM12), (3076, 9001), (4096, 5703),
                                     (4099, 9001)])
    assert _pdal_vertical_epsg(_pdal_srs(pdal_bin, path)) == 5703
    assert read_las(path).vertical_datum == "EPSG:5703"
    assert las_file_crs(path).crs.equals(pyproj.CRS(f"EPSG:{UTM12}+5703"))


def test_las14_geotiff_keys_read_where_pdal_22_reads_none(conifer, tmp_path) -> None:
    path = _tile(tmp_path, conifer, [(1024, 1), (3072, UTM12), (4096, 5703)], version="1.4")
    got = las_file_crs(path)
    assert got.horizontal.to_epsg() == UTM12 and got.vertical_name == "EPSG:5703"


@pytest.mark.parametrize("keys,needle", [
    ([(3072, UTM12), (4096, 5703), (4099, 9003)], "contradict"),  # metre CRS, feet key
    ([(3072, UTM12), (3076, 9003)], "contradict"),  # metre UTM, feet linear-unit key
    ([(3072, 3999)], "does not exist"),
])
def test_contradicting_or_unknown_keys_refused(keys, needle, conifer, tmp_path) -> None:
    path = _tile(tmp_path, conifer, keys)
    with pytest.raises(CRSError, match=needle) as e:
        read_las(path)
    assert str(path) in str(e.value)


# ---- heights that cannot be on Earth -------------------------------------------------------


@pytest.mark.parametrize("shift", [100_000.0, -1_000.0])
def test_terrain_off_the_earth_refused(shift, conifer, tmp_path, pdal_bin) -> None:
    z = conifer["z"] + shift  # MixedConifer's ground is near 0 m: terrain at 100 km / -1 km
    path = _tile(tmp_path, conifer, [(1024, 1), (3072, UTM12)], z=z)
    for call in (lambda: read_las(path), lambda: las_summary(path)):
        with pytest.raises(NoUsableDataError, match="-500 to 9000 m") as e:
            call()
        msg = str(e.value)
        assert str(path) in msg and f"{z.min():.2f}" in msg and f"{z.max():.2f}" in msg
    from canopyblocks.reference.rasters import make_reference_rasters

    with pytest.raises(NoUsableDataError, match="Earth"):
        make_reference_rasters([path], tmp_path / "r", pdal=pdal_bin)


def test_a_few_points_off_the_earth_are_warned_not_refused(conifer, tmp_path) -> None:
    z = conifer["z"].copy()
    bad = np.flatnonzero(conifer["c"] != 2)[:5]
    z[bad] = 20_000.0
    path = _tile(tmp_path, conifer, [(1024, 1), (3072, UTM12)], z=z)
    with pytest.warns(UserWarning, match="5 point"):
        pts = read_las(path)
    assert len(pts) == z.size


def test_integer_height_tally_equals_the_float_one() -> None:
    """las_summary counts on the integer coordinates; the count must equal the one on
    the heights themselves (brute force), at the range's edges too."""
    from canopyblocks.readers.cloud_checks import PLAUSIBLE_HEIGHTS, HeightTally

    rng = np.random.default_rng(3)
    scale, offset = 0.01, -600.0
    lo_i = round((PLAUSIBLE_HEIGHTS[0] - offset) / scale)
    hi_i = round((PLAUSIBLE_HEIGHTS[1] - offset) / scale)
    zi = np.concatenate([rng.integers(-10**6, 2 * 10**6, 5000),
                         [lo_i - 1, lo_i, lo_i + 1, hi_i - 1, hi_i, hi_i + 1]])
    c = rng.choice(np.array([1, 2, 7, 18], np.uint8), zi.size)
    a, b = HeightTally(), HeightTally()
    a.add_scaled(zi, c, scale, offset)
    z = zi * scale + offset
    b.add(z, c)
    keep = ~np.isin(c, (7, 18))
    out = keep & ((z < PLAUSIBLE_HEIGHTS[0] - 1e-9) | (z > PLAUSIBLE_HEIGHTS[1] + 1e-9))
    assert a.n_ground_out + a.n_other_out == int(out.sum())
    assert (a.n_ground, a.n_ground_out, a.n_other, a.n_other_out) == \
        (b.n_ground, b.n_ground_out, b.n_other, b.n_other_out)
    assert a.zmin == pytest.approx(z[keep].min()) and a.zmax == pytest.approx(z[keep].max())
