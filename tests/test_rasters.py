"""Reference rasters (DTM, DSM max, DSM p90) from the real airborne tiles, checked cell by
cell against an independent numpy/scipy computation of the documented cell rule.

Cell rule (canopyblocks.reference.rasters): a point counts for a cell when its horizontal
distance to the cell centre is < resolution * sqrt(2) / 2.  The oracle here finds those
points with a KD-tree ball query around each cell centre (not the library's 3 x 3
neighbour scheme) and uses numpy's mean / max / percentile per cell.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyproj
import pytest

from canopyblocks.errors import (
    CoverageError,
    CRSError,
    FileFormatError,
    InputError,
    NoUsableDataError,
)
from canopyblocks.reference.lidar_points import cell_neighbourhoods, cell_percentile
from canopyblocks.reference.rasters import NODATA, Grid, RasterParams, make_reference_rasters

laspy = pytest.importorskip("laspy")
rasterio = pytest.importorskip("rasterio")
cKDTree = pytest.importorskip("scipy.spatial").cKDTree

BCTS = ("als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz")
# 40 m x 40 m straddling the boundary of the two BC tiles (y = 629400): cells there need
# the points of both tiles.
BCTS_BOUNDS = (885100.0, 629380.0, 885140.0, 629420.0)


# ---------------------------------------------------------------- independent oracle
def _read(paths: list[Path]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    xs, ys, zs, cs = [], [], [], []
    for p in paths:
        las = laspy.read(p)
        xs.append(np.asarray(las.x))
        ys.append(np.asarray(las.y))
        zs.append(np.asarray(las.z))
        cs.append(np.asarray(las.classification))
    return tuple(np.concatenate(a) for a in (xs, ys, zs, cs))  # type: ignore[return-value]


def _oracle(x, y, z, transform, shape, res, stat):  # noqa: ANN001 - test helper
    """stat(z of points strictly within res*sqrt(2)/2 of each cell centre), NaN if none."""
    r = res * math.sqrt(2.0) / 2.0
    # only points near the grid can count (speeds up the tree; the rule is unchanged)
    x0, y0 = transform.c - res, transform.f + (shape[0] + 1) * transform.e
    x1, y1 = transform.c + (shape[1] + 1) * transform.a, transform.f + res
    near = (x > x0) & (x < x1) & (y > y0) & (y < y1)
    x, y, z = x[near], y[near], z[near]
    tree = cKDTree(np.c_[x, y])
    out = np.full(shape, np.nan)
    for row in range(shape[0]):
        for col in range(shape[1]):
            cx = transform.c + (col + 0.5) * transform.a
            cy = transform.f + (row + 0.5) * transform.e
            idx = np.asarray(tree.query_ball_point([cx, cy], r * 1.0001), dtype=int)
            if idx.size:
                idx = idx[np.hypot(x[idx] - cx, y[idx] - cy) < r]
            if idx.size:
                out[row, col] = stat(z[idx])
    return out


def _band(path: Path) -> tuple[np.ndarray, object]:
    with rasterio.open(path) as src:
        a = src.read(1).astype(np.float64)
        a[a == src.nodata] = np.nan
        return a, src


def _assert_same(actual: np.ndarray, expected: np.ndarray, tol: float = 1e-3) -> None:
    assert np.array_equal(np.isnan(actual), np.isnan(expected)), "nodata cells differ"
    ok = ~np.isnan(expected)
    assert ok.sum() > 0
    np.testing.assert_allclose(actual[ok], expected[ok], atol=tol, rtol=0)


# ------------------------------------------------------------------- pure numpy parts
def test_grid_snaps_outward_to_resolution() -> None:
    g = Grid.from_bounds((885101.3, 629379.9, 885139.1, 629420.0), 2.0, "EPSG:3005")
    assert (g.origin_x, g.origin_y, g.width, g.height) == (885100.0, 629378.0, 20, 21)
    assert g.bounds == (885100.0, 629378.0, 885140.0, 629420.0)
    assert g.transform == (885100.0, 2.0, 0.0, 629420.0, 0.0, -2.0)
    assert g.radius == pytest.approx(math.sqrt(2.0))


@pytest.mark.parametrize("kw", [dict(resolution=0), dict(resolution=-2.0),
                                dict(resolution=float("nan")), dict(ground="csf"),
                                dict(bounds=(1.0, 2.0, 0.0, 3.0)), dict(bounds=(1.0, 2.0, 3.0))])
def test_params_rejected(kw: dict) -> None:
    with pytest.raises(InputError):
        RasterParams(**kw)


def test_cell_percentile_matches_numpy_percentile() -> None:
    rng = np.random.default_rng(20240601)
    cell = rng.integers(0, 50, 4000)
    vals = rng.normal(300.0, 10.0, 4000)
    got = cell_percentile(cell, vals, 60, 90.0)
    for c in range(60):
        sel = vals[cell == c]
        if sel.size:
            assert got[c] == pytest.approx(np.percentile(sel, 90.0), abs=1e-9)
        else:
            assert np.isnan(got[c])
    # single-value cells and q at the ends
    assert cell_percentile(np.array([3]), np.array([7.5]), 5, 90.0)[3] == 7.5
    np.testing.assert_allclose(cell_percentile(cell, vals, 60, 100.0)[:50],
                               [vals[cell == c].max() for c in range(50)])


def test_cell_neighbourhoods_match_brute_force() -> None:
    rng = np.random.default_rng(7)
    x = rng.uniform(-3.0, 23.0, 3000)
    y = rng.uniform(-3.0, 17.0, 3000)
    res, w, h = 2.0, 10, 7
    r = res * math.sqrt(2) / 2
    cell, pt = cell_neighbourhoods(x, y, origin_x=0.0, top_y=14.0, resolution=res,
                                   width=w, height=h, radius=r)
    got = set(zip(cell.tolist(), pt.tolist()))
    cols, rows = np.meshgrid(np.arange(w), np.arange(h))
    cx = (cols.ravel() + 0.5) * res
    cy = 14.0 - (rows.ravel() + 0.5) * res
    d = np.hypot(x[None, :] - cx[:, None], y[None, :] - cy[:, None])
    c_idx, p_idx = np.nonzero(d < r)
    assert got == set(zip(c_idx.tolist(), p_idx.tolist()))


# ------------------------------------------------------------------- with real PDAL
@pytest.fixture(scope="module")
def bcts_run(tmp_path_factory, pdal_bin, sample):  # noqa: ANN001
    paths = [sample(p) for p in BCTS]
    out = tmp_path_factory.mktemp("bcts")
    seen: list[float] = []
    result = make_reference_rasters(paths, out, resolution=2.0, bounds=BCTS_BOUNDS,
                                    pdal=pdal_bin, progress=lambda f, m: seen.append(f))
    assert seen[-1] == 1.0 and seen == sorted(seen)
    return result, paths


def test_rasters_share_one_grid(bcts_run) -> None:  # noqa: ANN001
    result, _ = bcts_run
    g = result.grid
    assert (g.origin_x, g.origin_y, g.width, g.height) == (885100.0, 629380.0, 20, 20)
    metas = []
    for p in (result.dtm, result.dsm_max, result.dsm_p90):
        with rasterio.open(p) as src:
            metas.append((src.width, src.height, tuple(src.transform)[:6], src.nodata,
                          src.dtypes[0], src.crs.to_wkt()))
            assert src.crs is not None
            assert pyproj.CRS.from_wkt(src.crs.to_wkt()).sub_crs_list[0].to_epsg() == 3005
    assert metas[0] == metas[1] == metas[2]
    assert metas[0][:5] == (20, 20, (2.0, 0.0, 885100.0, 0.0, -2.0, 629420.0), NODATA,
                            "float32")


def test_dtm_dsm_p90_match_numpy_oracle(bcts_run) -> None:  # noqa: ANN001
    result, paths = bcts_run
    x, y, z, c = _read(paths)
    dtm, src = _band(result.dtm)
    shape, tr = dtm.shape, src.transform
    g = c == 2
    expected = _oracle(x[g], y[g], z[g], tr, shape, 2.0, np.mean)
    # the cells with ground points hold their mean; the others were filled and are marked
    mask, _ = _band(result.dtm_fill_mask)
    assert np.isnan(expected).any()  # the sample has holes under the canopy
    assert np.array_equal(mask == 1, np.isnan(expected))
    _assert_same(np.where(mask == 1, np.nan, dtm), expected)
    keep = (c != 7) & (c != 18)
    dsm, _ = _band(result.dsm_max)
    _assert_same(dsm, _oracle(x[keep], y[keep], z[keep], tr, shape, 2.0, np.max))
    p90, _ = _band(result.dsm_p90)
    _assert_same(p90, _oracle(x[keep], y[keep], z[keep], tr, shape, 2.0,
                              lambda v: np.percentile(v, 90.0)))
    # sanity of the sample: canopy above ground, p90 between ground and max
    ok = ~np.isnan(expected) & ~np.isnan(dsm)
    assert np.all(p90[ok] <= dsm[ok] + 1e-4)
    assert np.nanmax(dsm - dtm) > 10.0


def test_reprojected_output_matches_pyproj(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    # WGS 84 / UTM 17N -> WGS 84 / UTM 16N: same datum, so PDAL's PROJ and pyproj agree to
    # the millimetre (across datums they may pick different transformations: README).
    tile = sample("als/pyfor_test.laz")
    x, y, z, c = _read([tile])
    ux, uy = pyproj.Transformer.from_crs(32617, 32616, always_xy=True).transform(x, y)
    cx, cy = float(np.median(ux)), float(np.median(uy))
    bounds = (cx - 15.0, cy - 15.0, cx + 15.0, cy + 15.0)
    result = make_reference_rasters([tile], tmp_path, bounds=bounds, crs="EPSG:32616",
                                    pdal=pdal_bin)
    with rasterio.open(result.dsm_max) as src:
        assert src.crs.to_epsg() == 32616
    keep = (c != 7) & (c != 18)
    dsm, src = _band(result.dsm_max)
    _assert_same(dsm, _oracle(ux[keep], uy[keep], z[keep], src.transform, dsm.shape, 2.0,
                              np.max))
    p90, _ = _band(result.dsm_p90)
    _assert_same(p90, _oracle(ux[keep], uy[keep], z[keep], src.transform, dsm.shape, 2.0,
                              lambda v: np.percentile(v, 90.0)))


@pytest.mark.slow
def test_smrf_dtm_close_to_class2_dtm(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    tile = sample("als/lidR_Topography.laz")  # real relief, 0.9 pts/m2, ground in class 2
    bounds = (273440.0, 5274440.0, 273560.0, 5274560.0)
    a = make_reference_rasters([tile], tmp_path / "c2", resolution=4.0, bounds=bounds,
                               pdal=pdal_bin)
    b = make_reference_rasters([tile], tmp_path / "smrf", resolution=4.0, bounds=bounds,
                               ground="smrf", pdal=pdal_bin)
    d2, _ = _band(a.dtm)
    ds, _ = _band(b.dtm)
    both = ~np.isnan(d2) & ~np.isnan(ds)
    assert both.sum() > 0.5 * d2.size
    assert np.median(np.abs(ds[both] - d2[both])) < 0.3


# ------------------------------------------------------------------------ bad input
def _write_tile(path: Path, src: Path, crs: pyproj.CRS | None, n: int = 20000,
                classification: int | None = None, version: str = "1.2") -> Path:
    las = laspy.read(src)
    hdr = laspy.LasHeader(point_format=1, version=version)
    hdr.scales = las.header.scales
    hdr.offsets = las.header.offsets
    if crs is not None:
        hdr.add_crs(crs)
    out = laspy.LasData(hdr)
    out.x = np.asarray(las.x)[:n]
    out.y = np.asarray(las.y)[:n]
    out.z = np.asarray(las.z)[:n]
    cls = np.asarray(las.classification)[:n]
    out.classification = cls if classification is None else np.full(n, classification, "u1")
    out.write(path)
    return path


def test_bounds_outside_tiles_is_coverage_error(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    with pytest.raises(CoverageError, match="do not overlap"):
        make_reference_rasters([sample(BCTS[0])], tmp_path / "o", bounds=(0, 0, 100, 100),
                               pdal=pdal_bin)
    assert not list((tmp_path / "o").glob("*.tif")) if (tmp_path / "o").exists() else True


def test_tile_without_crs(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    tile = _write_tile(tmp_path / "nocrs.las", sample("als/pyfor_test.laz"), None)
    with pytest.raises(CRSError, match="no CRS.*--crs"):
        make_reference_rasters([tile], tmp_path / "o", pdal=pdal_bin)
    # given the CRS its coordinates are in, it works and the raster carries it
    info = laspy.read(tile)
    b = (float(info.x.min()) + 5, float(info.y.min()) + 5,
         float(info.x.min()) + 25, float(info.y.min()) + 25)
    r = make_reference_rasters([tile], tmp_path / "ok", crs="EPSG:32617", bounds=b,
                               pdal=pdal_bin)
    with rasterio.open(r.dsm_max) as src:
        assert src.crs.to_epsg() == 32617


def test_tile_in_feet_is_crs_error(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    tile = _write_tile(tmp_path / "feet.las", sample("als/pyfor_test.laz"),
                       pyproj.CRS.from_epsg(2236))  # NAD83 / Florida East (ftUS)
    with pytest.raises(CRSError, match="(?i)foot|feet"):
        make_reference_rasters([tile], tmp_path / "o", pdal=pdal_bin)


def test_tiles_in_different_crs_need_crs(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    with pytest.raises(CRSError, match="different CRSs"):
        make_reference_rasters([sample("als/pyfor_test.laz"), sample(BCTS[0])], tmp_path,
                               pdal=pdal_bin)


def test_no_ground_points(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    tile = _write_tile(tmp_path / "noground.las", sample("als/pyfor_test.laz"),
                       pyproj.CRS.from_epsg(32617), classification=1)
    with pytest.raises(NoUsableDataError, match="smrf"):
        make_reference_rasters([tile], tmp_path / "o", pdal=pdal_bin)
    assert not list((tmp_path / "o").glob("*.tif")), "a failed run left rasters behind"


def test_missing_and_corrupt_tiles(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    with pytest.raises(FileFormatError, match="does not exist"):
        make_reference_rasters([tmp_path / "nope.laz"], tmp_path, pdal=pdal_bin)
    data = sample(BCTS[0]).read_bytes()
    for n in (200, 100_000):
        bad = tmp_path / f"truncated{n}.laz"
        bad.write_bytes(data[:n])
        with pytest.raises(FileFormatError, match=f"truncated{n}.laz.*truncated"):
            make_reference_rasters([bad], tmp_path, pdal=pdal_bin)
    text = tmp_path / "notes.las"
    text.write_text("x,y,z\n" * 100)
    with pytest.raises(FileFormatError, match="not a LAS/LAZ file"):
        make_reference_rasters([text], tmp_path, pdal=pdal_bin)


def test_cli_rasters(tmp_path: Path, pdal_bin: str, sample, monkeypatch) -> None:  # noqa: ANN001
    from canopyblocks.cli import main

    monkeypatch.setenv("CANOPYBLOCKS_PDAL", pdal_bin)
    tile = str(sample("als/pyfor_test.laz"))
    rc = main(["-q", "rasters", tile, "-o", str(tmp_path / "out"), "--bounds",
               "405100", "3276400", "405120", "3276420"])
    assert rc == 0
    for name in ("dtm.tif", "dsm_max.tif", "dsm_p90.tif"):
        with rasterio.open(tmp_path / "out" / name) as src:
            assert (src.width, src.height) == (10, 10)
    assert main(["-q", "rasters", tile, "-o", str(tmp_path / "bad"), "--bounds",
                 "0", "0", "10", "10"]) == 2
    assert main(["-q", "rasters", tile, "-o", str(tmp_path / "bad"),
                 "--resolution", "-1"]) == 2


def test_las14_geotiff_keys_crs_is_not_lost(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    """PDAL 2.2 ignores GeoTIFF-key CRS records in LAS 1.4; the CRS laspy reads is used."""
    tile = _write_tile(tmp_path / "v14.las", sample("als/pyfor_test.laz"),
                       pyproj.CRS.from_epsg(32617), version="1.4")
    las = laspy.read(tile)
    b = (float(las.x.min()) + 4, float(las.y.min()) + 4,
         float(las.x.min()) + 20, float(las.y.min()) + 20)
    r = make_reference_rasters([tile], tmp_path / "o", bounds=b, pdal=pdal_bin)
    with rasterio.open(r.dsm_max) as src:  # + unknown height, as every stated CRS without one
        crs = pyproj.CRS.from_wkt(src.crs.to_wkt())
        assert (crs.sub_crs_list[0] if crs.is_compound else crs).to_epsg() == 32617
    x, y, z, c = _read([tile])
    dsm, src = _band(r.dsm_max)
    keep = (c != 7) & (c != 18)
    _assert_same(dsm, _oracle(x[keep], y[keep], z[keep], src.transform, dsm.shape, 2.0, np.max))


def test_crop_corridor_points(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    shapely = pytest.importorskip("shapely")
    from canopyblocks.reference.lidar_points import crop_corridor

    tile = sample("als/pyfor_test.laz")
    poly = shapely.LineString([(405020.0, 3276480.0), (405180.0, 3276330.0)]).buffer(
        1.0, cap_style="flat")
    out = crop_corridor([tile], poly.wkt, tmp_path / "corr.laz", pdal=pdal_bin)
    x, y, _, _ = _read([tile])
    assert laspy.read(out).header.point_count == int(shapely.contains_xy(poly, x, y).sum())
    far = shapely.box(0, 0, 10, 10)
    with pytest.raises(NoUsableDataError, match="corridor"):
        crop_corridor([tile], far.wkt, tmp_path / "none.laz", pdal=pdal_bin)
    assert not (tmp_path / "none.laz").exists()


def test_cancel_leaves_no_rasters(tmp_path: Path, pdal_bin: str, sample) -> None:  # noqa: ANN001
    from canopyblocks.errors import CancelledError
    from canopyblocks.progress import Progress

    msgs: list[str] = []
    prog = Progress(callback=lambda f, m: msgs.append(m),
                    cancelled=lambda: any("dsm_max done" in m for m in msgs))
    with pytest.raises(CancelledError):
        make_reference_rasters([sample("als/pyfor_test.laz")], tmp_path / "o",
                               bounds=(405100, 3276400, 405120, 3276420), pdal=pdal_bin,
                               progress=prog)
    assert any("dtm done" in m for m in msgs)  # the DTM is made first, then the DSMs
    assert not list((tmp_path / "o").iterdir())


# ------------------------------------------------------------- filled DTM, CRS codes
def test_fill_reproduces_a_plane_and_leaves_the_outside_empty() -> None:
    """A plane is harmonic, so holes enclosed by measured cells come back exactly; a hole on
    the survey's edge gets a value within the measured ground around it; cells outside
    the survey (no point, not enclosed) stay empty; a gap with no point at all inside the
    survey is filled."""
    from canopyblocks.reference.dtm_fill import fill_dtm_holes

    rows, cols = np.mgrid[0:30, 0:40]
    plane = 100.0 + 0.5 * cols - 0.25 * rows
    rng = np.random.default_rng(22)
    dtm = plane.copy()
    holes = rng.random(plane.shape) < 0.25
    holes[[0, -1], :] = False
    holes[:, [0, -6, -5, -4, -3, -2, -1]] = False  # enclosed by measured cells
    holes[10:16, 10:20] = True  # and a big gap under dense canopy
    dtm[holes] = np.nan
    dtm[:, -5:] = np.nan  # the survey's last 5 columns: no point at all ...
    support = np.ones(plane.shape, bool)
    support[:, -5:] = False
    support[:, -5] = True  # ... except the first of them: points, no ground
    filled, mask = fill_dtm_holes(dtm, support)
    assert np.array_equal(mask[:, :-5], holes[:, :-5])
    np.testing.assert_allclose(filled[holes], plane[holes], atol=1e-6)
    assert mask[:, -5].all() and not mask[:, -4:].any()
    assert np.isnan(filled[:, -4:]).all()
    edge = filled[:, -5]
    assert edge.min() >= plane[:, -6].min() - 1e-9 and edge.max() <= plane[:, -6].max() + 1e-9
    # an enclosed gap without any point is a hole of the survey: filled
    support2 = np.ones(plane.shape, bool)
    support2[10:13, 10:13] = False
    dtm2 = plane.copy()
    dtm2[10:13, 10:13] = np.nan
    filled2, mask2 = fill_dtm_holes(dtm2, support2)
    assert mask2.sum() == 9
    np.testing.assert_allclose(filled2[10:13, 10:13], plane[10:13, 10:13], atol=1e-9)


def _raw_pdal_dtm(pdal_bin: str, tiles: list[Path], grid, out: Path) -> np.ndarray:  # noqa: ANN001
    """PDAL's DTM written here by a pipeline of its own (not the library's): mean of class 2
    within the cell circle, nodata -9999 -- the raw DTM before any filling."""
    import json
    import subprocess

    stages: list[object] = [{"type": "readers.las", "filename": str(t)} for t in tiles]
    stages += [{"type": "filters.range", "limits": "Classification[2:2]"},
               {"type": "writers.gdal", "filename": str(out), "output_type": "mean",
                "resolution": grid.resolution, "radius": grid.radius,
                "origin_x": grid.origin_x, "origin_y": grid.origin_y,
                "width": grid.width, "height": grid.height, "nodata": -9999,
                "window_size": 0}]
    r = subprocess.run([pdal_bin, "pipeline", "--stdin"], input=json.dumps(stages),
                       text=True, capture_output=True, timeout=300)
    assert r.returncode == 0, r.stderr
    with rasterio.open(out) as src:
        return src.read(1)


def test_filled_dtm_has_no_holes_and_the_mask_marks_exactly_pdals_empty_cells(
        bcts_run, pdal_bin, tmp_path: Path) -> None:  # noqa: ANN001
    result, paths = bcts_run
    raw = _raw_pdal_dtm(pdal_bin, paths, result.grid, tmp_path / "raw.tif")
    with rasterio.open(result.dtm) as d, rasterio.open(result.dtm_fill_mask) as m, \
            rasterio.open(result.dsm_max) as s:
        dtm, mask, dsm = d.read(1), m.read(1), s.read(1)
        assert m.dtypes[0] == "uint8" and m.nodata == 255 and m.transform == d.transform
    empty = raw == -9999
    assert 0 < empty.sum() < empty.size  # PDAL left holes under the canopy
    assert (dsm != NODATA).all()  # the whole area holds points: every cell must have ground
    assert (dtm != NODATA).all()
    assert int((mask == 1).sum()) == int(empty.sum())
    assert np.array_equal(mask == 1, empty) and np.array_equal(mask == 0, ~empty)
    np.testing.assert_allclose(dtm[~empty], raw[~empty], atol=1e-3)
    assert result.stats["dtm_filled"] == int(empty.sum())
    # a filled value lies between the lowest and highest measured ground around it
    from scipy import ndimage

    lo = ndimage.minimum_filter(np.where(empty, np.inf, raw), size=7, mode="nearest")
    hi = ndimage.maximum_filter(np.where(empty, -np.inf, raw), size=7, mode="nearest")
    assert np.all((dtm[empty] >= lo[empty] - 1e-3) & (dtm[empty] <= hi[empty] + 1e-3))


@pytest.mark.parametrize("tile,expected", [
    ("als/lasR_bcts_1.laz", ("EPSG:3005", "EPSG:5713")),  # NAD83 / BC Albers + CGVD28 height
    ("als/pyfor_test.laz", ("EPSG:32617", None)),  # vertical CRS unknown in the file
])
def test_rasters_carry_authority_codes(tmp_path: Path, pdal_bin: str, sample, tile,  # noqa: ANN001
                                       expected) -> None:
    las = laspy.read(sample(tile))
    x0, y0 = float(np.median(las.x)), float(np.median(las.y))
    r = make_reference_rasters([sample(tile)], tmp_path, bounds=(x0, y0, x0 + 20, y0 + 20),
                               pdal=pdal_bin)
    for p in (r.dtm, r.dsm_max, r.dsm_p90, r.dtm_fill_mask):
        with rasterio.open(p) as src:
            crs = pyproj.CRS.from_wkt(src.crs.to_wkt())
        h = crs.sub_crs_list[0] if crs.is_compound else crs
        assert f"EPSG:{h.to_epsg()}" == expected[0]
        assert "unknown" not in crs.name.split(" + ")[0].lower()
        if expected[1] is not None:
            assert f"EPSG:{crs.sub_crs_list[1].to_epsg()}" == expected[1]
    assert r.crs.sub_crs_list[0].to_epsg() == int(expected[0].split(":")[1])
