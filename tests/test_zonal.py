"""Block reference values from rasters vs a brute-force cell-by-cell computation."""

from __future__ import annotations

import time
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import rasterio
import shapely
from affine import Affine

from canopyblocks.errors import CoverageError, CRSError, FileFormatError, InputError
from canopyblocks.reference.corridor import block_corridors
from canopyblocks.reference.zonal import block_reference_values

X0, Y0, RES = 500_003.3, 4_600_207.1, 2.0  # raster origin (upper left) and cell size


def write_tif(path: Path, arr: np.ndarray, *, x0: float = X0, y0: float = Y0, res: float = RES,
              crs: object = "EPSG:32612", nodata: float | None = -9999.0) -> Path:
    arr = np.asarray(arr, dtype=np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=arr.shape[1], height=arr.shape[0],
                       count=1, dtype="float32", crs=crs, nodata=nodata,
                       transform=Affine(res, 0.0, x0, 0.0, -res, y0)) as dst:
        dst.write(arr, 1)
    return path


def make_blocks(n: int, length: float, angle_deg: float, x0: float, y0: float,
                crs: object = 32612) -> gpd.GeoDataFrame:
    th = np.radians(angle_deg)
    s0 = np.arange(n) * length
    sm = s0 + length / 2
    d = pd.DataFrame({"track": "gt1r", "length": float(length), "block": np.arange(n),
                      "s_start": s0, "s_end": s0 + length,
                      "x": x0 + sm * np.cos(th), "y": y0 + sm * np.sin(th)})
    return gpd.GeoDataFrame(d, geometry=gpd.points_from_xy(d.x, d.y), crs=crs)


def brute_force(poly: shapely.Geometry, arrays: dict[str, np.ndarray], *,
                all_touched: bool = True, x0: float = X0, y0: float = Y0,
                res: float = RES) -> dict[str, np.ndarray]:
    """Values of the cells a polygon touches, by testing every cell square with shapely."""
    h, w = next(iter(arrays.values())).shape
    out = {k: [] for k in arrays}
    n = 0
    for r in range(h):
        for c in range(w):
            xa, yb = x0 + c * res, y0 - (r + 1) * res
            if all_touched:
                hit = shapely.box(xa, yb, xa + res, yb + res).intersects(poly)
            else:
                hit = poly.contains(shapely.Point(xa + res / 2, yb + res / 2))
            if hit:
                n += 1
                for k, a in arrays.items():
                    out[k].append(a[r, c])
    res_ = {k: np.asarray(v, dtype=float) for k, v in out.items()}
    res_["_n"] = n
    return res_


@pytest.fixture()
def rasters(tmp_path: Path) -> dict[str, object]:
    rng = np.random.default_rng(1234)
    h, w = 60, 70
    dtm = 300 + rng.normal(0, 2, (h, w))
    dsm = dtm + rng.uniform(0, 30, (h, w))
    p90 = dtm + 0.8 * (dsm - dtm)
    dtm[10:14, 20:40] = -9999.0  # a nodata patch the track crosses
    dsm[30:33, 30:50] = -9999.0
    return {
        "dtm": write_tif(tmp_path / "dtm.tif", dtm),
        "dsm_max": write_tif(tmp_path / "dsm.tif", dsm),
        "dsm_p90": write_tif(tmp_path / "p90.tif", p90),
        "arrays": {"dtm": np.where(dtm == -9999, np.nan, dtm),
                   "dsm_max": np.where(dsm == -9999, np.nan, dsm), "dsm_p90": p90},
    }


