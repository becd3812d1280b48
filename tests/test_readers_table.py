"""Plain-table reader: CSV and (Geo)Parquet with lon/lat/h or x/y/z + CRS."""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import pandas as pd
import pyproj
import pytest

from canopyblocks.errors import CRSError, FileFormatError, InputError, NoUsableDataError
from canopyblocks.readers import file_info, open_track, read_atl03, read_table

UTM17 = pyproj.CRS.from_epsg(32617)


def _track_df(n=500, seed=0):
    rng = np.random.default_rng(seed)
    s = np.sort(rng.uniform(0, 400, n))
    x = 370_000.0 + s * 0.6
    y = 3_280_000.0 + s * 0.8
    lon, lat = pyproj.Transformer.from_crs(UTM17, 4326, always_xy=True).transform(x, y)
    return pd.DataFrame({"time": s / 7000.0, "x": x, "y": y, "lon": lon, "lat": lat,
                         "h": 40 + rng.normal(0, 2, n), "s_true": s})


def test_csv_lonlat(tmp_path):
    df = _track_df()
    p = tmp_path / "photons.csv"
    df[["time", "lon", "lat", "h"]].to_csv(p, index=False, float_format="%.10f")
    tr = read_table(p)
    assert tr.track == "photons" and len(tr) == len(df)
    assert tr.crs.to_epsg() == 32617
    np.testing.assert_allclose(tr.x, df["x"], atol=1e-3)
    np.testing.assert_allclose(tr.s, df["s_true"] - df["s_true"].min(), atol=1e-3)
    assert tr.vertical_datum == "unknown"


def test_csv_xyz_needs_crs(tmp_path):
    df = _track_df().rename(columns={"h": "z"})
    p = tmp_path / "xyz.csv"
    df[["x", "y", "z"]].to_csv(p, index=False)
    with pytest.raises(CRSError, match=r"xyz\.csv: columns 'x'/'y' have no CRS; give crs="):
        read_table(p)
    tr = read_table(p, crs="EPSG:32617")
    assert tr.crs.to_epsg() == 32617
    np.testing.assert_allclose(np.sort(tr.x), np.sort(df["x"]), atol=1e-6)
    np.testing.assert_allclose(tr.h[np.argsort(tr.time)], df["z"], atol=1e-9)


def test_xy_in_feet_goes_to_utm(tmp_path):
    df = _track_df()
    ft = pyproj.CRS.from_epsg(2236)  # NAD83 / Florida East (ftUS)
    fx, fy = pyproj.Transformer.from_crs(UTM17, ft, always_xy=True).transform(df.x, df.y)
    p = tmp_path / "ft.csv"
    pd.DataFrame({"x": fx, "y": fy, "h": df.h}).to_csv(p, index=False)
    tr = read_table(p, crs=ft)
    assert tr.crs.to_epsg() == 32617
    np.testing.assert_allclose(np.sort(tr.x), np.sort(df.x), atol=0.01)


def test_geoparquet_carries_its_crs(tmp_path):
    df = _track_df()
    gdf = gpd.GeoDataFrame(df[["time", "h"]], geometry=gpd.points_from_xy(df.x, df.y),
                           crs=UTM17)
    p = tmp_path / "ph.parquet"
    gdf.to_parquet(p)
    tr = read_table(p)
    assert tr.crs.to_epsg() == 32617
    np.testing.assert_allclose(tr.x, df.x, atol=1e-6)


def test_photon_track_roundtrip_through_parquet(tmp_path, sample):
    src = read_atl03(sample("icesat2/vegr_atl03_clip.h5"), "gt1r")
    p = tmp_path / "gt1r.parquet"
    src.to_geodataframe().to_parquet(p)
    tr = read_table(p)
    assert tr.track == "gt1r" and len(tr) == len(src)
    for col in ("time", "lat", "lon", "h", "s", "signal_conf"):
        np.testing.assert_array_equal(getattr(tr, col), getattr(src, col))


def test_track_column_selection(tmp_path):
    a, b = _track_df(100, 1), _track_df(50, 2)
    df = pd.concat([a.assign(track="gt1l"), b.assign(track="gt1r")])
    p = tmp_path / "two.csv"
    df[["track", "lon", "lat", "h"]].to_csv(p, index=False)
    with pytest.raises(InputError, match=r"two\.csv: holds 2 tracks \(gt1l, gt1r\)"):
        read_table(p)
    tr = read_table(p, track="gt1r")
    assert tr.track == "gt1r" and len(tr) == 50
    with pytest.raises(InputError, match="no rows with track 'gt3r'"):
        read_table(p, track="gt3r")


def test_bbox_and_s_range_equal_posthoc(tmp_path):
    df = _track_df()
    p = tmp_path / "t.csv"
    df[["time", "lon", "lat", "h"]].to_csv(p, index=False, float_format="%.10f")
    full = read_table(p)
    lo = np.quantile(full.lon, [0.2, 0.5])
    sub = read_table(p, bbox=(lo[0], -90, lo[1], 90))
    m = (full.lon >= lo[0]) & (full.lon <= lo[1])
    np.testing.assert_array_equal(sub.s, full.s[m])
    sub = open_track(p, s_range=(100, 200))
    m = (full.s >= 100) & (full.s <= 200)
    np.testing.assert_array_equal(sub.h, full.h[m])


def test_bad_tables(tmp_path):
    p = tmp_path / "cols.csv"
    pd.DataFrame({"a": [1, 2], "b": [3, 4], "h": [1, 2]}).to_csv(p, index=False)
    with pytest.raises(FileFormatError, match=r"cols\.csv: needs columns 'lon'/'lat'.*columns "
                                              r"are a, b, h"):
        read_table(p)
    p2 = tmp_path / "noh.csv"
    pd.DataFrame({"lon": [1.0], "lat": [2.0]}).to_csv(p2, index=False)
    with pytest.raises(FileFormatError, match=r"noh\.csv: no height column 'h' or 'z'"):
        read_table(p2)
    p3 = tmp_path / "empty.csv"
    pd.DataFrame({"lon": [], "lat": [], "h": []}).to_csv(p3, index=False)
    with pytest.raises(NoUsableDataError, match=r"empty\.csv: the table has no rows"):
        read_table(p3)
    p4 = tmp_path / "text.csv"
    pd.DataFrame({"lon": ["a", "b"], "lat": [1, 2], "h": [1, 2]}).to_csv(p4, index=False)
    with pytest.raises(FileFormatError, match=r"text\.csv: column 'lon' is not numeric"):
        read_table(p4)
    p5 = tmp_path / "junk.parquet"
    p5.write_bytes(b"not parquet at all")
    with pytest.raises(FileFormatError, match=r"junk\.parquet: cannot read as Parquet"):
        read_table(p5)


def test_file_info_table(tmp_path):
    df = _track_df()
    p = tmp_path / "t.csv"
    df[["time", "lon", "lat", "h"]].to_csv(p, index=False, float_format="%.10f")
    info = file_info(p)
    assert info["product"] == "table" and info["n_photons"] == len(df)
    assert info["bbox"][1] == pytest.approx(df.lat.min())
