"""Columns sorted window by window (photon_order.py) == numpy's global stable argsort."""

from __future__ import annotations

import numpy as np
import pytest

from canopyblocks.readers.photon_order import order_windows, sort_columns_in_windows


def _shots(rng: np.random.Generator, n: int) -> np.ndarray:
    """Real ATL03 order: shots 0.7 m apart in time order, the photons of a shot (heights
    in time order) spread along-track by ~0.1 m (tests/data's Wyoming clip: 4,776 of
    6,809 photons out of order, none by more than 24 places)."""
    shot = np.sort(rng.integers(0, max(1, n // 8), n))
    return shot * 0.7 + rng.uniform(-0.1, 0.1, n)


def _keys(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    base = np.sort(rng.random(n)) * (n / 15.0)
    ties = np.round(base + rng.uniform(-1.5, 1.5, n), 1)  # many equal values
    with_nan = base + rng.uniform(-1, 1, n)
    with_inf = base.copy()
    if n:
        with_nan[rng.integers(0, n, 3)] = np.nan
        with_inf[n // 3] = np.inf
        with_inf[n // 2] = -np.inf
    return {
        "sorted": base,
        "shots": _shots(rng, n),
        "local_1m": base + rng.uniform(-1.0, 1.0, n),          # real ATL03
        "local_50m": base + rng.normal(0.0, 50.0, n),
        "ties": ties,
        "nan": with_nan,
        "inf": with_inf,
        "reversed": base[::-1].copy(),
        "constant": np.full(n, 7.0),
        "one_far": np.r_[base[1:], -1.0][:n],                  # no cut anywhere
        "integers": rng.integers(0, 50, max(n, 1)).astype(np.float64)[:n],
    }


@pytest.mark.parametrize("window", [1, 2, 7, 64, 1000, 1 << 16])
@pytest.mark.parametrize("n", [0, 1, 2, 5, 3001])
def test_windows_equal_global_stable_sort(n, window):
    rng = np.random.default_rng(n * 31 + window)
    for name, key in _keys(rng, n).items():
        order = np.argsort(key, kind="stable")
        cols = {"s": key.copy(), "i": np.arange(n), "f32": rng.random(n).astype(np.float32),
                "conf": rng.integers(-2, 5, (n, 5)).astype(np.int8)}
        expect = {k: v[order] for k, v in cols.items()}
        sort_columns_in_windows(cols, "s", window=window)
        for k in cols:
            np.testing.assert_array_equal(cols[k], expect[k], err_msg=f"{name} {k} w={window}")


def test_cuts_separate_nothing_a_sort_would_exchange():
    rng = np.random.default_rng(5)
    key = _shots(rng, 20_000)
    assert np.count_nonzero(np.diff(key) < 0) > 5_000
    cuts = order_windows(key, window=500)
    assert cuts[0] == 0 and cuts[-1] == key.size and np.all(np.diff(cuts) > 0)
    assert cuts.size == 41 and np.diff(cuts).max() < 520  # a cut just after each multiple
    for c in cuts[1:-1]:
        assert key[:c].max() <= key[c:].min()
    # no cut when one value belongs at the other end
    assert order_windows(np.r_[np.arange(5000.0), -1.0], window=100).tolist() == [0, 5001]


def test_in_order_untouched():
    cols = {"s": np.arange(10.0), "v": np.arange(10)}
    ids = {k: id(v) for k, v in cols.items()}
    assert sort_columns_in_windows(cols, "s") is False
    assert {k: id(v) for k, v in cols.items()} == ids
