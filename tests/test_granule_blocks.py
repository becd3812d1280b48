"""`blocks` over several granules: one table with a granule column, the same blocks as
one granule at a time, filtered by time (UTC) and by a polygon (checked point by point)."""

from __future__ import annotations

import json
import shutil

import geopandas as gpd
import h5py
import numpy as np
import pytest
from shapely.geometry import Point, shape

CLIP = "icesat2/vegr_atl03_clip.h5"
YEAR = 365 * 86400.0


@pytest.fixture(scope="module")
def granules(sample, tmp_path_factory):
    """The real clip, and a copy of it taken a year later (delta_time + 365 days)."""
    d = tmp_path_factory.mktemp("granules")
    a, b = d / "ATL03_a.h5", d / "ATL03_b.h5"
    shutil.copy(sample(CLIP), a)
    shutil.copy(sample(CLIP), b)
    with h5py.File(b, "r+") as f:
        for beam in (k for k in f if k.startswith("gt")):
            f[f"{beam}/heights/delta_time"][...] = f[f"{beam}/heights/delta_time"][:] + YEAR
            if f"{beam}/bckgrd_atlas/delta_time" in f:  # the background rate too: a whole copy
                t = f[f"{beam}/bckgrd_atlas/delta_time"]
                t[...] = t[:] + YEAR
    return a, b


class _Run:
    def __init__(self, code: int, output: str) -> None:
        self.exit_code, self.output = code, output


@pytest.fixture
def _blocks(capsys):
    """``blocks`` as the terminal runs it (exit codes and one-line errors of main)."""
    from canopyblocks.cli import main

    def run(*args: str) -> _Run:
        code = main(["blocks", *args])
        cap = capsys.readouterr()
        return _Run(code, cap.out + cap.err)

    return run


def test_two_granules_one_table_the_same_blocks(granules, tmp_path, _blocks) -> None:
    a, b = granules
    one = _blocks(str(a), "--length", "25", "-o", str(tmp_path / "one.gpkg"))
    both = _blocks(str(a), str(b), "--length", "25", "-o", str(tmp_path / "both.gpkg"))
    assert one.exit_code == 0 and both.exit_code == 0, both.output
    t1 = gpd.read_file(tmp_path / "one.gpkg", layer="blocks")
    t2 = gpd.read_file(tmp_path / "both.gpkg", layer="blocks")
    assert t2.crs == t1.crs
    assert list(t2["granule"].value_counts().sort_index()) == [len(t1), len(t1)]
    for g in ("ATL03_a.h5", "ATL03_b.h5"):
        part = t2[t2["granule"] == g].reset_index(drop=True)
        for col in ("block", "n_photons", "top", "ground", "hmax"):
            np.testing.assert_array_equal(part[col].to_numpy(), t1[col].to_numpy(), col)


def test_time_filter_keeps_the_granules_taken_inside(granules, tmp_path, _blocks) -> None:
    a, b = granules
    with h5py.File(a, "r") as f:
        t0 = float(f["gt1r/heights/delta_time"][0])
    # the clip's first photon, in UTC, without this package: 2018-01-01 + delta_time
    day = (np.datetime64("2018-01-01") + np.timedelta64(int(t0), "s")).astype("datetime64[D]")
    later = day + np.timedelta64(365, "D")
    out = tmp_path / "t.parquet"
    r = _blocks(str(a), str(b), "--length", "25", "--time", str(later),
                str(later + np.timedelta64(1, "D")), "-o", str(out))
    assert r.exit_code == 0, r.output
    assert set(gpd.read_parquet(out)["granule"]) == {"ATL03_b.h5"}
    assert "1 of 2 granules taken outside the time range, skipped: ATL03_a.h5" in r.output
    r = _blocks(str(a), str(b), "--time", "2030-01-01", "2030-02-01", "-o", str(out))
    assert r.exit_code == 2 and "no block in the granules, area and time range" in r.output
    r = _blocks(str(a), "--time", "2022-13-45", "2030-02-01", "-o", str(out))
    assert r.exit_code == 2 and "--time START '2022-13-45'" in r.output


def test_polygon_keeps_the_blocks_whose_centre_is_inside(granules, tmp_path, _blocks) -> None:
    a, _ = granules
    all_ = _blocks(str(a), "--length", "25", "-o", str(tmp_path / "all.gpkg"))
    assert all_.exit_code == 0, all_.output
    t = gpd.read_file(tmp_path / "all.gpkg", layer="blocks")
    lat_mid = float(np.median(t["lat"]))
    lon0, lon1 = float(t["lon"].min()) - 0.01, float(t["lon"].max()) + 0.01
    ring = [[lon0, lat_mid], [lon1, lat_mid], [lon1, lat_mid + 0.05], [lon0, lat_mid + 0.05],
            [lon0, lat_mid]]
    gj = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {},
          "geometry": {"type": "Polygon", "coordinates": [ring]}}]}
    (tmp_path / "north.geojson").write_text(json.dumps(gj))
    r = _blocks(str(a), "--length", "25", "--polygon", str(tmp_path / "north.geojson"),
                "-o", str(tmp_path / "north.gpkg"))
    assert r.exit_code == 0, r.output
    kept = gpd.read_file(tmp_path / "north.gpkg", layer="blocks")
    poly = shape(gj["features"][0]["geometry"])
    expect = {int(row.block) for row in t.itertuples() if poly.contains(Point(row.lon, row.lat))}
    assert 0 < len(expect) < len(t)
    assert set(kept["block"].astype(int)) == expect
    # the same blocks as without the polygon (edges and values), not a re-blocked subset
    same = t.set_index("block").loc[sorted(expect)]
    k = kept.set_index(kept["block"].astype(int)).loc[sorted(expect)]
    np.testing.assert_array_equal(k["s_start"].to_numpy(), same["s_start"].to_numpy())
    np.testing.assert_array_equal(k["hmax"].to_numpy(), same["hmax"].to_numpy())


def test_one_file_options_are_refused_with_several(granules, tmp_path, _blocks) -> None:
    a, b = granules
    r = _blocks(str(a), str(b), "--photon-layer", "-o", str(tmp_path / "x.gpkg"))
    assert r.exit_code == 2 and "--photon-layer: one PATH at a time" in r.output
