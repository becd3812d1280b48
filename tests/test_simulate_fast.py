"""The fast simulator paths against brute force and against each other.

Footprint search on the grid index (straight runs of shots and the general method), the
counting sort into shot order, the exact per-shot height searches, and the contract that
results do not depend on how the track is cut into chunks.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from canopyblocks.readers.las import LasPoints
from canopyblocks.reference import footprint_index as footprints
from canopyblocks.simulate import (
    RH_LEVELS,
    CloudIndex,
    FootprintPairs,
    SimParams,
    SimTrack,
    TruthParams,
    engine,
    footprint_truth,
    shots_along,
    simulate_photons,
)
from canopyblocks.simulate.truth import _HeightSearch

CRS = 32610
X0, Y0 = 500_000.0, 5_000_000.0


def random_cloud(n: int, size: float, seed: int, quantum: float | None = None):
    rng = np.random.default_rng(seed)
    x = X0 + rng.random(n) * size
    y = Y0 + rng.random(n) * size
    ground = 0.05 * (x - X0)
    canopy = rng.random(n) < 0.5
    z = ground + np.where(canopy, rng.random(n) * 25.0, rng.normal(0, 0.05, n))
    if quantum:  # LAS-like heights on a 1 cm grid: many equal heights
        z = np.round(z / quantum) * quantum
    return x, y, z


def brute_sorted_pairs(x, y, z, sx, sy, radius):
    """(shot, point) pairs with r <= R by brute force, ordered by shot, height, point."""
    d2 = (sx[:, None] - x[None, :]) ** 2 + (sy[:, None] - y[None, :]) ** 2
    shot, point = np.nonzero(d2 <= radius * radius)
    order = np.lexsort((point, z[point], shot))
    return shot[order], point[order], d2[shot[order], point[order]]


@pytest.mark.parametrize("azimuth", [0.0, 33.0, 90.0, 135.0, 251.0])
def test_straight_run_pairs_equal_brute_force_in_order(azimuth):
    x, y, z = random_cloud(6000, 70.0, 3, quantum=0.01)
    idx = CloudIndex(x, y, z)
    a = math.radians(azimuth)
    cx, cy = X0 + 35.0, Y0 + 35.0
    tr = SimTrack.line(cx - 25 * math.sin(a), cy - 25 * math.cos(a),
                       cx + 25 * math.sin(a), cy + 25 * math.cos(a))
    sx, sy, _ = shots_along(tr, 0.7)
    radius = 6.5
    pairs = idx.pairs(sx, sy, radius)
    assert pairs.height_sorted
    shot, point, d2 = brute_sorted_pairs(x, y, z, sx, sy, radius)
    assert np.array_equal(pairs.shot, shot)
    assert np.array_equal(pairs.point, point)  # same order: by shot, height, cloud order
    assert np.array_equal(pairs.z, z[point])
    assert np.allclose(pairs.weight, np.exp(-2 * d2 / radius ** 2), rtol=1e-9, atol=0)
    assert np.array_equal(pairs.indptr, np.concatenate([[0], np.cumsum(
        np.bincount(shot, minlength=sx.size))]))


def test_general_method_same_pairs_as_straight_run():
    x, y, z = random_cloud(4000, 60.0, 5, quantum=0.01)
    idx = CloudIndex(x, y, z)
    sx = X0 + np.linspace(10.0, 50.0, 40)
    sy = Y0 + np.linspace(12.0, 40.0, 40)
    line = idx.pairs(sx, sy, 6.5)
    # the same shots in another order are not a run along a line: general method
    perm = np.random.default_rng(0).permutation(sx.size)
    gen = idx.pairs(sx[perm], sy[perm], 6.5)
    inv = np.argsort(perm)
    for k in (0, 7, 39):
        a = slice(line.indptr[k], line.indptr[k + 1])
        j = inv[k]
        b = slice(gen.indptr[j], gen.indptr[j + 1])
        assert np.array_equal(line.point[a], gen.point[b])
        assert np.allclose(line.weight[a], gen.weight[b], rtol=1e-9)


def test_counting_sort_fallback_matches(monkeypatch):
    x, y, z = random_cloud(3000, 50.0, 9)
    idx = CloudIndex(x, y, z)
    sx, sy, _ = shots_along(SimTrack.line(X0 + 10, Y0 + 25, X0 + 40, Y0 + 25), 0.7)
    fast = idx.pairs(sx, sy, 6.5)
    monkeypatch.setattr(footprints, "_coo_tocsr", None)
    slow = idx.pairs(sx, sy, 6.5)
    assert np.array_equal(fast.indptr, slow.indptr)
    assert np.array_equal(fast.point, slow.point)
    assert np.array_equal(fast.weight, slow.weight)


def test_sorted_index_equals_searchsorted():
    rng = np.random.default_rng(1)
    edges = np.cumsum(np.full(200, 0.7)) + rng.normal(0, 1e-9, 200)
    edges.sort()
    t = np.concatenate([rng.uniform(-5, 150, 5000), edges, edges[:50] + 1e-12,
                        np.nextafter(edges[:50], -np.inf)])
    for right in (False, True):
        got = footprints._sorted_index(edges, t, right=right)
        assert np.array_equal(got, np.searchsorted(edges, t, side="right" if right else "left"))
    # uneven spacing still gives the exact answer
    uneven = np.sort(rng.uniform(0, 100, 50))
    assert np.array_equal(footprints._sorted_index(uneven, t, right=False),
                          np.searchsorted(uneven, t, side="left"))


def test_height_search_against_brute_force():
    rng = np.random.default_rng(2)
    counts = np.array([5, 0, 1, 40, 17])
    z = np.concatenate([np.sort(np.round(rng.uniform(100, 130, c), 2)) for c in counts])
    indptr = np.concatenate([[0], np.cumsum(counts)])
    has = counts > 0
    ids = np.flatnonzero(has)
    find = _HeightSearch(z, counts, ids, indptr[:-1][has], indptr[1:][has])
    g = np.array([110.0, 100.0, 120.0, 115.5])
    for t in (-1.25, 0.0, 0.5, 2.0, 1.25):
        for strict in (True, False):
            got = find.first(g, t, strict)
            for j, k in enumerate(ids):
                seg = z[indptr[k]:indptr[k + 1]] - g[j]
                hit = np.flatnonzero(seg > t if strict else seg >= t)
                assert got[j] == indptr[k] + (hit[0] if hit.size else seg.size)


def test_truth_of_unsorted_pairs_equals_sorted():
    x, y, z = random_cloud(3000, 40.0, 7)
    idx = CloudIndex(x, y, z)
    sx = X0 + np.array([10.0, 20.0, 30.0])
    sy = Y0 + np.array([20.0, 20.0, 20.0])
    p = idx.pairs(sx, sy, 6.5)
    shuffled = np.concatenate([p.indptr[k] + np.random.default_rng(k).permutation(c)
                               for k, c in enumerate(p.counts)])
    q = FootprintPairs(p.n_shots, p.shot[shuffled], p.point[shuffled], p.z[shuffled],
                       p.weight[shuffled], p.indptr)
    a = footprint_truth(p, 0.25, TruthParams(), 0.5)
    b = footprint_truth(q, 0.25, TruthParams(), 0.5)
    for col in a:
        assert np.allclose(a[col], b[col], rtol=0, atol=1e-9, equal_nan=True), col


def test_weighted_percentiles_with_tied_heights():
    """Quantised heights (many ties): RH is the inverse CDF, checked by brute force."""
    x, y, z = random_cloud(5000, 40.0, 11, quantum=0.5)
    idx = CloudIndex(x, y, z)
    sx, sy = X0 + np.array([15.0, 25.0]), Y0 + np.array([20.0, 20.0])
    p = idx.pairs(sx, sy, 6.5)
    t = footprint_truth(p, 0.25, TruthParams(), 0.5)
    for k in range(2):
        a = slice(p.indptr[k], p.indptr[k + 1])
        hag = p.z[a] - t["ground"][k]
        w = p.weight[a]
        can = hag > 0.5
        h, ww = hag[can], w[can]
        o = np.argsort(h, kind="stable")
        cum = np.cumsum(ww[o]) / ww.sum()
        for q in RH_LEVELS:
            assert t[f"rh{q}"][k] == h[o][np.argmax(cum >= q / 100 - 1e-12)]
        assert t["cover"][k] == np.mean(hag > 2.0)
        assert t["top"][k] == p.z[a].max()


@pytest.mark.parametrize("realisations, params", [
    (1, SimParams()),
    (3, SimParams(background_rate_mhz=7.5, geolocation_sigma=2.0)),
])
def test_results_do_not_depend_on_chunking(monkeypatch, realisations, params):
    x, y, z = random_cloud(20000, 120.0, 4, quantum=0.01)
    pts = LasPoints.from_arrays(x, y, z, crs=CRS)
    track = SimTrack(((X0 + 10, Y0 + 10), (X0 + 100, Y0 + 40), (X0 + 60, Y0 + 110)))
    runs = []
    for length in (7.0, 100.0, 1000.0):
        monkeypatch.setattr(engine, "CHUNK_LENGTH", length)
        runs.append(simulate_photons(pts, track, params, realisations=realisations, seed=3))
    a = runs[0]
    assert a.photons["h"].size > 100
    for b in runs[1:]:
        for col in a.truth:
            assert np.array_equal(a.truth[col], b.truth[col], equal_nan=True), col
        for col in a.photons:
            assert np.array_equal(a.photons[col], b.photons[col], equal_nan=True), col


def test_bent_track_truth_and_sources_against_brute_force():
    x, y, z = random_cloud(8000, 80.0, 6)
    pts = LasPoints.from_arrays(x, y, z, crs=CRS)
    track = SimTrack(((X0 + 10, Y0 + 10), (X0 + 60, Y0 + 30), (X0 + 40, Y0 + 70)))
    sim = simulate_photons(pts, track, realisations=5, seed=8)
    d2 = (sim.shot_x[:, None] - x[None, :]) ** 2 + (sim.shot_y[:, None] - y[None, :]) ** 2
    inside = d2 <= 6.5 ** 2
    assert np.array_equal(sim.truth["n_points"], inside.sum(axis=1))
    assert np.array_equal(sim.truth["top"], np.where(inside, z[None, :], -np.inf).max(axis=1))
    assert np.allclose(sim.truth["weight_sum"],
                       np.where(inside, np.exp(-2 * d2 / 6.5 ** 2), 0).sum(axis=1), rtol=1e-12)
    ph = sim.photons
    assert inside[ph["shot"], ph["src_index"]].all()  # every source lies in its footprint


def test_block_prefix_sums_against_cumsum():
    rng = np.random.default_rng(12)
    w = np.exp(-2 * rng.random(1003))  # footprint weights lie in [exp(-2), 1]
    cw = np.cumsum(w)
    blocks = footprints._Prefix(w)
    full = footprints._Prefix(w, cw)
    i = np.concatenate([[-1, 0, 15, 16, 17, 1002], rng.integers(-1, 1003, 500)])
    for p in (blocks, full):
        assert np.allclose(p.at(i), np.where(i >= 0, cw[np.maximum(i, 0)], 0.0),
                           rtol=1e-13, atol=0)
    t = np.concatenate([rng.uniform(-1, cw[-1] + 1, 2000), [0.0, cw[-1] * 2]])
    for right in (False, True):
        want = np.searchsorted(cw, t, side="right" if right else "left")
        assert np.array_equal(blocks.search(t, right), want)
        assert np.array_equal(full.search(t, right), want)
    # the pairs choose block sums for a few look-ups and a full cumsum for many
    pairs = FootprintPairs(1, None, np.arange(w.size), np.zeros(w.size), w,
                           np.array([0, w.size]))
    assert pairs.prefix(3).cw is None and pairs.prefix(10_000).cw is not None


@pytest.mark.parametrize("high", [50, 70_000, 2**40])
def test_radix_argsort_is_a_stable_argsort(high):
    keys = np.random.default_rng(13).integers(0, high, 20_000)
    assert np.array_equal(footprints._argsort_ranks(keys), np.argsort(keys, kind="stable"))
