"""Photon schema, CRS helpers, atomic writes, tables, progress, package hygiene."""

from __future__ import annotations

import subprocess
import sys
import warnings

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely

import canopyblocks as cb
from canopyblocks.atomic import atomic_output
from canopyblocks.errors import CancelledError, CRSError, FileFormatError, InputError
from canopyblocks.geo import as_crs, from_metric, require_metric_crs, to_metric, utm_crs_for
from canopyblocks.photons import PhotonTrack, along_track_distance
from canopyblocks.progress import Progress


# ----------------------------------------------------------------------------- geo
@pytest.mark.parametrize(
    ("lon", "lat", "epsg"),
    [(-106.57, 41.53, 32613), (-122.0, 37.0, 32610), (0.5, 51.0, 32631), (-179.9, -10.0, 32701),
     (179.9, 10.0, 32660), (36.8, -1.3, 32737), (-60.0, 87.0, 3413), (10.0, -85.0, 3031)],
)
def test_utm_zone_known_values(lon: float, lat: float, epsg: int) -> None:
    assert utm_crs_for(np.array([lon]), np.array([lat])).to_epsg() == epsg


def test_single_point_projection_round_trips() -> None:
    x, y, crs = to_metric(np.array([-106.5]), np.array([41.5]))
    lon, lat = from_metric(x, y, crs)
    assert x.shape == (1,) and lon[0] == pytest.approx(-106.5) and lat[0] == pytest.approx(41.5)


def test_require_metric_crs_rejects_geographic_and_feet() -> None:
    with pytest.raises(CRSError, match="not projected"):
        require_metric_crs(as_crs(4326))
    with pytest.raises(CRSError, match="not metres"):
        require_metric_crs(as_crs(2263))  # NAD83 / New York Long Island (ftUS)
    assert require_metric_crs(as_crs("EPSG:3005")).to_epsg() == 3005
    with pytest.raises(CRSError, match="missing"):
        as_crs(None)
    with pytest.raises(CRSError, match="not a CRS"):
        as_crs("EPSG:nonsense")


def test_projection_round_trip_and_scale() -> None:
    lon = np.array([-106.571, -106.571])
    lat = np.array([41.532, 41.533])  # 0.001 degree of latitude ~ 111.07 m here
    x, y, crs = to_metric(lon, lat)
    assert crs.to_epsg() == 32613
    assert np.hypot(x[1] - x[0], y[1] - y[0]) == pytest.approx(111.07, abs=0.2)
    lon2, lat2 = from_metric(x, y, crs)
    np.testing.assert_allclose(lon2, lon, atol=1e-9)
    np.testing.assert_allclose(lat2, lat, atol=1e-9)


# -------------------------------------------------------------------------- photons
def test_along_track_distance_of_a_scattered_straight_line() -> None:
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 100, 2000))
    true_s = 7.0 * t  # 7 m/s along a 30-degree heading
    ang = np.deg2rad(30.0)
    across = rng.normal(0, 1.0, t.size)  # ~2 m footprint scatter
    x = 500.0 + true_s * np.cos(ang) - across * np.sin(ang)
    y = 900.0 + true_s * np.sin(ang) + across * np.cos(ang)
    s, off = along_track_distance(x, y, t)
    # independent truth: s = distance along the known direction from the first photon
    np.testing.assert_allclose(s - s[0], true_s - true_s[0], atol=0.05)
    assert np.std(off) == pytest.approx(1.0, rel=0.1)
    # reversed time: s still grows with time
    s2, _ = along_track_distance(x[::-1], y[::-1], t)
    assert np.corrcoef(t, s2)[0, 1] > 0.99


def test_photon_track_from_lonlat_sorts_and_projects() -> None:
    lat = np.array([41.533, 41.532, 41.5325])
    lon = np.full(3, -106.571)
    tr = PhotonTrack.from_lonlat(np.array([2.0, 0.0, 1.0]), lat, lon, np.array([3.0, 1.0, 2.0]),
                                 track="gt1r")
    assert tr.crs.to_epsg() == 32613
    np.testing.assert_array_equal(tr.time, [0.0, 1.0, 2.0])
    np.testing.assert_array_equal(tr.h, [1.0, 2.0, 3.0])
    assert tr.s[0] == 0.0 and tr.s[-1] == pytest.approx(111.07, abs=0.2)
    gdf = tr.to_geodataframe()
    assert isinstance(gdf, gpd.GeoDataFrame) and gdf.crs.to_epsg() == 32613
    assert list(gdf.columns[:3]) == ["track", "time", "lat"]
    assert len(tr.subset(tr.h > 1.5)) == 2


