"""``process_waveforms`` returns a GeoDataFrame, as the photon API's block tables.

Reference: the GEDI L2A product of the same shots (tests/data/gedi), read here with h5py:
its ``lon_lowestmode_a1`` / ``lat_lowestmode_a1`` (the position of the ground mode) projected
with pyproj, and ``elev_lowestmode_a1``; the UTM zone from the zone formula on L2A's
longitudes. Shots are joined by the exact uint64 ``shot_number``; only shots that L2A's
``quality_flag`` and our flag both call good are compared.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import geopandas as gpd
import h5py
import numpy as np
import pandas as pd
import pyproj
import pytest

from canopyblocks.errors import CRSError
from canopyblocks.readers.gedi import read_gedi_l1b
from canopyblocks.waveforms.process import _footprint_table, process_waveforms

BEAMS = ("BEAM0001", "BEAM0101", "BEAM1011")


def _l2a(path: Path, beam: str) -> dict[str, np.ndarray]:
    with h5py.File(path, "r") as f:
        b = f[beam]
        geo = b["geolocation"]
        return {"shot_number": b["shot_number"][:], "quality_flag": b["quality_flag"][:],
                "lon": geo["lon_lowestmode_a1"][:].astype(np.float64),
                "lat": geo["lat_lowestmode_a1"][:].astype(np.float64),
                "ground": geo["elev_lowestmode_a1"][:].astype(np.float64)}


def _matched(gdf: gpd.GeoDataFrame, ref: dict[str, np.ndarray]
             ) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``gdf`` and of ``ref`` for the same good shots."""
    pos = {int(s): i for i, s in enumerate(ref["shot_number"])}
    ours = gdf["shot_number"].to_numpy().astype(np.uint64)
    theirs = np.array([pos.get(int(s), -1) for s in ours])
    good = (theirs >= 0) & (gdf["flag"].to_numpy() == "ok")
    good &= ref["quality_flag"][np.maximum(theirs, 0)] == 1
    return np.nonzero(good)[0], theirs[good]


@pytest.mark.parametrize("beam", BEAMS)
def test_points_at_l2a_ground_positions_in_the_utm_zone(gedi_l1b: Path, gedi_l2a: Path,
                                                         beam: str) -> None:
    gdf = process_waveforms(read_gedi_l1b(gedi_l1b, beam))
    ref = _l2a(gedi_l2a, beam)
    assert isinstance(gdf, gpd.GeoDataFrame) and gdf.geometry.name == "geometry"
    zone = int(np.floor((np.median(ref["lon"]) + 180.0) / 6.0)) + 1
    south = np.median(ref["lat"]) < 0
    assert gdf.crs == pyproj.CRS.from_epsg((32700 if south else 32600) + zone)  # 32723
    ours, theirs = _matched(gdf, ref)
    assert len(ours) >= 10
    x, y = pyproj.Transformer.from_crs("EPSG:4326", gdf.crs, always_xy=True).transform(
        ref["lon"][theirs], ref["lat"][theirs])
    geom = gdf.geometry.iloc[ours]
    assert geom.has_z.all()
    np.testing.assert_allclose(geom.x, x, atol=0.01)   # metres
    np.testing.assert_allclose(geom.y, y, atol=0.01)
    np.testing.assert_allclose(geom.z, ref["ground"][theirs], atol=0.10)


def test_given_crs_and_a_geographic_crs_refused(gedi_l1b: Path, gedi_l2a: Path) -> None:
    batch = read_gedi_l1b(gedi_l1b, "BEAM0101")
    gdf = process_waveforms(batch, crs="EPSG:31983")          # SIRGAS 2000 / UTM 23S
    assert gdf.crs == pyproj.CRS.from_epsg(31983)
    ref = _l2a(gedi_l2a, "BEAM0101")
    ours, theirs = _matched(gdf, ref)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:31983", always_xy=True).transform(
        ref["lon"][theirs], ref["lat"][theirs])
    np.testing.assert_allclose(gdf.geometry.iloc[ours].x, x, atol=0.01)
    np.testing.assert_allclose(gdf.geometry.iloc[ours].y, y, atol=0.01)
    with pytest.raises(CRSError, match="not projected"):
        process_waveforms(batch, crs="EPSG:4326")


def test_columns_those_of_the_file_layer_path(gedi_l1b: Path) -> None:
    batch = read_gedi_l1b(gedi_l1b, "BEAM0101")
    pd.testing.assert_frame_equal(
        pd.DataFrame(process_waveforms(batch).drop(columns="geometry")),
        _footprint_table(batch))


def test_shots_without_a_position_get_empty_points(gedi_l1b: Path) -> None:
    batch = read_gedi_l1b(gedi_l1b, "BEAM0101")
    whole = process_waveforms(batch)
    lost = np.zeros(len(batch), dtype=bool)
    lost[[0, 5, 6]] = True
    lat0 = np.where(lost, np.nan, batch.lat_bin0)
    holed = process_waveforms(replace(batch, lat_bin0=lat0), crs=whole.crs)
    assert holed.geometry[lost].is_empty.all()
    assert not holed.geometry[~lost].is_empty.any()
    assert holed.geometry[~lost].geom_equals_exact(whole.geometry[~lost], 0.0).all()
    pd.testing.assert_frame_equal(holed.drop(columns=["geometry", "lat", "lon"]),
                                  whole.drop(columns=["geometry", "lat", "lon"]))
    none = process_waveforms(replace(batch, lon_bin0=np.full(len(batch), np.nan)))
    assert none.geometry.is_empty.all() and none.crs is None
    assert len(process_waveforms(batch.subset(np.array([], dtype=np.intp)))) == 0
