"""``--polygon`` as users give it: WKT text in a file, a vector file in another CRS than the
tiles' (reprojected and named), a self-intersecting polygon (refused); and
``validate --diameter`` on GEDI footprints (refused, as ``run`` and ``simulate`` do).

Independent checks: the square written is the square read (its area and corners in the
tiles' CRS, computed here with pyproj); a bow tie is invalid for GEOS itself.
"""

from __future__ import annotations

import warnings
import zipfile

import geopandas as gpd
import pytest
import shapely

from canopyblocks.cli import main
from canopyblocks.errors import InputError
from canopyblocks.workflows.blocks_granules import read_polygon as blocks_polygon
from canopyblocks.workflows.rasters import read_polygon

TILE = "als/lidR_Topography.laz"


@pytest.fixture(scope="module")
def tile(sample):
    import laspy

    p = sample(TILE)
    with laspy.open(p) as r:
        h = r.header
        crs = h.parse_crs()
        box = (float(h.mins[0]), float(h.mins[1]), float(h.maxs[0]), float(h.maxs[1]))
    return p, crs, box


def _square(box, inset=20.0):
    return shapely.box(box[0] + inset, box[1] + inset, box[2] - inset, box[3] - inset)


def _bow_tie(box):
    return shapely.Polygon([(box[0], box[1]), (box[2], box[3]), (box[2], box[1]),
                            (box[0], box[3])])


def test_wkt_text_in_a_file_is_read_as_wkt(tile, tmp_path) -> None:
    path, crs, box = tile
    f = tmp_path / "area.wkt"
    f.write_text(_square(box).wkt + "\n")
    got = read_polygon(str(f), tiles=[path])
    assert got.equals(_square(box))


def test_a_polygon_file_in_another_crs_is_reprojected_to_the_tiles_and_named(tile,
                                                                             tmp_path) -> None:
    path, crs, box = tile
    sq = _square(box)
    f = tmp_path / "area.geojson"
    gpd.GeoSeries([sq], crs=crs).to_crs(4326).to_file(f)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = read_polygon(str(f), tiles=[path])
    said = [str(w.message) for w in caught]
    assert any("WGS 84" in m and crs.name in m and "area.geojson" in m for m in said), said
    assert got.area == pytest.approx(sq.area, rel=1e-6)
    assert shapely.hausdorff_distance(got, sq) < 0.01  # metres, after the round trip


def test_a_polygon_file_in_the_tiles_crs_is_used_as_is(tile, tmp_path) -> None:
    path, crs, box = tile
    f = tmp_path / "area.gpkg"
    gpd.GeoSeries([_square(box)], crs=crs).to_file(f)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = read_polygon(str(f), tiles=[path])
    assert got.equals(_square(box))


@pytest.mark.parametrize("form", ["wkt", "wkt-file", "gpkg"])
def test_a_self_intersecting_polygon_is_refused(form, tile, tmp_path) -> None:
    path, crs, box = tile
    bow = _bow_tie(box)
    assert not bow.is_valid  # GEOS's own verdict
    value: str = bow.wkt
    if form == "wkt-file":
        (tmp_path / "bow.wkt").write_text(bow.wkt)
        value = str(tmp_path / "bow.wkt")
    elif form == "gpkg":
        gpd.GeoSeries([bow], crs=crs).to_file(tmp_path / "bow.gpkg")
        value = str(tmp_path / "bow.gpkg")
    for reader in (lambda v: read_polygon(v, tiles=[path]), blocks_polygon):
        if form == "wkt" and reader is blocks_polygon:
            continue  # blocks --polygon takes files only
        with pytest.raises(InputError) as info:
            reader(value)
        msg = str(info.value)
        assert "Self-intersection" in msg and "not valid" in msg and "\n" not in msg, msg
        if form != "wkt":
            assert value in msg


def test_rasters_cli_refuses_a_bow_tie_with_one_line(tile, tmp_path, capsys) -> None:
    path, _, box = tile
    code = main(["-q", "rasters", str(path), "-o", str(tmp_path / "r"), "--polygon",
                 _bow_tie(box).wkt])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--polygon" in err[0] and "Self-intersection" in err[0], err
    assert not (tmp_path / "r").exists() or not any((tmp_path / "r").iterdir())


def test_blocks_polygon_wkt_file_without_crs_is_refused_by_name(tile, tmp_path) -> None:
    path, _, box = tile
    f = tmp_path / "area.wkt"
    f.write_text(_square(box).wkt)
    with pytest.raises(InputError, match="states no CRS"):
        blocks_polygon(str(f))


def test_validate_diameter_on_gedi_footprints_is_refused(sample, tmp_path, capsys) -> None:
    with zipfile.ZipFile(sample("gedi/GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.zip")
                         ) as z:
        name = z.namelist()[0]
        z.extract(name, tmp_path)
    fp = tmp_path / "fp.gpkg"
    assert main(["-q", "waveforms", str(tmp_path / name), "-o", str(fp)]) == 0
    capsys.readouterr()
    code = main(["-q", "validate", str(fp), "--points", str(sample(TILE)), "--diameter", "13",
                 "-o", str(tmp_path / "v.gpkg")])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--diameter" in err[0] and "GEDI footprint" in err[0], err
    assert not (tmp_path / "v.gpkg").exists()
