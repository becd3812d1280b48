"""Footprints, tracks and truth metrics of the simulator against brute force."""

from __future__ import annotations

import math

import numpy as np
import pytest

from canopyblocks.errors import InputError, NoUsableDataError
from canopyblocks.readers.las import LasPoints
from canopyblocks.simulate import (
    RH_LEVELS,
    CloudIndex,
    SimParams,
    SimTrack,
    TruthParams,
    footprint_truth,
    line_through,
    shots_along,
    simulate_photons,
)

CRS = 32610
X0, Y0 = 500_000.0, 5_000_000.0


def random_cloud(n: int, size: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = X0 + rng.random(n) * size
    y = Y0 + rng.random(n) * size
    ground = 0.05 * (x - X0)  # a 5 % slope
    canopy = rng.random(n) < 0.5
    z = ground + np.where(canopy, rng.random(n) * 25.0, rng.normal(0, 0.05, n))
    return x, y, z


def brute_pairs(x, y, sx, sy, radius):
    d2 = (sx[:, None] - x[None, :]) ** 2 + (sy[:, None] - y[None, :]) ** 2
    return d2 <= radius * radius, d2


# ----------------------------------------------------------------------------- tracks
def test_shots_along_polyline_spacing():
    tr = SimTrack(((0.0, 0.0), (30.0, 0.0), (30.0, 40.0)))
    x, y, s = shots_along(tr, 0.7)
    assert tr.length == 70.0
    assert s.size == math.floor(70.0 / 0.7 + 1e-9) + 1
    assert np.allclose(np.diff(s), 0.7)
    # positions are at distance s along the polyline
    on_first = s <= 30.0
    assert np.allclose(x[on_first], s[on_first]) and np.allclose(y[on_first], 0.0)
    assert np.allclose(x[~on_first], 30.0) and np.allclose(y[~on_first], s[~on_first] - 30.0)


@pytest.mark.parametrize("azimuth, expected", [
    (0.0, ((50.0, 10.0), (50.0, 190.0))),      # northward through the centre
    (90.0, ((10.0, 100.0), (90.0, 100.0))),    # eastward
    (180.0, ((50.0, 190.0), (50.0, 10.0))),    # southward: starts in the north
])
def test_line_through_azimuth(azimuth, expected):
    tr = line_through((0.0, 0.0, 100.0, 200.0), azimuth, inset=10.0)
    assert np.allclose(tr.vertices, expected, atol=1e-9)


def test_line_through_diagonal_clipped():
    tr = line_through((0.0, 0.0, 100.0, 100.0), 45.0)
    assert np.allclose(tr.vertices, ((0.0, 0.0), (100.0, 100.0)))
    assert tr.length == pytest.approx(100 * math.sqrt(2))
    with pytest.raises(NoUsableDataError, match="smaller than twice the inset"):
        line_through((0.0, 0.0, 10.0, 10.0), 0.0, inset=6.0)
    with pytest.raises(InputError, match="two different end points"):
        SimTrack.line(1.0, 1.0, 1.0, 1.0)


# ------------------------------------------------------------------------- footprints
def test_pairs_match_brute_force_on_bent_track():
    x, y, z = random_cloud(4000, 60.0, 1)
    idx = CloudIndex(x, y, z)
    tr = SimTrack(((X0 + 5, Y0 + 5), (X0 + 40, Y0 + 20), (X0 + 30, Y0 + 55)))
    sx, sy, _ = shots_along(tr, 0.7)
    radius = 6.5
    pairs = idx.pairs(sx, sy, radius)
    inside, d2 = brute_pairs(x, y, sx, sy, radius)
    got = np.zeros_like(inside)
    got[pairs.shot, pairs.point] = True
    assert np.array_equal(got, inside)
    assert pairs.point.size == inside.sum()  # no duplicates
    assert np.all(np.diff(pairs.shot) >= 0)
    assert np.allclose(pairs.weight, np.exp(-2 * d2[pairs.shot, pairs.point] / radius ** 2))
    assert np.array_equal(np.diff(pairs.indptr), inside.sum(axis=1))


# ------------------------------------------------------------------------------ truth
def _brute_truth(z, w, psf, tp, rh_floor, ground_for_rh=None):
    """Independent truth of one footprint: fine-grid KDE, sorting, counting.

    RH and cover are computed relative to ``ground_for_rh`` when given (so they are
    checked exactly, apart from the ground's own grid resolution)."""
    grid = np.arange(z.min() - 2, z.max() + 2, 0.0005)
    f = (w[None, :] * np.exp(-0.5 * ((grid[:, None] - z[None, :]) / psf) ** 2)).sum(axis=1)
    peaks = np.flatnonzero((f[1:-1] > f[:-2]) & (f[1:-1] >= f[2:])
                           & (f[1:-1] >= tp.peak_fraction * f.max())) + 1
    ground = grid[peaks[0]]
    hag = z - (ground if ground_for_rh is None else ground_for_rh)
    canopy = hag > rh_floor
    h, ww = hag[canopy], w[canopy]
    order = np.argsort(h)
    h, ww = h[order], ww[order]
    cum = np.cumsum(ww) / ww.sum()
    rh = {q: float(h[np.argmax(cum >= q / 100 - 1e-12)]) if h.size else 0.0 for q in RH_LEVELS}
    cover = float(np.mean(hag > tp.cover_threshold))
    return ground, float(z.max()), rh, cover


def test_truth_against_brute_force():
    x, y, z = random_cloud(3000, 40.0, 7)
    idx = CloudIndex(x, y, z)
    sx = X0 + np.array([10.0, 20.0, 30.0, 12.5])
    sy = Y0 + np.array([10.0, 22.0, 28.0, 30.0])
    radius, psf, tp = 6.5, 0.25, TruthParams()
    pairs = idx.pairs(sx, sy, radius)
    got = footprint_truth(pairs, psf, tp, rh_floor=0.5)
    inside, d2 = brute_pairs(x, y, sx, sy, radius)
    for k in range(sx.size):
        m = inside[k]
        w = np.exp(-2 * d2[k, m] / radius ** 2)
        ground, top, rh, cover = _brute_truth(z[m], w, psf, tp, 0.5, got["ground"][k])
        assert got["ground"][k] == pytest.approx(ground, abs=0.002)
        assert got["top"][k] == top
        assert got["cover"][k] == pytest.approx(cover, abs=1e-12)
        assert got["n_points"][k] == m.sum()
        for q in RH_LEVELS:
            assert got[f"rh{q}"][k] == pytest.approx(rh[q], abs=1e-9)


def test_flat_ground_truth_is_exact_and_empty_footprints_nan():
    g = np.arange(0.0, 30.0, 0.5)
    gx, gy = np.meshgrid(g, g)
    x, y = X0 + gx.ravel(), Y0 + gy.ravel()
    z = np.full(x.size, 12.34)
    idx = CloudIndex(x, y, z)
    sx = X0 + np.array([10.0, 15.0, 200.0])
    sy = Y0 + np.array([10.0, 15.0, 200.0])  # the last shot is far outside the cloud
    t = footprint_truth(idx.pairs(sx, sy, 6.5), 0.25, TruthParams(), rh_floor=0.5)
    assert t["ground"][:2] == pytest.approx([12.34, 12.34], abs=1e-6)
    assert np.all(t["cover"][:2] == 0.0) and np.all(t["rh95"][:2] == 0.0)
    assert np.isnan(t["ground"][2]) and np.isnan(t["cover"][2]) and t["n_points"][2] == 0


def test_two_layer_truth_metrics():
    """Ground 0 m everywhere, canopy at exactly 20 m on one half: RH and cover by hand."""
    g = np.arange(0.0, 40.0, 0.5)
    gx, gy = np.meshgrid(g, g)
    gx, gy = gx.ravel(), gy.ravel()
    cx, cy = gx[gx >= 20.0], gy[gx >= 20.0]
    x = X0 + np.concatenate([gx, cx])
    y = Y0 + np.concatenate([gy, cy])
    z = np.concatenate([np.zeros(gx.size), np.full(cx.size, 20.0)])
    idx = CloudIndex(x, y, z)
    sx, sy = np.array([X0 + 30.0, X0 + 10.0]), np.array([Y0 + 20.0, Y0 + 20.0])
    t = footprint_truth(idx.pairs(sx, sy, 6.5), 0.25, TruthParams(), rh_floor=0.5)
    # shot 0: everything inside R is under the canopy: half the points at 20 m
    assert t["ground"][0] == pytest.approx(0.0, abs=1e-6)
    assert t["top"][0] == 20.0
    assert t["cover"][0] == pytest.approx(0.5)
    for q in RH_LEVELS:
        assert t[f"rh{q}"][0] == pytest.approx(20.0)
    # shot 1: no canopy within R (10 m from the edge)
    assert t["top"][1] == 0.0 and t["cover"][1] == 0.0 and t["rh50"][1] == 0.0


def test_truth_columns_on_simulation_match_index():
    x, y, z = random_cloud(3000, 40.0, 3)
    pts = LasPoints.from_arrays(x, y, z, crs=CRS)
    sim = simulate_photons(pts, SimTrack.line(X0 + 8, Y0 + 20, X0 + 32, Y0 + 20), seed=1)
    inside, _ = brute_pairs(x, y, sim.shot_x, sim.shot_y, 6.5)
    assert np.array_equal(sim.truth["n_points"], inside.sum(axis=1))
    top = np.where(inside, z[None, :], -np.inf).max(axis=1)
    assert np.array_equal(sim.truth["top"], top)


def test_params_validation():
    with pytest.raises(InputError, match="diameter"):
        SimParams(diameter=-1)
    with pytest.raises(InputError, match="photon_rate"):
        SimParams(photon_rate="savanna")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="instrument"):
        SimParams(instrument="gedi")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="noise_rate"):
        SimParams(noise_rate=-0.1)
    with pytest.raises(InputError, match="peak_fraction"):
        TruthParams(peak_fraction=1.5)
    p = SimParams(instrument="mabel")
    assert (p.diameter, p.shot_spacing, p.pulse_rate) == (2.0, 0.04, 5000.0)
    assert SimParams(photon_rate="boreal", beam="weak").photon_mean == 0.25
    assert SimParams(photon_rate="tropical").photon_mean == 0.6
    with pytest.warns(FutureWarning, match=r"preset=\) is deprecated.*photon_rate="):
        old = SimParams(preset="boreal")  # type: ignore[arg-type]  # the old name still works
    assert (old.photon_rate, old.preset, old.photon_mean) == ("boreal", None, 1.0)
    assert SimParams(mean_photons=3.0, beam="weak").photon_mean == 3.0
    assert SimParams(diameter=17).radius == 8.5
