"""Tables written by older versions are upgraded once, where they are read: a block table
without error bars or ``use`` reads with NaN sigmas and ``use`` = flag ok; ``use`` stored
as 0/1/NULL reads as a bool; the residuals of an old table use the blocks it would use."""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest

from canopyblocks.blocks.uncertainty import upgrade_table
from canopyblocks.outputs.tables import read_blocks, read_layer, write_table


def _old_blocks() -> gpd.GeoDataFrame:
    x = np.array([500000.0, 500025.0, 500050.0, 500075.0])
    return gpd.GeoDataFrame({
        "track": "gt1r", "length": 25.0, "block": np.arange(4), "x": x, "y": 5.0e6,
        "top": [30.0, 31.0, 29.0, 200.0], "ground": 10.0, "hmax": [20.0, 21.0, 19.0, 190.0],
        "h90": 15.0, "flag": ["ok", "sparse", "ok", "implausible"]},
        geometry=gpd.points_from_xy(x, np.full(4, 5.0e6)), crs="EPSG:32612")


@pytest.mark.parametrize("suffix", [".gpkg", ".parquet", ".csv"])
def test_an_old_block_table_reads_in_todays_form(tmp_path, suffix) -> None:
    path = tmp_path / f"old{suffix}"
    write_table(_old_blocks(), path, layer="blocks")
    t = read_blocks(path)
    assert t["use"].dtype == bool
    assert t["use"].tolist() == [True, False, True, False]  # the flag's ok, by hand
    assert np.isnan(t["hmax_sigma"]).all() and np.isnan(t["ground_sigma"]).all()


def test_use_stored_as_numbers_or_null_reads_as_a_bool(tmp_path) -> None:
    t = pd.DataFrame({"flag": ["ok", "ok", "ok"], "ref_flag": "ok", "hmax": 1.0,
                      "use": [1.0, 0.0, np.nan]})
    assert upgrade_table(t)["use"].tolist() == [True, False, False]
    path = tmp_path / "r.csv"
    t.drop(columns="use").assign(ref_flag=["ok", "missing", "ok"]).to_csv(path, index=False)
    # a residuals table without use: the block's flag and a usable reference
    assert read_layer(path)["use"].tolist() == [True, False, True]


def test_a_table_without_flags_is_left_alone() -> None:
    stats = pd.DataFrame({"metric": ["hmax"], "rmse": [1.0]})
    assert list(upgrade_table(stats.copy()).columns) == ["metric", "rmse"]


def test_residuals_of_an_old_table_use_what_it_would_use() -> None:
    from canopyblocks.validation.residuals import compute_residuals

    blocks = _old_blocks()
    ref = pd.DataFrame({"track": "gt1r", "length": 25.0, "block": np.arange(4),
                        "ref_ground": 10.0, "ref_top": 30.0, "ref_top90": 28.0,
                        "ref_hmax": 20.0, "ref_h90": 15.0, "ref_flag": "ok"})
    res = compute_residuals(blocks, ref, None)
    assert res["use"].tolist() == [True, False, True, False]
    assert np.isnan(res["hmax_sigma"]).all()
