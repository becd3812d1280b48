"""The block table's and the per-block sigma features' one-pass paths over photons in
along-track order give the same bits as the general paths (sorts, searches, the paper's
engine) they stand in for: checked on random tracks, sorted and not, with ties, gaps and
windows that cut the track."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from pyproj import CRS

from canopyblocks.blocks import BlockParams, kernels
from canopyblocks.blocks.atl08_classify import Atl08Classes
from canopyblocks.blocks.engine import block_skeleton, compute_blocks
from canopyblocks.blocks.ground_surface import GroundSurface
from canopyblocks.blocks.grouped import percentile_by_group, percentiles_by_group
from canopyblocks.blocks.uncertainty_features import _interval_of, _step_tops, block_features
from canopyblocks.photons import PhotonTrack
from canopyblocks.readers.atl03_geolocation import GEOLOCATION_SIGMA_COLUMN

SKELETON = ["track", "length", "block", "s_start", "s_end", "x", "y", "lon", "lat",
            "n_photons"]


def _track(seed: int, n: int, gaps: bool) -> PhotonTrack:
    rng = np.random.default_rng(seed)
    s = np.sort(rng.random(n) * n / 7.0) + 1234.5
    if gaps:  # empty stretches: blocks missing from the table
        s[n // 3:] += 500.0
        s[2 * n // 3:] += 1e4
    s[5:9] = s[5]  # ties
    h = 300.0 + rng.normal(0.0, 5.0, n)
    x = 500_000.0 + s * 0.8 + rng.normal(0.0, 1.0, n)
    y = 4_000_000.0 + s * 0.6
    return PhotonTrack(time=s / 7000.0, lat=np.zeros(n), lon=np.zeros(n), h=h, x=x, y=y, s=s,
                       track="gt1l", crs=CRS.from_epsg(32613))


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("gaps", [False, True])
def test_skeleton_is_the_engines_rows(seed: int, gaps: bool) -> None:
    t = _track(seed, 20_000 + 997 * seed, gaps)
    p = BlockParams(lengths=(10.0, 25.0, 100.0, 7.3), s0=None if seed else 1300.25)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sparse blocks: none of this test's business
        full = compute_blocks(t, replace(p, noise="none"), window_photons=3_000)
    skel = block_skeleton(t, p)
    pd.testing.assert_frame_equal(pd.DataFrame(skel[SKELETON]), pd.DataFrame(full[SKELETON]),
                                  check_exact=True)
    assert skel.geometry.geom_equals_exact(full.geometry, 0.0).all()
    assert skel.dtypes.equals(full.dtypes)


@pytest.mark.parametrize("seed", [0, 1])
def test_interval_of_matches_the_search(seed: int) -> None:
    rng = np.random.default_rng(seed)
    s = np.sort(rng.random(5000) * 1000.0)
    s[100:110] = s[100]
    a = np.unique(np.r_[rng.random(40) * 1100.0 - 50.0, s[100], s[0], s[-1]])
    want = np.searchsorted(a, s, side="right") - 1
    assert np.array_equal(_interval_of(s, a), want)
    shuffled = rng.permutation(s)  # not in order: the search itself
    assert np.array_equal(_interval_of(shuffled, a),
                          np.searchsorted(a, shuffled, side="right") - 1)
    with_nan = np.r_[s, np.nan]
    assert np.array_equal(_interval_of(with_nan, a),
                          np.searchsorted(a, with_nan, side="right") - 1)


def _tops_by_sort(r: np.ndarray, k: np.ndarray, h: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    order = np.lexsort((h, k, r))
    r, k, h = r[order], k[order], h[order]
    last = np.ones(r.size, bool)
    last[:-1] = (r[1:] != r[:-1]) | (k[1:] != k[:-1])
    return r[last], k[last], h[last]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_step_tops_in_order_and_not(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 3000
    r = np.sort(rng.integers(0, 60, n))
    k = np.concatenate([np.sort(rng.integers(0, 5, np.count_nonzero(r == i)))
                        for i in range(60)])
    h = np.where(rng.random(n) < 0.3, 0.0, rng.random(n) * 30.0)
    h[rng.random(n) < 0.05] = 7.0  # ties
    for rr, kk, hh in ((r, k, h), (r[::-1].copy(), k, h)):  # in order, then not
        got, want = _step_tops(rr, kk, hh), _tops_by_sort(rr, kk, hh)
        for g, w in zip(got, want):
            assert g.dtype == w.dtype and np.array_equal(g, w)
    one = (np.array([3]), np.array([1]), np.array([2.5]))
    assert all(np.array_equal(g, w) for g, w in zip(_step_tops(*one), one))


def _classes(seed: int, n: int) -> tuple[PhotonTrack, Atl08Classes]:
    """A track with random classes (none, noise, ground, canopy, top), heights above a
    surface (some NaN), a background rate and a geolocation sigma (some unusable)."""
    rng = np.random.default_rng(seed)
    t = _track(seed, n, gaps=True)
    cls = rng.choice(np.array([-1, 0, 1, 2, 3], np.int8), n, p=[0.02, 0.3, 0.3, 0.2, 0.18])
    h = np.where(cls == 1, rng.normal(0.0, 0.4, n), rng.random(n) * 30.0 - 5.0)
    h[cls == 0] = rng.normal(0.0, 20.0, np.count_nonzero(cls == 0))
    h[rng.random(n) < 0.01] = np.nan
    geo = rng.random(n) * 5.0
    geo[rng.random(n) < 0.1] = np.nan
    geo[rng.random(n) < 0.05] = 0.0
    t.extra[GEOLOCATION_SIGMA_COLUMN] = geo
    nodes = np.linspace(t.s[0] - 1.0, t.s[-1] + 1.0, 50)
    surf = GroundSurface(nodes, 300.0 + np.sin(nodes / 50.0), np.ones(50, bool),
                         np.zeros(n, bool))
    return t, Atl08Classes(cls, h, surf, rng.random(n) * 1e-3, "estimated")


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("length", [10.0, 25.0, 100.0])
def test_feature_sums_compiled_and_numpy_agree(monkeypatch, seed: int, length: float) -> None:
    if kernels.compiled() is None:
        pytest.skip("numba not installed: only the numpy code runs")
    t, c = _classes(seed, 30_000)
    a = np.arange(t.s[0] - 3.0, t.s[-1], length)
    a = a[np.unique(np.searchsorted(a, t.s, side="right") - 1)]  # intervals with photons
    b = a + length * (0.7 if seed == 2 else 1.0)  # (seed 2: gaps between them)
    hmax = np.where(np.arange(a.size) % 7 == 0, np.nan, 12.0)
    if seed == 1:
        t.extra.pop(GEOLOCATION_SIGMA_COLUMN)
    out = {}
    for flag in ("0", "1"):
        monkeypatch.setenv("CANOPYBLOCKS_NUMBA", flag)
        out[flag] = block_features(t, c, a, b, hmax)
    for k, v in out["0"].items():
        assert v.dtype == out["1"][k].dtype and np.array_equal(
            v.view(np.int64), out["1"][k].view(np.int64)), k
    f = out["1"]
    assert f["n_all"].sum() > 0.5 * 0.98 * t.s.size and f["canopy_gradient"].max() > 0
    # one block by hand: the classes' counts and the ground photons' spread
    i = a.size // 2
    inb = (t.s >= a[i]) & (t.s < b[i]) & (c.classes >= 0)
    assert f["n_all"][i] == np.count_nonzero(inb)
    assert f["n_top"][i] == np.count_nonzero(inb & (c.classes == 3))
    gh = c.height[inb & (c.classes == 1)]
    assert np.isclose(f["ground_spread"][i], np.std(gh, ddof=1), rtol=1e-9, equal_nan=True)


@pytest.mark.parametrize("seed", [0, 1])
def test_percentiles_in_runs_compiled_and_numpy_agree(monkeypatch, seed: int) -> None:
    if kernels.compiled() is None:
        pytest.skip("numba not installed: only the numpy code runs")
    rng = np.random.default_rng(seed)
    group = np.sort(rng.integers(0, 400, 20_000))  # runs, some groups empty
    values = rng.random(20_000) * 30.0
    values[rng.random(20_000) < 0.02] = 7.5  # ties
    qs = (98.0, 90.0, 0.0, 100.0, 33.3)
    monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "0")
    want = percentiles_by_group(group, values, qs, 410)
    by_height = np.argsort(values, kind="stable")
    want_sorted = percentiles_by_group(group[by_height], values[by_height], qs, 410,
                                       values_sorted=True)
    monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "1")
    got = percentiles_by_group(group, values, qs, 410)
    for w in (want, want_sorted):
        assert np.array_equal(got.view(np.int64), w.view(np.int64))
    assert np.isnan(got[400:]).all()
    for q in qs:  # one percentile at a time, compiled and not
        one = percentile_by_group(group, values, q, 410)
        monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "0")
        assert np.array_equal(one.view(np.int64),
                              percentile_by_group(group, values, q, 410).view(np.int64))
        monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "1")
        assert np.array_equal(one.view(np.int64), got[:, qs.index(q)].view(np.int64))
    i = int(group[0])  # one group by numpy's own percentile
    assert np.array_equal(got[i], np.percentile(values[group == i], qs))
