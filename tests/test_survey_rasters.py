"""Survey rasters made tile by tile equal the rasters of the whole survey, cell by cell.

The two bundled BC tiles are cut into a catalog of 12 tiles whose edges fall at odd
places (not on cell edges), plus two far-away decoy tiles (shifted copies).  The rasters
of the catalog, read tile by tile, must equal the rasters of the two whole tiles (which
tests/test_rasters.py checks against a KD-tree oracle), and a window straddling a corner
of four catalog tiles is checked against that oracle here too.  Serial and parallel runs
must give the same bytes; a polygon limits the area and the tiles read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canopyblocks.reference.rasters import make_reference_rasters
from canopyblocks.workflows.rasters import make_survey_rasters

laspy = pytest.importorskip("laspy")
rasterio = pytest.importorskip("rasterio")
shapely = pytest.importorskip("shapely")

from test_rasters import _assert_same, _band, _oracle, _read  # noqa: E402

BCTS = ("als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz")
# catalog edges: x at 885071.3 and 885140.7, y at 629237.9, 629400.0 (the two files'
# own edge), 629503.3 (odd places, so cells on them need two or four tiles)
X_CUTS = (885071.3, 885140.7)
Y_CUTS = (629237.9, 629400.0, 629503.3)
DECOY_SHIFT = (5000.0, 3000.0)
NAMES = ("dtm", "dsm_max", "dsm_p90", "dtm_fill_mask")


def _write(path: Path, las: object, keep: np.ndarray, shift: tuple[float, float] = (0, 0)
           ) -> None:
    out = laspy.LasData(las.header)  # type: ignore[attr-defined]
    out.points = las.points[keep].copy()  # type: ignore[attr-defined]
    if shift != (0, 0):
        out.header.offsets = out.header.offsets + np.array([shift[0], shift[1], 0.0])
    out.update_header()
    out.write(str(path))


@pytest.fixture(scope="module")
def catalog(tmp_path_factory, sample):  # noqa: ANN001
    folder = tmp_path_factory.mktemp("catalog")
    xe = (-np.inf, *X_CUTS, np.inf)
    ye = (-np.inf, *Y_CUTS, np.inf)
    n = 0
    for k, name in enumerate(BCTS):
        las = laspy.read(sample(name))
        x, y = np.asarray(las.x), np.asarray(las.y)
        for i in range(len(xe) - 1):
            for j in range(len(ye) - 1):
                keep = (x >= xe[i]) & (x < xe[i + 1]) & (y >= ye[j]) & (y < ye[j + 1])
                if keep.any():
                    _write(folder / f"t{k}_{i}_{j}.laz", las, keep)
                    n += 1
        _write(folder / f"decoy_{k}.laz", las, np.ones(x.size, bool), DECOY_SHIFT)
    assert n >= 10
    return folder, [sample(p) for p in BCTS]


@pytest.fixture(scope="module")
def whole(tmp_path_factory, catalog):  # noqa: ANN001
    _, paths = catalog
    return make_reference_rasters(paths, tmp_path_factory.mktemp("whole"))


def _same_files(a: Path, b: Path) -> None:
    for name in NAMES:
        x, _ = _band(a / f"{name}.tif")
        y, _ = _band(b / f"{name}.tif")
        assert x.shape == y.shape
        assert np.array_equal(np.isnan(x), np.isnan(y)), name
        np.testing.assert_array_equal(x[~np.isnan(x)], y[~np.isnan(y)], err_msg=name)


def test_catalog_equals_whole_tiles_cell_by_cell(tmp_path: Path, catalog, whole) -> None:  # noqa: ANN001
    folder, paths = catalog
    tiles = sorted(p for p in folder.iterdir() if not p.name.startswith("decoy"))
    seen: list[str] = []
    r = make_survey_rasters(tiles, tmp_path / "cat", backend="serial",
                            progress=lambda f, m: seen.append(m))
    assert r.grid == whole.grid
    assert r.stats["tiles_read"] == len(tiles)
    _same_files(tmp_path / "cat", Path(whole.dtm).parent)
    assert sum(m.startswith("tile ") for m in seen) == len(tiles)  # progress per tile
    # and against the KD-tree oracle on a window around the corner of four catalog tiles
    x, y, z, c = _read(paths)
    cx, cy = X_CUTS[1], Y_CUTS[2]
    win = (round(cx) - 14.0, round(cy) - 14.0, round(cx) + 14.0, round(cy) + 14.0)
    w = make_survey_rasters(tiles, tmp_path / "win", bounds=win, backend="serial")
    keep = (c != 7) & (c != 18)
    dsm, src = _band(w.dsm_max)
    _assert_same(dsm, _oracle(x[keep], y[keep], z[keep], src.transform, dsm.shape, 2.0,
                              np.max), tol=1e-4)  # float32 GeoTIFF at ~340 m
    p90, _ = _band(w.dsm_p90)
    _assert_same(p90, _oracle(x[keep], y[keep], z[keep], src.transform, dsm.shape, 2.0,
                              lambda v: np.percentile(v, 90.0)), tol=1e-4)
    dtm, _ = _band(w.dtm)
    mask, _ = _band(w.dtm_fill_mask)
    g = c == 2
    _assert_same(np.where(mask == 1, np.nan, dtm),
                 _oracle(x[g], y[g], z[g], src.transform, dsm.shape, 2.0, np.mean), tol=1e-4)


def test_parallel_equals_serial_and_decoys_are_skipped(tmp_path: Path, catalog) -> None:  # noqa: ANN001
    folder, _ = catalog
    b = (885030.0, 629200.0, 885180.0, 629560.0)
    serial = make_survey_rasters(folder, tmp_path / "s", bounds=b, backend="serial")
    par = make_survey_rasters(folder, tmp_path / "p", bounds=b, backend="processes",
                              workers=2)
    _same_files(tmp_path / "s", tmp_path / "p")
    n_decoys = sum(p.name.startswith("decoy") for p in folder.iterdir())
    assert serial.stats["tiles"] - serial.stats["tiles_read"] >= n_decoys
    assert par.stats["tiles_read"] == serial.stats["tiles_read"]


def test_polygon_keeps_whole_survey_values_inside(tmp_path: Path, catalog, whole) -> None:  # noqa: ANN001
    folder, _ = catalog
    line = shapely.LineString([(885040.0, 629180.0), (885160.0, 629600.0)])
    corridor = line.buffer(15.0)
    r = make_survey_rasters(folder, tmp_path / "c", polygon=corridor, backend="serial")
    n_decoys = sum(p.name.startswith("decoy") for p in folder.iterdir())
    assert r.stats["tiles"] - r.stats["tiles_read"] >= n_decoys
    full, fsrc = _band(Path(whole.dsm_max))
    cut, csrc = _band(r.dsm_max)
    # the same cells of the whole run (grids aligned on the resolution)
    dc = round((csrc.transform.c - fsrc.transform.c) / 2.0)
    dr = round((fsrc.transform.f - csrc.transform.f) / 2.0)
    sub = full[dr:dr + cut.shape[0], dc:dc + cut.shape[1]]
    rows, cols = np.indices(cut.shape)
    xs = csrc.transform.c + (cols + 0.5) * 2.0
    ys = csrc.transform.f - (rows + 0.5) * 2.0
    inside = shapely.contains_xy(corridor, xs, ys)
    assert inside.sum() > 500
    assert np.isnan(cut[~inside]).all()
    np.testing.assert_array_equal(cut[inside], sub[inside])
    a, _ = _band(Path(whole.dsm_p90))
    b, _ = _band(Path(r.dsm_p90))
    np.testing.assert_array_equal(b[inside], a[dr:dr + cut.shape[0],
                                               dc:dc + cut.shape[1]][inside])


def test_cli_rasters_folder_polygon(tmp_path: Path, catalog) -> None:  # noqa: ANN001
    from canopyblocks.cli import main

    folder, _ = catalog
    poly = shapely.box(885100.0, 629380.0, 885140.0, 629420.0).wkt
    assert main(["-q", "rasters", str(folder), "-o", str(tmp_path / "o"), "--polygon", poly,
                 "--workers", "2"]) == 0
    with rasterio.open(tmp_path / "o" / "dsm_max.tif") as src:
        assert (src.width, src.height) == (20, 20)
    assert main(["-q", "rasters", str(folder), "-o", str(tmp_path / "bad"), "--polygon",
                 "POLYGON ((0 0, 1 0, 1 1, 0 0))"]) == 2
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["-q", "rasters", str(empty), "-o", str(tmp_path / "bad2")]) == 2
    assert not (tmp_path / "bad").exists() or not any((tmp_path / "bad").iterdir())


def test_cancel_stops_the_pool_and_writes_nothing(tmp_path: Path, catalog) -> None:  # noqa: ANN001
    from canopyblocks.errors import CancelledError
    from canopyblocks.progress import Progress

    folder, _ = catalog
    msgs: list[str] = []
    prog = Progress(callback=lambda f, m: msgs.append(m),
                    cancelled=lambda: any(m.startswith("tile 2 ") for m in msgs))
    with pytest.raises(CancelledError):
        make_survey_rasters(folder, tmp_path / "o", backend="processes", workers=2,
                            progress=prog)
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())