def test_validate_drops_nan_photons_with_a_warning() -> None:
    tr = PhotonTrack.from_xy(np.arange(5.0), np.zeros(5), np.array([1, np.nan, 3, 4, 5.0]),
                             crs=32613)
    with pytest.warns(cb.CanopyBlocksWarning, match="dropped 1 of 5"):
        v = tr.validate()
    assert len(v) == 4 and np.isfinite(v.h).all()
    bad = PhotonTrack.from_xy(np.arange(3.0), np.zeros(3), np.zeros(3), crs=32613)
    bad.h = np.zeros(4)
    with pytest.raises(InputError, match="shape"):
        bad.validate()
    with pytest.raises(CRSError, match="not projected"):
        PhotonTrack.from_xy(np.arange(3.0), np.zeros(3), np.zeros(3), crs=4326)


# --------------------------------------------------------------------------- atomic
def test_atomic_output_leaves_nothing_on_failure(tmp_path) -> None:
    target = tmp_path / "sub" / "out.csv"
    with pytest.raises(CancelledError):
        with atomic_output(target) as tmp:
            tmp.write_text("half")
            raise CancelledError("stop")
    assert not target.exists()
    assert list((tmp_path / "sub").iterdir()) == []
    with atomic_output(target) as tmp:
        tmp.write_text("whole")
    assert target.read_text() == "whole"
    assert [p.name for p in (tmp_path / "sub").iterdir()] == ["out.csv"]


def test_progress_sub_ranges_and_cancel() -> None:
    seen: list[float] = []
    p = Progress(callback=lambda f, m: seen.append(round(f, 6)))
    p.sub(0.5, 1.0).update(0.5)
    p.sub(0.0, 0.5).sub(0.0, 0.5).update(1.0)
    assert seen == [0.75, 0.25]
    flag = {"stop": False}
    q = Progress(cancelled=lambda: flag["stop"])
    q.update(0.1)
    flag["stop"] = True
    with pytest.raises(CancelledError):
        q.sub(0, 0.5).update(0.2)


# --------------------------------------------------------------------------- tables
def _toy_blocks() -> gpd.GeoDataFrame:
    df = pd.DataFrame({"track": ["gt1r", "gt1r"], "length": [25.0, 25.0], "block": [0, 1],
                       "top": [20.5, np.nan], "flag": ["ok", "sparse"]})
    return gpd.GeoDataFrame(df, geometry=shapely.points([0.0, 25.0], [0.0, 0.0]), crs=32613)


@pytest.mark.parametrize("suffix", [".gpkg", ".parquet", ".csv"])
def test_write_and_read_tables(tmp_path, suffix: str) -> None:
    out = tmp_path / f"b{suffix}"
    cb.write_table(_toy_blocks(), out)
    back = cb.read_layer(out, "blocks" if suffix == ".gpkg" else None)
    assert list(back["block"]) == [0, 1]
    assert back["top"].iloc[0] == pytest.approx(20.5)
    assert np.isnan(back["top"].iloc[1])
    if suffix != ".csv":
        assert back.crs.to_epsg() == 32613


def test_gpkg_append_keeps_other_layers_and_stats_table(tmp_path) -> None:
    out = tmp_path / "v.gpkg"
    cb.write_table(_toy_blocks(), out)
    stats = pd.DataFrame({"length": [25.0], "metric": ["hmax"], "n": [3]})
    cb.write_table(stats, out, layer="stats", append=True)
    import pyogrio

    assert {n for n, _ in pyogrio.list_layers(out)} == {"blocks", "stats"}
    assert cb.read_layer(out, "stats")["metric"].tolist() == ["hmax"]
    with pytest.raises(FileFormatError, match="no layer 'residuals'"):
        cb.read_layer(out, "residuals")


def test_bad_table_paths(tmp_path) -> None:
    with pytest.raises(InputError, match="unknown suffix '.shp'"):
        cb.write_table(_toy_blocks(), tmp_path / "x.shp")
    with pytest.raises(FileFormatError, match="no such file"):
        cb.read_layer(tmp_path / "missing.gpkg")
    junk = tmp_path / "junk.gpkg"
    junk.write_bytes(b"not a geopackage" * 10)
    with pytest.raises(FileFormatError, match="cannot read"):
        cb.read_layer(junk)


# ------------------------------------------------------------------------- package
def test_core_imports_no_qgis_and_logs_silently() -> None:
    code = (
        "import sys, canopyblocks, canopyblocks.workflows.blocks, canopyblocks.cli;"
        "bad=[m for m in sys.modules if m == 'qgis' or m.startswith('qgis.')];"
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    import logging

    handlers = logging.getLogger("canopyblocks").handlers
    assert any(isinstance(h, logging.NullHandler) for h in handlers)


def test_errors_have_builtin_parents() -> None:
    assert issubclass(cb.InputError, ValueError)
    assert issubclass(cb.FileFormatError, OSError)
    assert issubclass(cb.DependencyError, ImportError)
    assert issubclass(cb.SparseBlockWarning, UserWarning)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(cb.SparseBlockWarning):
            warnings.warn("x", cb.SparseBlockWarning, stacklevel=1)
