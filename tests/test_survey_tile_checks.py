"""A survey's tiles that are not what their headers or names say: checked, counted once,
flagged or refused (never a silent wrong number).

Made from the two bundled BC tiles (``als/lasR_bcts_1.laz`` and ``_2``, adjacent, 2 m
rasters over both): a renamed copy, the same path twice, a symlink and a crop of a tile
(the rasters must equal those of the two tiles, cell for cell; before, DSM p90 differed
in 8,124 cells by up to 4.41 m); a tile whose header extent is moved 5 km (before: skipped
by its header, 15,300 cells nodata instead of 1,048); a tile without ground points
(before: its 14,676 cells were interpolated across the whole tile, DTM off by up to
7.72 m); tiles stating CGVD28 and CGVD2013 (before: merged, the rasters declared the first
tile's datum).  And COPC/EPT sources whose hierarchy lies (``tests/copc_data.py``).
"""

from __future__ import annotations

import os
import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from canopyblocks.errors import CanopyBlocksWarning, CRSError, FileFormatError, InputError
from canopyblocks.readers.tile_checks import duplicate_tiles
from canopyblocks.workflows.rasters import make_survey_rasters

laspy = pytest.importorskip("laspy")
rasterio = pytest.importorskip("rasterio")

sys.path.insert(0, str(Path(__file__).parent))
from badinputs.survey_corpus import crop_of, grow_header, move_header  # noqa: E402
from copc_data import (  # noqa: E402
    build_octree,
    copc_damaged,
    garbled_node,
    root_node,
    sibling_box,
    tile_points,
    write_copc,
    write_ept,
)

BCTS = ("als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz")
BOUNDS = (885022.0, 629157.0, 885218.0, 629700.0)


def _band(path: Path) -> np.ndarray:
    with rasterio.open(path) as src:
        a = src.read(1).astype(float)
        a[a == src.nodata] = np.nan
    return a


