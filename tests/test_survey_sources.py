"""One survey argument: files, folders, glob patterns, a .vpc catalog, COPC and EPT sources
resolve to the same points; a COPC whose CRS is an extended VLR, or that states none and
is given one; a Web Mercator CRS is not taken for ground metres.

Independent truths: the bundled BC tiles read with ``read_las`` (and cropped here by their
coordinates), the .vpc written here by hand from the STAC ItemCollection layout QGIS and
PDAL wrench write (a GeoJSON FeatureCollection whose items' ``data`` asset names a tile).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from canopyblocks.errors import CanopyBlocksWarning, CRSError, FileFormatError, InputError
from canopyblocks.readers import remote
from canopyblocks.readers.las import LasPoints, read_las
from canopyblocks.readers.survey import read_survey, source_crs, survey_sources
from canopyblocks.workflows.rasters import survey_tiles
from copc_data import build_octree, tile_points, write_copc, write_ept
from loopback_servers import RangeHTTPServer, S3Server, use_s3_server

TILES = ("als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz")
BOX = (885100.0, 629200.0, 885160.0, 629420.0)


def write_vpc(path: Path, hrefs: list[str]) -> Path:
    """A virtual point cloud as QGIS writes it (only what a reader needs)."""
    feats = [{"type": "Feature", "stac_version": "1.0.0", "id": Path(h).stem,
              "geometry": None, "properties": {"datetime": "0-01-01T00:00:00Z"},
              "links": [], "assets": {"data": {"href": h, "roles": ["data"]}}}
             for h in hrefs]
    path.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    return path


def table(p: LasPoints) -> np.ndarray:
    rows = np.column_stack([p.x, p.y, p.z, p.classification, p.return_number,
                            p.number_of_returns])
    return rows[np.lexsort(rows.T[::-1])]


@pytest.fixture(scope="module")
def tiles(sample) -> list[Path]:  # noqa: ANN001
    return [sample(t) for t in TILES]


@pytest.fixture(scope="module")
def laz(tiles) -> LasPoints:  # noqa: ANN001
    return read_las(tiles)


@pytest.fixture(scope="module")
def store(tmp_path_factory, tiles) -> Path:  # noqa: ANN001
    root = tmp_path_factory.mktemp("survey_sources")
    tree = build_octree(tile_points(tiles), capacity=5000)
    write_copc(tiles, root / "survey.copc.laz", tree=tree, page_level=2)
    write_copc(tiles, root / "evlr.copc.laz", tree=tree, crs="evlr")
    write_copc(tiles, root / "nocrs.copc.laz", tree=tree, crs="none")
    write_ept(tiles, root / "ept", tree=tree, split_level=2)
    (root / "tiles").mkdir()
    for t in tiles:
        shutil.copy(t, root / "tiles" / t.name)
    write_vpc(root / "survey.vpc", ["./tiles/lasR_bcts_1.laz",
                                    str(root / "tiles" / "lasR_bcts_2.laz")])
    return root


def test_every_spelling_of_a_survey_resolves_to_its_tiles(store: Path) -> None:
    want = [store / "tiles" / "lasR_bcts_1.laz", store / "tiles" / "lasR_bcts_2.laz"]
    assert survey_tiles(store / "tiles") == want
    assert survey_tiles([str(store / "tiles" / "*.laz")]) == want
    assert survey_tiles(str(store / "survey.vpc")) == want
    # the same tile given twice (a folder and one of its files) is read once, with a warning
    with pytest.warns(CanopyBlocksWarning, match="given twice"):
        assert survey_tiles([store / "tiles", want[1]]) == want
    assert survey_tiles(store / "ept") == [str(store / "ept" / "ept.json")]
    url = "https://example.org/a/survey.copc.laz"
    assert survey_tiles([url]) == [url]  # a URL stays as given, never a mangled path


def test_a_survey_that_is_not_there_is_refused_by_name(store: Path, tmp_path: Path) -> None:
    with pytest.raises(FileFormatError, match="gone.laz: no such file"):
        survey_sources([str(tmp_path / "gone.laz")])
    with pytest.raises(InputError, match="matches no file"):
        survey_sources([str(tmp_path / "*.laz")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="holds no .las or .laz"):
        survey_sources(tmp_path / "empty")
    (tmp_path / "bad.vpc").write_text("{not json")
    with pytest.raises(FileFormatError, match="not a virtual point cloud"):
        survey_sources(tmp_path / "bad.vpc")
    write_vpc(tmp_path / "none.vpc", [])
    with pytest.raises(FileFormatError, match="names no tile"):
        survey_sources(tmp_path / "none.vpc")


def test_vpc_copc_and_ept_read_the_same_points(store: Path, laz: LasPoints) -> None:
    keep = (laz.x >= BOX[0]) & (laz.x <= BOX[2]) & (laz.y >= BOX[1]) & (laz.y <= BOX[3])
    want = table(laz.subset(keep))
    for src in ("survey.vpc", "survey.copc.laz", "ept/ept.json", "evlr.copc.laz"):
        got = read_survey(survey_sources(store / src), bbox=BOX)
        np.testing.assert_array_equal(table(got), want, err_msg=src)
        assert got.crs.equals(laz.crs), src


def test_remote_copc_and_ept_read_the_same_points(store: Path, laz: LasPoints, monkeypatch,
                                                  tmp_path: Path) -> None:  # noqa: ANN001
    keep = (laz.x >= BOX[0]) & (laz.x <= BOX[2]) & (laz.y >= BOX[1]) & (laz.y <= BOX[3])
    want = table(laz.subset(keep))
    with RangeHTTPServer(store) as http:
        remote.clear_cache()
        for rel in ("survey.copc.laz", "survey.vpc"):
            if rel == "survey.vpc":  # a remote catalog names its tiles relative to itself
                write_vpc(store / "remote.vpc", ["./survey.copc.laz"])
                rel = "remote.vpc"
            got = read_survey(survey_sources(f"{http.url}/{rel}"), bbox=BOX)
            np.testing.assert_array_equal(table(got), want, err_msg=rel)
    with S3Server() as s3:
        for f in sorted((store / "ept").rglob("*")):
            if f.is_file():
                s3.put("surveys", f"bc/ept/{f.relative_to(store / 'ept')}", f)
        use_s3_server(monkeypatch, s3.endpoint, tmp_path)
        remote.clear_cache()
        got = read_survey(survey_sources("s3://surveys/bc/ept/ept.json"), bbox=BOX)
    np.testing.assert_array_equal(table(got), want)


def test_copc_crs_in_an_extended_vlr_or_given(store: Path, laz: LasPoints) -> None:
    stated = source_crs(store / "evlr.copc.laz")
    assert stated.horizontal is not None and stated.horizontal.equals(laz.crs)
    with pytest.raises(CRSError, match="states no CRS; give its CRS"):
        read_survey([store / "nocrs.copc.laz"], bbox=BOX)
    got = read_survey([store / "nocrs.copc.laz"], bbox=BOX, crs=laz.crs.to_wkt())
    assert got.crs.equals(laz.crs) and len(got) > 1000
    with pytest.raises(CRSError, match="differs from the CRS given"):
        read_survey([store / "survey.copc.laz"], bbox=BOX, crs="EPSG:32610")


def test_web_mercator_is_not_ground_metres() -> None:
    from canopyblocks.geo import ground_metres

    assert not ground_metres("EPSG:3857") and not ground_metres("EPSG:3395")
    assert not ground_metres("EPSG:4326")
    assert ground_metres("EPSG:32609") and ground_metres("EPSG:3005")
    assert ground_metres("EPSG:3005+5703")
    assert not ground_metres("EPSG:2927")  # US survey feet


def test_read_survey_into_another_crs_keeps_the_area_exactly(store: Path,
                                                             laz: LasPoints) -> None:
    import pyproj
    import shapely

    utm = pyproj.CRS.from_epsg(32609)
    to = pyproj.Transformer.from_crs(laz.crs, utm, always_xy=True)
    ux, uy = to.transform(laz.x, laz.y)
    cx, cy = float(np.median(ux)), float(np.median(uy))
    area = shapely.Point(cx, cy).buffer(40.0)
    got = read_survey([store / "survey.copc.laz"], polygon=area, to_crs=utm)
    # brute force: every tile point reprojected here, kept by the same polygon
    keep = shapely.covers(area, shapely.points(ux, uy))
    assert got.crs.equals(utm) and len(got) == keep.sum() > 1000
    np.testing.assert_allclose(np.sort(got.x), np.sort(ux[keep]), atol=1e-6)
    np.testing.assert_array_equal(np.sort(got.z), np.sort(laz.z[keep]))
