"""Validation statistics against scipy.stats.linregress and hand computation."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from canopyblocks.errors import InputError
from canopyblocks.schema import STATS_COLUMNS
from canopyblocks.validation.stats import block_stats, error_stats


def test_error_stats_vs_linregress() -> None:
    rng = np.random.default_rng(42)
    ref = rng.uniform(2, 30, 200)
    photon = 0.8 * ref + 1.5 + rng.normal(0, 2, 200)
    st = error_stats(photon, ref)
    lr = sps.linregress(ref, photon)
    assert st["n"] == 200
    assert st["slope"] == pytest.approx(lr.slope, rel=1e-12)
    assert st["intercept"] == pytest.approx(lr.intercept, rel=1e-12)
    assert st["r2"] == pytest.approx(lr.rvalue**2, rel=1e-12)
    r = photon - ref
    assert st["bias"] == pytest.approx(r.sum() / 200, rel=1e-12)
    assert st["rmse"] == pytest.approx(np.sqrt((r**2).sum() / 200), rel=1e-12)
    assert st["mae"] == pytest.approx(np.abs(r).sum() / 200, rel=1e-12)


def test_hand_computed_small_case() -> None:
    # photon 2, 4, 7 vs reference 1, 3, 5: residuals 1, 1, 2
    st = error_stats(np.array([2.0, 4.0, 7.0, np.nan]), np.array([1.0, 3.0, 5.0, 9.0]))
    assert st["n"] == 3
    assert st["bias"] == pytest.approx(4 / 3)
    assert st["rmse"] == pytest.approx(np.sqrt(6 / 3))
    assert st["mae"] == pytest.approx(4 / 3)
    assert st["slope"] == pytest.approx(1.25)  # sxy 10 / sxx 8
    assert st["intercept"] == pytest.approx(13 / 3 - 1.25 * 3)
    assert st["r2"] == pytest.approx(900 / 912)  # sxy^2 / (sxx * syy), syy = 114 / 9


def test_small_n_and_degenerate() -> None:
    st = error_stats([1.0, 2.0], [1.5, 2.5])
    assert st["n"] == 2 and st["bias"] == pytest.approx(-0.5)
    assert np.isnan(st["slope"]) and np.isnan(st["r2"]) and np.isnan(st["intercept"])
    st = error_stats([1.0, 2.0, 3.0], [5.0, 5.0, 5.0])  # constant reference
    assert np.isnan(st["slope"]) and st["rmse"] == pytest.approx(np.sqrt((16 + 9 + 4) / 3))
    st = error_stats([], [], allow_empty=True)  # an empty group of a table
    assert st["n"] == 0 and np.isnan(st["bias"])
    with pytest.raises(InputError, match="empty"):  # an empty call from a user
        error_stats([], [])


def _residual_frame() -> pd.DataFrame:
    rng = np.random.default_rng(5)
    n = 60
    df = pd.DataFrame({
        "length": np.repeat([25.0, 10.0], n // 2),
        "aspect_class": rng.choice(["E", "NE", "flat"], n),
        "slope_class": rng.choice(["0-5", "5-10"], n),
        "use": rng.uniform(size=n) > 0.2,
    })
    for m in ("ground", "top", "hmax", "h90"):
        df[f"ref_{m}"] = rng.uniform(0, 30, n)
        df[m] = df[f"ref_{m}"] + rng.normal(0.5, 1, n)
    df.loc[3, "hmax"] = np.nan  # NaN-safe
    return df


def test_block_stats_groups() -> None:
    df = _residual_frame()
    st = block_stats(df)
    assert list(st.columns) == list(STATS_COLUMNS)
    assert set(st["length"]) == {10.0, 25.0}
    used = df[df["use"]]
    for length in (10.0, 25.0):
        for m in ("ground", "hmax"):
            rows = st[(st["length"] == length) & (st["metric"] == m)]
            assert rows["group"].iloc[0] == "all"
            sub = used[used["length"] == length]
            ok = sub[m].notna()
            r = (sub[m] - sub[f"ref_{m}"])[ok]
            all_row = rows[rows["group"] == "all"].iloc[0]
            assert all_row["n"] == ok.sum()
            assert all_row["bias"] == pytest.approx(r.mean())
            lr = sps.linregress(sub[f"ref_{m}"][ok], sub[m][ok])
            assert all_row["r2"] == pytest.approx(lr.rvalue**2)
            e = rows[rows["group"] == "aspect:E"].iloc[0]
            sub_e = sub[(sub["aspect_class"] == "E") & ok]
            assert e["n"] == len(sub_e)
            assert e["rmse"] == pytest.approx(np.sqrt(((sub_e[m] - sub_e[f"ref_{m}"])**2).mean()))
            assert set(rows["group"]) == {"all", "aspect:E", "aspect:NE", "aspect:flat",
                                          "slope:0-5", "slope:5-10"}
    # unused rows are excluded unless asked
    st_all = block_stats(df, only_used=False)
    n_all = st_all[(st_all["length"] == 25.0) & (st_all["metric"] == "top")
                   & (st_all["group"] == "all")]["n"].iloc[0]
    assert n_all == 30
    with pytest.raises(InputError, match="unknown metric"):
        block_stats(df, metrics=("z90x",))