def _rasters(tiles: list, out: Path, **kw: object) -> tuple[object, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = make_survey_rasters(tiles, out, backend="serial", bounds=BOUNDS, **kw)
    return r, [str(w.message) for w in caught]


@pytest.fixture(scope="module")
def survey(tmp_path_factory, sample):  # noqa: ANN001
    d = tmp_path_factory.mktemp("survey")
    a, b = (Path(shutil.copy(sample(p), d / Path(p).name)) for p in BCTS)
    return d, a, b


@pytest.fixture(scope="module")
def reference(survey, tmp_path_factory):  # noqa: ANN001
    _, a, b = survey
    r, ws = _rasters([a, b], tmp_path_factory.mktemp("ref"))
    assert ws == []
    return r


def test_copies_links_and_crops_are_counted_once(survey, reference, tmp_path) -> None:  # noqa: ANN001
    d, a, b = survey
    copy = Path(shutil.copy(a, tmp_path / "tile1.LAZ"))
    link = tmp_path / "link.laz"
    os.symlink(a, link)
    crop = crop_of(a, tmp_path / "crop.laz")
    with pytest.warns(CanopyBlocksWarning) as caught:
        kept, dropped = duplicate_tiles([a, b, copy, a, link, crop])
    assert len(caught) == 4
    assert kept == [a, b]
    assert [(Path(s).name, Path(t).name, why) for s, t, why in dropped] == [
        ("tile1.LAZ", a.name, "same points"), (a.name, a.name, "same file"),
        ("link.laz", a.name, "same file"), ("crop.laz", a.name, "part of")]
    want = _band(reference.dsm_p90)
    for name, extra in (("copy", copy), ("twice", a), ("link", link), ("crop", crop)):
        r, ws = _rasters([a, b, extra], tmp_path / name)
        assert r.stats["tiles"] == 2, name
        assert len(ws) == 1 and str(extra) in ws[0] and str(a) in ws[0], ws
        np.testing.assert_array_equal(_band(r.dsm_p90), want, err_msg=name)
    # the crop listed first is dropped too; tiles that only touch are both kept
    with pytest.warns(CanopyBlocksWarning, match="crop.laz holds a part of the points"):
        assert duplicate_tiles([crop, a, b])[0] == [a, b]
    # a reclassified copy holds the same points: counted once too
    las = laspy.read(b)
    las.classification = np.where(np.asarray(las.classification) == 2, 1, 2).astype(np.uint8)
    las.write(str(tmp_path / "reclassed.laz"))
    with pytest.warns(CanopyBlocksWarning, match="reclassed.laz holds the same points as"):
        assert duplicate_tiles([a, b, tmp_path / "reclassed.laz"])[0] == [a, b]


def test_a_copy_with_its_points_reordered_is_counted_once(survey, reference, tmp_path) -> None:  # noqa: ANN001
    """The same header, other first points: compared by all points, whatever their order
    (before: counted twice, DSM p90 off by up to 1.62 m)."""
    from canopyblocks.readers import tile_checks

    _, a, b = survey
    las = laspy.read(b)
    shuffled = laspy.LasData(las.header)
    shuffled.points = las.points[np.random.default_rng(3).permutation(len(las.points))]
    shuffled.write(str(tmp_path / "shuffled.laz"))
    r, ws = _rasters([a, b, tmp_path / "shuffled.laz"], tmp_path / "out")
    assert r.stats["tiles"] == 2
    assert len(ws) == 1 and "shuffled.laz holds the same points as" in ws[0] and str(b) in ws[0]
    for name in ("dtm", "dsm_max", "dsm_p90"):
        np.testing.assert_array_equal(_band(getattr(r, name)), _band(getattr(reference, name)))
    # one point 1 cm higher (inside the z range, same header): other points, both kept
    z = np.asarray(shuffled.z).copy()
    z[np.argsort(z)[z.size // 2]] += 0.01
    shuffled.z = z
    shuffled.write(str(tmp_path / "moved1.laz"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert duplicate_tiles([a, b, tmp_path / "moved1.laz"])[0] == [a, b,
                                                                       tmp_path / "moved1.laz"]
    # tiles whose headers differ (a survey of disjoint tiles) are never read in full
    tile_checks._cached_order_free.cache_clear()
    assert duplicate_tiles([a, b]) == ([a, b], [])
    assert tile_checks._cached_order_free.cache_info().currsize == 0


@pytest.fixture(scope="module")
def cloud_of_both(survey, tmp_path_factory) -> Path:  # noqa: ANN001
    _, a, b = survey
    p = tmp_path_factory.mktemp("cloud") / "both.copc.laz"
    tree = build_octree(tile_points([a, b]), capacity=20_000)
    write_copc([a, b], p, tree=tree, page_level=3)
    write_ept([a, b], p.parent / "ept", tree=tree, split_level=3)
    return p


def test_tiles_beside_a_copc_of_them_are_counted_once(survey, reference, cloud_of_both,
                                                      tmp_path) -> None:  # noqa: ANN001
    """A COPC made of the survey's tiles, given with them: the tiles are left out (before:
    every point counted twice); the rasters equal the tiles' alone, cell for cell."""
    _, a, b = survey
    for order in ([a, b, cloud_of_both], [cloud_of_both, b, a]):
        with pytest.warns(CanopyBlocksWarning) as caught:
            kept, dropped = duplicate_tiles(order)
        assert kept == [cloud_of_both] and {d[0] for d in dropped} == {a, b}
        msgs = [str(w.message) for w in caught]
        assert all(str(cloud_of_both) in m and "not both" in m for m in msgs), msgs
        assert any(str(a) in m for m in msgs) and any(str(b) in m for m in msgs)
    ept = str(cloud_of_both.parent / "ept" / "ept.json")
    with pytest.warns(CanopyBlocksWarning, match="every one of its points is a point of"):
        assert duplicate_tiles([a, ept, b]) == ([ept], [(a, ept, "in cloud"),
                                                         (b, ept, "in cloud")])
    r, ws = _rasters([a, b, cloud_of_both], tmp_path / "out")
    assert len(ws) == 2, ws
    for name in ("dtm", "dsm_max", "dsm_p90"):
        np.testing.assert_array_equal(_band(getattr(r, name)), _band(getattr(reference, name)))


def test_a_copc_sharing_part_of_a_tile_is_refused_and_a_disjoint_one_kept(
        survey, reference, tmp_path) -> None:  # noqa: ANN001
    _, a, b = survey
    half = crop_of(b, tmp_path / "half.laz")
    part = tmp_path / "half.copc.laz"
    write_copc([half], part, tree=build_octree(tile_points([half]), capacity=20_000))
    with pytest.raises(InputError) as exc:
        _rasters([a, b, part], tmp_path / "refused")
    msg = str(exc.value)
    assert str(b) in msg and str(part) in msg and "not both" in msg, msg
    assert f"{laspy.read(half).header.point_count:,} of the tile's" in msg
    assert not (tmp_path / "refused" / "dtm.tif").exists()
    # a COPC of tile 1 beside tile 2 (adjacent): no point shared, both read, no warning
    one = tmp_path / "one.copc.laz"
    write_copc([a], one, tree=build_octree(tile_points([a]), capacity=20_000))
    r, ws = _rasters([one, b], tmp_path / "out")
    assert ws == []
    for name in ("dtm", "dsm_max", "dsm_p90"):
        np.testing.assert_array_equal(_band(getattr(r, name)), _band(getattr(reference, name)))


def test_a_header_extent_moved_off_its_points_is_refused(survey, tmp_path) -> None:  # noqa: ANN001
    _, a, b = survey
    moved = Path(shutil.copy(b, tmp_path / "moved.laz"))
    move_header(moved, 5000.0, 0.0)
    with pytest.raises(FileFormatError) as exc:
        _rasters([a, moved], tmp_path / "out")
    msg = str(exc.value)
    assert str(moved) in msg and "its header says the points lie in (890024.09" in msg
    assert "256 of its first 256 points lie outside" in msg
    assert not (tmp_path / "out" / "dtm.tif").exists()


def test_a_header_grown_500_km_is_named_not_the_grid_size(survey, tmp_path) -> None:  # noqa: ANN001
    """Max x raised 500 km, every point still inside: the whole survey's grid would be too
    large; the header is named first, in either order, and nothing is written."""
    _, a, b = survey
    grown = Path(shutil.copy(b, tmp_path / "grown.laz"))
    grow_header(grown, 5.0e5)
    for order in ([a, grown], [grown, a]):
        with pytest.raises(FileFormatError) as exc:
            make_survey_rasters(order, tmp_path / "out", backend="serial")
        msg = str(exc.value)
        assert msg.startswith(f"{grown}: its header says the points lie in (885024.09"), msg
        assert "1385217.09" in msg and "cells" not in msg and "resolution" not in msg
        assert not (tmp_path / "out" / "dtm.tif").exists()


def test_a_tile_without_ground_is_not_interpolated_across(survey, reference, tmp_path) -> None:  # noqa: ANN001
    from scipy.spatial import cKDTree

    _, a, b = survey
    las = laspy.read(b)
    c = np.asarray(las.classification)
    c[c == 2] = 1
    las.classification = c
    bare = tmp_path / "unclassed.laz"
    las.write(str(bare))
    r, ws = _rasters([a, bare], tmp_path / "out")
    assert len(ws) == 1 and str(bare) in ws[0] and "no ground point" in ws[0], ws
    assert f"its {r.stats['dtm_unsupported']:,} cells" in ws[0]
    assert r.stats["dtm_unsupported"] == 14_676
    dtm = _band(r.dtm)
    # independently: cells whose centre lies on the unclassed tile (its points' extent)
    # with no ground point of the other tile within the cell radius have no DTM
    g = laspy.read(a)
    gx, gy = np.asarray(g.x)[g.classification == 2], np.asarray(g.y)[g.classification == 2]
    with rasterio.open(r.dtm) as src:
        t = src.transform
    rows, cols = np.indices(dtm.shape)
    cx, cy = t.c + (cols + 0.5) * 2.0, t.f - (rows + 0.5) * 2.0
    bx, by = np.asarray(las.x), np.asarray(las.y)
    on_bare = (cx >= bx.min()) & (cx <= bx.max()) & (cy >= by.min()) & (cy <= by.max())
    dist, _ = cKDTree(np.c_[gx, gy]).query(np.c_[cx.ravel(), cy.ravel()])
    unsupported = on_bare & (dist.reshape(dtm.shape) >= 2.0 * np.sqrt(2) / 2)
    assert unsupported.sum() > 14_000
    assert np.isnan(dtm[unsupported]).all()
    # elsewhere (beyond the cell radius of the unclassed tile) the measured DTM is the one
    # of the two classified tiles
    ref = _band(reference.dtm)
    far = (cx < bx.min() - 1.5) | (cx > bx.max() + 1.5) | (cy < by.min() - 1.5) | \
        (cy > by.max() + 1.5)
    measured = (_band(r.dtm_fill_mask) == 0) & far
    assert measured.sum() > 10_000
    np.testing.assert_allclose(dtm[measured], ref[measured], atol=1e-3)


def _datum_copy(src: Path, out: Path, vertical: int | None) -> Path:
    import pyproj

    las = laspy.convert(laspy.read(src), file_version="1.4", point_format_id=6)
    las.header.vlrs.clear()
    las.header.add_crs(pyproj.CRS.from_user_input(
        "EPSG:3005" if vertical is None else f"EPSG:3005+{vertical}"))
    las.write(str(out))
    return out


def test_tiles_in_two_vertical_datums_are_refused(survey, tmp_path) -> None:  # noqa: ANN001
    _, a, b = survey
    a28 = _datum_copy(a, tmp_path / "a28.laz", 5713)   # CGVD28
    b13 = _datum_copy(b, tmp_path / "b13.laz", 6647)   # CGVD2013
    for order in ([b13, a28], [a28, b13]):
        with pytest.raises(CRSError) as exc:
            _rasters(order, tmp_path / "out")
        msg = str(exc.value)
        assert "different vertical datums" in msg and str(a28) in msg and str(b13) in msg
        assert "EPSG:5713 (CGVD28 height)" in msg and "EPSG:6647" in msg
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
    b28 = _datum_copy(b, tmp_path / "b28.laz", 5713)
    r, ws = _rasters([a28, b28], tmp_path / "same")
    assert ws == [] and "CGVD28" in r.crs.name
    bare = _datum_copy(b, tmp_path / "bnone.laz", None)
    r, ws = _rasters([a28, bare], tmp_path / "mixed")
    assert len(ws) == 1 and str(bare) in ws[0] and "states no vertical datum" in ws[0]


def test_a_tile_without_vertical_datum_beside_cgvd28_declares_cgvd28_in_any_order(
        survey, tmp_path) -> None:  # noqa: ANN001
    """The datum the tiles state is declared whatever the order; the tile stating none is
    named as assumed in it; ``run``'s reference datum is the same in both orders."""
    import pyproj
    import rasterio

    from canopyblocks.workflows.chain.tiles import _tiles_crs

    _, a, b = survey
    a28 = _datum_copy(a, tmp_path / "a28.laz", 5713)
    bare = _datum_copy(b, tmp_path / "bnone.laz", None)
    wkts = {}
    for k, order in enumerate(([a28, bare], [bare, a28])):
        r, ws = _rasters(order, tmp_path / f"o{k}")
        assert len(ws) == 1 and ws[0].startswith(f"{bare} states no vertical datum")
        assert "taken to be in EPSG:5713 (CGVD28 height)" in ws[0]
        for name in ("dtm", "dsm_max", "dsm_p90"):
            with rasterio.open(getattr(r, name)) as src:
                wkts.setdefault(name, set()).add(src.crs.to_wkt())
        assert pyproj.CRS(_tiles_crs(order)).equals(pyproj.CRS("EPSG:3005+5713"))
    for name, found in wkts.items():
        assert len(found) == 1, name
        crs = pyproj.CRS.from_wkt(found.pop())
        assert crs.sub_crs_list[1].to_epsg() == 5713 and "nknown" not in crs.to_wkt(), name
    assert (tmp_path / "o0" / "dtm.tif").read_bytes() == (tmp_path / "o1" / "dtm.tif").read_bytes()


# ---- COPC / EPT hierarchies that lie ------------------------------------------------------


@pytest.fixture(scope="module")
def copc(tmp_path_factory, sample) -> tuple[Path, bytes]:  # noqa: ANN001
    d = tmp_path_factory.mktemp("copc")
    p = d / "topo.copc.laz"
    topo = sample("als/lidR_Topography.laz")
    write_copc([topo], p, tree=build_octree(tile_points([topo]), capacity=5000), page_level=1)
    return p, p.read_bytes()


# {size}: the root node's chunk, in bytes (49,390 written by lazrs 0.8, 49,787 by 0.5)
COPC_LIES = {"half": "holds 2,500 points in {size:,} bytes, its LAZ chunk holds 5,000 points "
                     "in {size:,} bytes",
             "none": "holds 0 points in {size:,} bytes, its LAZ chunk holds 5,000 points in "
                     "{size:,} bytes",
             "other": "at the same LAZ chunk",
             "sibling": "at the same LAZ chunk",
             "centre": "its octree's cube is centred at (278500.00",
             "header": "its header says the points lie in (278357.14"}


@pytest.mark.parametrize("edit", sorted(COPC_LIES))
def test_a_copc_hierarchy_that_lies_is_refused(copc, tmp_path, edit) -> None:  # noqa: ANN001
    from canopyblocks.readers.copc import read_copc

    p = tmp_path / f"{edit}.copc.laz"
    p.write_bytes(copc_damaged(copc[1], edit))
    # whole file, and a box under the damaged node (before: read as it says: 70,903 or
    # 68,403 points of 73,403; 2,521 instead of 2,327 in the box; "no points")
    boxes = [None, (273440.0, 5274440.0, 273490.0, 5274490.0)]
    for box in boxes[:1] if edit == "sibling" else boxes:  # a box under the damaged node
        with pytest.raises(FileFormatError) as exc:
            read_copc(p, bounds=box)
        want = COPC_LIES[edit].format(size=root_node(copc[1])[5])
        assert str(p) in str(exc.value) and want in str(exc.value), str(exc.value)
        assert "write the file again" in str(exc.value)
    if edit == "sibling":  # only the node pointed elsewhere is read; the whole
        # hierarchy's counts, checked in a box read too, no longer add up (before: its
        # sibling's 523 points read as its own)
        with pytest.raises(FileFormatError, match="its hierarchy's nodes hold 73,363 points, "
                           "its header says 73,403"):
            read_copc(p, bounds=sibling_box(copc[1]))


def test_a_garbled_copc_chunk_names_its_node(copc, tmp_path, capsys) -> None:  # noqa: ANN001
    """64 bytes inverted inside one node's chunk: the node named is that one (not the
    first of its batch), with no decompressor text, and nothing is written."""
    from canopyblocks.cli import main
    from canopyblocks.readers.copc import read_copc

    p = tmp_path / "garbled.copc.laz"
    p.write_bytes(copc_damaged(copc[1], "garbled"))
    want = (f"{p}: the point data of octree node {garbled_node(copc[1])} cannot be "
            "decompressed: the file is damaged; copy or download it again, or write it again")
    with pytest.raises(FileFormatError) as exc:
        read_copc(p)
    assert str(exc.value) == want
    out = tmp_path / "r"
    assert main(["-q", "rasters", str(p), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"canopyblocks: error: {want}" and not out.exists(), err


def test_two_copc_nodes_swapped_are_refused_by_their_cubes(copc, tmp_path) -> None:  # noqa: ANN001
    """Two siblings' chunks exchanged: every count adds up and every node begins its own
    chunk; the points read for a node lie outside its cube."""
    from canopyblocks.readers.copc import read_copc

    p = tmp_path / "swap.copc.laz"
    p.write_bytes(copc_damaged(copc[1], "swap"))
    for box in (None, sibling_box(copc[1])):  # the node first in the file is named
        with pytest.raises(FileFormatError) as exc:
            read_copc(p, bounds=box)
        assert str(p) in str(exc.value), str(exc.value)
        assert "523 of the 523 points read for node 2-0-1-1 lie outside its octree cube" in \
            str(exc.value)


def test_an_ept_without_its_root_or_a_node_is_named(tmp_path, sample) -> None:  # noqa: ANN001
    import json

    from canopyblocks.readers.ept import read_ept

    topo = sample("als/lidR_Topography.laz")
    src = tmp_path / "ept"
    write_ept([topo], src, tree=build_octree(tile_points([topo]), capacity=5000), split_level=1)
    assert read_ept(src / "ept.json").x.size == 73_403
    for name in ("noroot", "noentry"):
        d = tmp_path / name
        shutil.copytree(src, d)
        h = d / "ept-hierarchy" / "0-0-0-0.json" if name == "noroot" else \
            sorted((d / "ept-hierarchy").glob("1-*.json"))[0]
        j = json.loads(h.read_text())
        del j["0-0-0-0" if name == "noroot" else
              next(k for k, v in j.items() if k.startswith("2-") and v > 0)]
        h.write_text(json.dumps(j))
        with pytest.raises(FileFormatError) as exc:
            read_ept(d / "ept.json")
        want = ("has no root node 0-0-0-0" if name == "noroot"
                else "its hierarchy's nodes hold 72,880 points, ept.json says 73,403")
        assert want in str(exc.value), str(exc.value)


@pytest.mark.parametrize("shift", [20.0, -35.0])
def test_ept_bounds_moved_name_ept_json_not_a_node_file(tmp_path, sample, capsys,  # noqa: ANN001
                                                         shift) -> None:
    """ept.json's cube moved along x: the node files are whole; the refusal names ept.json's
    bounds (before: a node file "holds another node's points"), and nothing is written."""
    import json

    from canopyblocks.cli import main

    topo = sample("als/lidR_Topography.laz")
    d = tmp_path / "ept"
    write_ept([topo], d, tree=build_octree(tile_points([topo]), capacity=5000), split_level=1)
    j = json.loads((d / "ept.json").read_text())
    j["bounds"][0] += shift
    j["bounds"][3] += shift
    (d / "ept.json").write_text(json.dumps(j))
    out = tmp_path / "r"
    assert main(["-q", "rasters", str(d / "ept.json"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"canopyblocks: error: {d / 'ept.json'}: ")
    assert "do not fit in any one node's cube: ept.json's bounds (" in lines[0], err
    assert "correct ept.json's bounds or write the dataset again" in lines[0], err
    assert "another node's points" not in err and not out.exists()