@pytest.mark.parametrize("all_touched", [True, False])
@pytest.mark.parametrize("width", [2.0, 7.3])
def test_against_brute_force(rasters: dict, all_touched: bool, width: float) -> None:
    # diagonal track inside the raster (x 500003..500143, y 4600087..4600207)
    blocks = make_blocks(6, 15.0, -53.0, 500_040.7, 4_600_195.2)
    cor = block_corridors(blocks, width=width)
    ref = block_reference_values(cor, dtm=rasters["dtm"], dsm_max=rasters["dsm_max"],
                                 dsm_p90=rasters["dsm_p90"], all_touched=all_touched)
    assert list(ref.index) == list(blocks.index)
    for i, poly in enumerate(cor.geometry):
        bf = brute_force(poly, rasters["arrays"], all_touched=all_touched)
        g, t, t9 = bf["dtm"], bf["dsm_max"], bf["dsm_p90"]
        assert ref["ref_ground"].iloc[i] == pytest.approx(np.nanmean(g), abs=1e-4)
        assert ref["ref_top"].iloc[i] == pytest.approx(np.nanmax(t), abs=1e-4)
        assert ref["ref_top90"].iloc[i] == pytest.approx(np.nanmax(t9), abs=1e-4)
        assert ref["ref_hmax"].iloc[i] == pytest.approx(np.nanmax(t) - np.nanmean(g), abs=1e-4)
        assert ref["ref_h90"].iloc[i] == pytest.approx(np.nanmax(t9) - np.nanmean(g), abs=1e-4)
        cov = np.sum(np.isfinite(g) & np.isfinite(t)) / bf["_n"]
        assert ref["coverage"].iloc[i] == pytest.approx(cov, abs=1e-12)
    assert (ref["ref_flag"] == "ok").all()
    assert (ref["coverage"] < 1).any()  # the nodata patches were crossed


def test_other_statistics(rasters: dict) -> None:
    blocks = make_blocks(3, 25.0, 10.0, 500_020.0, 4_600_150.0)
    cor = block_corridors(blocks, width=3.0)
    ref = block_reference_values(cor, dtm=rasters["dtm"], dsm_max=rasters["dsm_max"],
                                 dsm_p90=rasters["dsm_p90"], ground_stat="min",
                                 top_stat="median", top90_stat="mean")
    for i, poly in enumerate(cor.geometry):
        bf = brute_force(poly, rasters["arrays"])
        assert ref["ref_ground"].iloc[i] == pytest.approx(np.nanmin(bf["dtm"]), abs=1e-4)
        assert ref["ref_top"].iloc[i] == pytest.approx(np.nanmedian(bf["dsm_max"]), abs=1e-4)
        assert ref["ref_top90"].iloc[i] == pytest.approx(np.nanmean(bf["dsm_p90"]), abs=1e-4)
    with pytest.raises(InputError, match="ground_stat='mode'"):
        block_reference_values(cor, dtm=rasters["dtm"], dsm_max=rasters["dsm_max"],
                               dsm_p90=rasters["dsm_p90"], ground_stat="mode")


def test_partly_outside_is_flagged_not_dropped(rasters: dict) -> None:
    # runs east past the raster's right edge at x = 500143.3
    blocks = make_blocks(8, 25.0, 0.0, 500_000.0 + 20.0, 4_600_120.0)
    cor = block_corridors(blocks)
    ref = block_reference_values(cor, dtm=rasters["dtm"], dsm_max=rasters["dsm_max"],
                                 dsm_p90=rasters["dsm_p90"])
    assert len(ref) == 8
    s_end_x = 500_020.0 + blocks["s_end"].to_numpy()
    s_start_x = 500_020.0 + blocks["s_start"].to_numpy()
    inside = s_end_x < 500_143.3
    beyond = s_start_x > 500_143.3
    assert (ref["ref_flag"][inside] == "ok").all()
    assert (ref["ref_flag"][~inside] == "outside").all()
    assert ref["ref_ground"][beyond].isna().all()
    assert (ref["coverage"][beyond] == 0).all()
    straddle = ~inside & ~beyond
    assert ref["ref_ground"][straddle].notna().all()  # values from the cells inside
    assert (ref["coverage"][straddle] < 1).all() and (ref["coverage"][straddle] > 0).all()


def test_nodata_flag(tmp_path: Path) -> None:
    arr = np.full((20, 20), 100.0)
    arr[:, 10:] = -9999.0  # east half nodata
    paths = [write_tif(tmp_path / f"{k}.tif", arr + o) for k, o in (("a", 0), ("b", 10), ("c", 5))]
    blocks = make_blocks(2, 10.0, 90.0, X0 + 31.0, Y0 - 35.0)  # x = X0+31: east half
    cor = block_corridors(blocks)
    ref = block_reference_values(cor, dtm=paths[0], dsm_max=paths[1], dsm_p90=paths[2])
    assert list(ref["ref_flag"]) == ["nodata", "nodata"]
    assert (ref["coverage"] == 0).all()


