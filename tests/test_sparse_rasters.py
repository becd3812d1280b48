"""A sparse grid along a corridor: the same cells as the dense grid, in tiled files.

The dense path is rebuilt here from its parts (every tile's unit, ``merge_tiles`` on the
whole box, the polygon test on every cell centre, ``fill_dtm_holes`` on the whole box) and
the sparse files must hold the same value in every cell of the box.  The windowed DTM fill
must equal the dense one on grids with enclosed gaps and absent windows; a tile copied 20
km away gives a run whose box the dense path refused, with the cells of a single-tile run;
the files are tiled, compressed, and read back by read_surface with the dense values.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")
shapely = pytest.importorskip("shapely")
pytest.importorskip("laspy")

from canopyblocks.reference.dtm_fill import fill_dtm_holes, fill_windows  # noqa: E402
from canopyblocks.reference.raster_grid import Grid, RasterParams  # noqa: E402
from canopyblocks.reference.raster_plan import las_plan  # noqa: E402
from canopyblocks.reference.raster_sampling import TiledValues, read_surface  # noqa: E402
from canopyblocks.reference.raster_tiles import merge_tiles, tile_surfaces  # noqa: E402
from canopyblocks.reference.raster_windows import Windows, to_dense  # noqa: E402
from canopyblocks.reference.rasters import make_reference_rasters  # noqa: E402

BCTS = ("als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz")
# a 13 m corridor across both tiles at an angle to the grid, with a bend
CORRIDOR = shapely.LineString([(885020.0, 629160.0), (885120.0, 629400.0),
                               (885210.0, 629690.0)]).buffer(6.5, cap_style="flat")


def _band(path: Path) -> np.ndarray:
    with rasterio.open(path) as src:
        a = src.read(1).astype(np.float64)
        a[a == src.nodata] = np.nan
    return a


def _dense_reference(paths: list[Path], poly: object, resolution: float
                     ) -> dict[str, np.ndarray]:
    """The dense path: all units, merged on the whole box, masked, filled on the box."""
    plan = las_plan(paths, RasterParams(resolution=resolution), None, poly, None)
    g = plan.grid
    surf = merge_tiles([tile_surfaces(u) for u in plan.units], g, ground=True)
    cx = g.origin_x + (np.arange(g.width) + 0.5) * g.resolution
    cy = g.top_y - (np.arange(g.height) + 0.5) * g.resolution
    xx, yy = np.meshgrid(cx, cy)
    outside = ~shapely.contains_xy(poly, xx, yy)
    for a in (surf.dtm, surf.top, surf.p90):
        a[outside] = np.nan
    filled, mask = fill_dtm_holes(surf.dtm, np.isfinite(surf.top))
    codes = np.where(mask, 1.0, np.where(np.isfinite(filled), 0.0, np.nan))
    return {"dtm": filled, "dsm_max": surf.top, "dsm_p90": surf.p90, "dtm_fill_mask": codes}


@pytest.fixture(scope="module", params=[2.0, 0.5])
def corridor_run(request, tmp_path_factory, sample):  # noqa: ANN001
    paths = [Path(sample(p)) for p in BCTS]
    out = tmp_path_factory.mktemp("sparse")
    return make_reference_rasters(paths, out, polygon=CORRIDOR,
                                  resolution=request.param), paths


def test_corridor_cells_equal_the_dense_path_cell_by_cell(corridor_run) -> None:  # noqa: ANN001
    rr, paths = corridor_run
    dense = _dense_reference(paths, CORRIDOR, rr.grid.resolution)
    files = {"dtm": rr.dtm, "dsm_max": rr.dsm_max, "dsm_p90": rr.dsm_p90,
             "dtm_fill_mask": rr.dtm_fill_mask}
    for name, path in files.items():
        got = _band(path)
        want = dense[name].astype(np.float32).astype(np.float64)
        assert got.shape == want.shape, name
        assert np.array_equal(np.isnan(got), np.isnan(want)), name
        np.testing.assert_array_equal(got[~np.isnan(got)], want[~np.isnan(want)], err_msg=name)
    assert np.isfinite(dense["dsm_max"]).sum() > 1000
    assert (dense["dtm_fill_mask"] == 1).sum() > 10  # holes under canopy were filled


def test_files_are_tiled_compressed_and_sparse(corridor_run) -> None:  # noqa: ANN001
    rr, _ = corridor_run
    for path in (rr.dtm, rr.dsm_max, rr.dsm_p90, rr.dtm_fill_mask):
        with rasterio.open(path) as src:
            assert src.profile["tiled"] and src.block_shapes[0] == (256, 256)
            assert src.compression.name.lower() == "deflate"
    assert rr.stats["windows"] >= 1


def _fill_case(seed: int, size: int = 16, n: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """A (n*size)^2 grid: a ring of support (an enclosed gap), scattered points, random
    ground, and two windows without points at all (one on the grid's edge, one inside)."""
    rng = np.random.default_rng(seed)
    h = w = n * size
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot(yy - h / 2, xx - w / 2)
    support = (r > h * 0.2) & (r < h * 0.42) | (rng.random((h, w)) < 0.03)
    support &= ~(((yy // size == 0) | (yy // size == 1)) & (xx // size == 1))
    dtm = np.where(support & (rng.random((h, w)) < 0.6), 100 + 0.1 * xx + rng.random((h, w)),
                   np.nan)
    return dtm, support


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_windowed_fill_equals_dense_fill(seed: int) -> None:
    size, n = 16, 6
    dtm, support = _fill_case(seed, size, n)
    grid = Grid(0.0, 0.0, n * size - 5, n * size - 3, 1.0, "")  # partial windows at the edge
    dtm, support = dtm[:grid.height, :grid.width], support[:grid.height, :grid.width]
    want, want_mask = fill_dtm_holes(dtm, support)
    held = Windows.over(grid, None, size)
    keep = np.array([bool(_blocks(support, held)[s].any()) for s in range(held.ids.size)])
    windows = Windows(grid, held.ids[keep], size)  # the windows without points are absent
    got, mask = fill_windows(_blocks(dtm, windows), _blocks(support, windows) > 0, windows)
    dense = to_dense(got, windows)
    dense_mask = to_dense(mask.astype(float), windows, 0.0) > 0
    assert keep.sum() == keep.size - 2
    assert np.array_equal(dense_mask, want_mask)
    np.testing.assert_array_equal(np.isnan(dense), np.isnan(want))
    differ = want_mask & ~np.isclose(dense, want, rtol=0, atol=1e-9)
    for r, c in zip(*np.nonzero(differ)):  # only a tie of nearest measured cells may differ
        mr, mc = np.nonzero(np.isfinite(dtm))
        d = np.hypot(mr - r, mc - c)
        nearest = d == d.min()
        assert want[r, c] in dtm[mr[nearest], mc[nearest]]
        assert dense[r, c] in dtm[mr[nearest], mc[nearest]]
    assert differ.sum() <= 2
    assert np.array_equal(dense[~want_mask & ~np.isnan(want)], want[~want_mask & ~np.isnan(want)])
    assert want_mask.sum() > 50


def _blocks(a: np.ndarray, windows: Windows) -> np.ndarray:
    out = windows.blocks(0.0 if a.dtype == bool else np.nan)
    for s in range(windows.ids.size):
        r0, c0, nr, nc = windows.clip(s)
        out[s, :nr, :nc] = a[r0:r0 + nr, c0:c0 + nc]
    return out


def _shifted_copy(src: Path, dst: Path, dx: float, dy: float) -> None:
    data = bytearray(src.read_bytes())
    xo, yo = struct.unpack_from("<dd", data, 155)
    struct.pack_into("<dd", data, 155, xo + dx, yo + dy)
    maxx, minx, maxy, miny = struct.unpack_from("<dddd", data, 179)
    struct.pack_into("<dddd", data, 179, maxx + dx, minx + dx, maxy + dy, miny + dy)
    dst.write_bytes(bytes(data))


def test_corridor_over_20_km_runs_with_a_single_tiles_cells(tmp_path: Path, sample) -> None:  # noqa: ANN001
    src = Path(sample(BCTS[0]))
    far = tmp_path / "far.laz"
    _shifted_copy(src, far, 20000.0, 20000.0)
    line = shapely.LineString([(885020.0, 629160.0), (905200.0, 649380.0)])
    poly = line.buffer(6.5, cap_style="flat")
    two = make_reference_rasters([src, far], tmp_path / "two", polygon=poly)
    assert two.grid.width * two.grid.height > 100_000_000  # the dense grid was refused
    one = make_reference_rasters([src], tmp_path / "one", polygon=poly)
    for name in ("dtm", "dsm_max", "dsm_p90"):
        a = read_surface(getattr(one, name))
        b = read_surface(getattr(two, name))
        assert isinstance(b.values, TiledValues) and b.values.blocks.shape[0] < 200
        assert isinstance(a.values, np.ndarray)
        rows, cols = np.nonzero(np.isfinite(a.values))
        x = a.x0 + (cols + 0.5) * a.dx
        y = a.y0 - (rows + 0.5) * a.dy
        bc = np.floor((x - b.x0) / b.dx).astype(int)
        br = np.floor((b.y0 - y) / b.dy).astype(int)
        np.testing.assert_array_equal(b.values.take(br, bc), a.values[rows, cols], name)
        assert rows.size > 500
    assert (tmp_path / "two" / "dsm_max.tif").stat().st_size < 5_000_000


def test_tiled_surface_samples_as_the_dense_band(corridor_run, monkeypatch) -> None:  # noqa: ANN001
    rr, _ = corridor_run
    dense = read_surface(rr.dsm_max)
    assert isinstance(dense.values, np.ndarray)
    from canopyblocks.reference import raster_sampling

    monkeypatch.setattr(raster_sampling, "_DENSE_CELLS", 0)
    tiled = read_surface(rr.dsm_max)
    assert isinstance(tiled.values, TiledValues)
    rng = np.random.default_rng(4)
    pts = CORRIDOR.buffer(3)
    x0, y0, x1, y1 = pts.bounds
    x = rng.uniform(x0, x1, 200000)
    y = rng.uniform(y0, y1, 200000)
    np.testing.assert_array_equal(tiled.bilinear(x, y), dense.bilinear(x, y))
    assert np.isfinite(dense.bilinear(x, y)).sum() > 1000


def test_area_test_equals_contains_xy() -> None:
    from canopyblocks.reference.raster_windows import area_test

    area = CORRIDOR.buffer(1.4)
    box = (885000.0, 629150.0, 885200.0, 629700.0)
    test = area_test(area, box, 2.0)
    rng = np.random.default_rng(7)
    x = np.r_[rng.uniform(884990, 885210, 300000), np.round(rng.uniform(884990, 885210, 50000))]
    y = np.r_[rng.uniform(629140, 629710, 300000), np.round(rng.uniform(629140, 629710, 50000))]
    want = shapely.contains_xy(area, x, y)
    assert np.array_equal(test(x, y), want)
    assert want.sum() > 1000