def test_not_covering_raises(rasters: dict) -> None:
    blocks = make_blocks(4, 25.0, 0.0, 510_000.0, 4_600_100.0)
    with pytest.raises(CoverageError, match="do not cover the track"):
        block_reference_values(block_corridors(blocks), dtm=rasters["dtm"],
                               dsm_max=rasters["dsm_max"], dsm_p90=rasters["dsm_p90"])


def test_different_grids_raise(rasters: dict, tmp_path: Path) -> None:
    shifted = write_tif(tmp_path / "shifted.tif", rasters["arrays"]["dsm_p90"], x0=X0 + 1.0)
    blocks = make_blocks(3, 25.0, 0.0, 500_020.0, 4_600_150.0)
    with pytest.raises(InputError, match="different grids"):
        block_reference_values(block_corridors(blocks), dtm=rasters["dtm"],
                               dsm_max=rasters["dsm_max"], dsm_p90=shifted)
    other_crs = write_tif(tmp_path / "crs.tif", rasters["arrays"]["dsm_p90"], crs="EPSG:32613")
    with pytest.raises(InputError, match="different grids"):
        block_reference_values(block_corridors(blocks), dtm=rasters["dtm"],
                               dsm_max=rasters["dsm_max"], dsm_p90=other_crs)


def test_missing_files_and_crs(rasters: dict, tmp_path: Path) -> None:
    blocks = make_blocks(3, 25.0, 0.0, 500_020.0, 4_600_150.0)
    cor = block_corridors(blocks)
    with pytest.raises(FileFormatError, match="no such file"):
        block_reference_values(cor, dtm=tmp_path / "nope.tif", dsm_max=rasters["dsm_max"],
                               dsm_p90=rasters["dsm_p90"])
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"II*\x00garbage")
    with pytest.raises(FileFormatError, match="cannot read"):
        block_reference_values(cor, dtm=junk, dsm_max=rasters["dsm_max"],
                               dsm_p90=rasters["dsm_p90"])
    with pytest.raises(CRSError, match="no CRS"):
        block_reference_values(cor.set_crs(None, allow_override=True), dtm=rasters["dtm"],
                               dsm_max=rasters["dsm_max"], dsm_p90=rasters["dsm_p90"])


def test_corridors_reprojected_to_raster_crs(rasters: dict) -> None:
    """Blocks in UTM 13N over rasters in UTM 12N: polygons are reprojected."""
    blocks12 = make_blocks(4, 20.0, -30.0, 500_030.0, 4_600_190.0)
    cor12 = block_corridors(blocks12)
    cor13 = cor12.to_crs(32613)
    ref = block_reference_values(cor13, dtm=rasters["dtm"], dsm_max=rasters["dsm_max"],
                                 dsm_p90=rasters["dsm_p90"])
    back = cor13.to_crs(32612)
    for i, poly in enumerate(back.geometry):
        bf = brute_force(poly, rasters["arrays"])
        assert ref["ref_top"].iloc[i] == pytest.approx(np.nanmax(bf["dsm_max"]), abs=1e-4)
        assert ref["ref_ground"].iloc[i] == pytest.approx(np.nanmean(bf["dtm"]), abs=1e-4)


@pytest.mark.slow
def test_speed_5000_blocks(tmp_path: Path) -> None:
    """5,000 blocks of 10 m along a 50 km track on a 2 m grid: measured, bounded."""
    n, L = 5000, 10.0
    rng = np.random.default_rng(7)
    arr = (300 + rng.normal(0, 1, (60, int(n * L / RES) + 20))).astype(np.float32)
    p = [write_tif(tmp_path / f"{k}.tif", arr + o) for k, o in (("g", 0), ("t", 20), ("n", 15))]
    blocks = make_blocks(n, L, -0.05, X0 + 10, Y0 - 30)  # slightly diagonal
    t0 = time.perf_counter()
    cor = block_corridors(blocks)
    t1 = time.perf_counter()
    ref = block_reference_values(cor, dtm=p[0], dsm_max=p[1], dsm_p90=p[2])
    t2 = time.perf_counter()
    print(f"corridors {t1 - t0:.2f} s, reference values {t2 - t1:.2f} s for {n} blocks")
    assert (ref["ref_flag"] == "ok").all()
    assert t2 - t0 < 60
