"""The flash-lidar chain, step by step, on hand-made cubes and terrain points with known
answers (pixel geolocation, merging on the 5 m grid, lowest Gaussian, MCC, outliers)."""

from __future__ import annotations

import numpy as np
import pytest

from canopyblocks.errors import InputError
from canopyblocks.waveforms.esfl import (
    EsflCubes,
    EsflParams,
    esfl_chain,
    esfl_waveforms,
    lowest_gaussian,
)
from canopyblocks.waveforms.mcc import MccParams, mcc_ground, terrain_surface


def _gauss(m: int, centre: float, sigma: float, amp: float) -> np.ndarray:
    k = np.arange(m)
    return amp * np.exp(-0.5 * ((k - centre) / sigma) ** 2)


def test_pixel_geolocation_along_any_azimuth():
    """Pixel (row r, col c) of a footprint at (x, y) lies at u = (c + 0.5) p - 6 p along
    and v = (r + 0.5) p - 6 p across the track: brute force per pixel."""
    a = np.radians(30.0)
    along = (float(np.cos(a)), float(np.sin(a)))
    cubes = EsflCubes(np.zeros((2, 12, 12, 5)), np.array([10.0, 11.0]), 0.75,
                      np.array([100.0, 107.0]), np.array([200.0, 204.0]), along, 0.7)
    px, py = cubes.pixel_xy()
    for i in range(2):
        for r in range(12):
            for c in range(12):
                u, v = (c + 0.5) * 0.7 - 4.2, (r + 0.5) * 0.7 - 4.2
                want = (cubes.x[i] + u * along[0] - v * along[1],
                        cubes.y[i] + u * along[1] + v * along[0])
                assert np.allclose((px[i, r, c], py[i, r, c]), want)


def test_merging_aligns_range_gates_by_elevation():
    """Two footprints whose cubes start 1.5 m (two bins) apart, one 5 m cell: the merged
    waveform is the mean of the pixels sample by sample at the same elevation."""
    m = 20
    cubes = np.zeros((2, 12, 12, m))
    cubes[0, 4:8, 4:8, :] = np.arange(m)            # value = bin index
    cubes[1, 4:8, 4:8, :] = np.arange(m) + 100.0
    # footprint 1's top 1.5 m lower: its bin k is at footprint 0's bin k + 2
    data = EsflCubes(cubes, np.array([50.0, 48.5]), 0.75, np.array([2.5, 2.5]),
                     np.array([2.5, 2.5]), (1.0, 0.0), 0.7)
    wf = esfl_waveforms(data, EsflParams(cell=5.0, fraction=0.5))
    assert wf.waveforms.shape[0] == 1 and wf.n_pixels[0] == 32
    w = wf.waveforms[0]
    assert wf.top[0] == 50.0
    np.testing.assert_allclose(w[:2], [0.0, 1.0])               # footprint 0 only
    k = np.arange(2, m)
    np.testing.assert_allclose(w[2:m], (k + (k - 2 + 100.0)) / 2)  # both, same elevation
    np.testing.assert_allclose(w[m:m + 2], [m - 2 + 100.0, m - 1 + 100.0])
    # one waveform per footprint: no merging
    wf0 = esfl_waveforms(data, EsflParams(cell=0.0))
    assert wf0.waveforms.shape[0] == 2
    np.testing.assert_allclose(wf0.x, [2.5, 2.5], atol=1e-9)


def test_lowest_gaussian_is_the_lowest_centre_above_threshold():
    g = np.array([[5.0, 10.0, 2.0], [0.5, 40.0, 2.0], [3.0, 30.0, 2.0]])
    assert lowest_gaussian(g, 1.0) == 30.0          # the weak one at 40 is below it
    assert np.isnan(lowest_gaussian(g, 10.0))
    assert np.isnan(lowest_gaussian(np.zeros((0, 3)), 1.0))


def test_chain_on_hand_made_waveforms():
    """Per footprint: canopy at bin 10 and ground at bin 30.4 (0.75 m bins, top at 100 m)
    with noise sd 0.01: terrain 100 - 30.4 * 0.75 = 77.2 m within 0.1 m; the top is the
    first sample above mean + 4 sd (brute force on the noise-free return plus margin)."""
    rng = np.random.default_rng(0)
    n, m = 30, 60
    clean = _gauss(m, 10.0, 1.2, 1.0) + _gauss(m, 30.4, 1.0, 0.8)
    cubes = np.zeros((n, 12, 12, m))
    cubes[:, 4:8, 4:8, :] = clean
    cubes += rng.normal(0.0, 0.01, cubes.shape)
    data = EsflCubes(cubes, np.full(n, 100.0), 0.75, np.arange(n) * 8.4,
                     np.zeros(n), (1.0, 0.0), 0.7)
    _, res = esfl_chain(data, EsflParams(cell=0.0))
    assert not res["outlier"].any()
    np.testing.assert_allclose(res["ground_gauss"], 100 - 30.4 * 0.75, atol=0.1)
    np.testing.assert_allclose(res["terrain"], 100 - 30.4 * 0.75, atol=0.1)
    # pixel-mean noise sd 0.01 / 4 -> threshold ~0.01: the canopy Gaussian exceeds it
    # from bin 10 - 1.2 * sqrt(2 ln(1 / 0.01)) = 6.4, so the top is bin 6 or 7
    top_bin = (100.0 - res["top"]) / 0.75
    assert np.all((top_bin >= 6) & (top_bin <= 7))
    np.testing.assert_allclose(res["height"], res["top"] - res["terrain"])


def test_outlier_rule_and_canopy_limit():
    """One footprint's ground return 12 m below the others' (noise taken for ground)
    is an outlier; the others are not."""
    n, m = 25, 60
    cubes = np.zeros((n, 12, 12, m))
    ground_bin = np.full(n, 30.0)
    ground_bin[12] = 46.0                     # 16 bins = 12 m lower
    for i in range(n):
        cubes[i, 4:8, 4:8, :] = _gauss(m, 10.0, 1.2, 1.0) + _gauss(m, ground_bin[i], 1.0, 0.8)
    cubes += np.random.default_rng(1).normal(0.0, 0.01, cubes.shape)
    data = EsflCubes(cubes, np.full(n, 100.0), 0.75, np.arange(n) * 8.4, np.zeros(n),
                     (1.0, 0.0), 0.7)
    _, res = esfl_chain(data, EsflParams(cell=0.0))
    assert list(np.flatnonzero(res["outlier"])) == [12]


def test_mcc_removes_points_above_the_terrain():
    """A sloping, curved terrain sampled every 5 m along a line, a fifth of the points
    lifted 2-20 m (canopy taken for the ground): MCC keeps every true terrain point and
    none of the lifted ones; the surface through the kept points is the terrain within
    0.3 m (the 0.2 m noise)."""
    rng = np.random.default_rng(1)
    s = np.arange(0.0, 500.0, 5.0)
    x, y = 1000 + 0.6 * s, 2000 + 0.8 * s
    z = 100 + 0.1 * s + 3 * np.sin(s / 40) + rng.normal(0, 0.2, s.size)
    lifted = rng.random(s.size) < 0.2
    zz = z + np.where(lifted, rng.uniform(2, 20, s.size), 0.0)
    keep = mcc_ground(x, y, zz, MccParams(scale=5.0, curvature=0.5))
    assert not (keep & lifted).any()
    assert keep[~lifted].mean() >= 0.95
    surf = terrain_surface(x, y, zz, keep)
    assert np.sqrt(np.mean((surf - z) ** 2)) < 0.3
    # 2-D: a tilted plane on a 5 m grid, a fifth of the points 10 m up
    gx, gy = np.meshgrid(np.arange(0, 100, 5.0), np.arange(0, 100, 5.0))
    gx, gy = gx.ravel(), gy.ravel()
    gz = 50 + 0.2 * gx + rng.normal(0, 0.1, gx.size)
    up = rng.random(gx.size) < 0.2
    keep = mcc_ground(gx, gy, gz + 10 * up, MccParams(scale=5.0, curvature=0.5))
    assert not (keep & up).any() and keep[~up].mean() >= 0.9


def test_bad_arguments():
    with pytest.raises(InputError, match="fraction"):
        EsflParams(fraction=0.0)
    with pytest.raises(InputError, match="cell"):
        EsflParams(cell=-1.0)
    with pytest.raises(InputError, match="noise_fit"):
        EsflParams(noise_fit="mode")
    with pytest.raises(InputError, match="scale"):
        MccParams(scale=0.0)
    with pytest.raises(InputError, match="one value per footprint"):
        EsflCubes(np.zeros((2, 12, 12, 5)), np.zeros(3), 0.75, np.zeros(2), np.zeros(2),
                  (1.0, 0.0), 0.7)
    with pytest.raises(InputError, match="unit vector"):
        EsflCubes(np.zeros((2, 12, 12, 5)), np.zeros(2), 0.75, np.zeros(2), np.zeros(2),
                  (1.0, 1.0), 0.7)
    with pytest.raises(InputError, match="1-D"):
        mcc_ground(np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)))


def test_footprints_without_a_window_are_left_out():
    """A footprint with nothing under it (top NaN, as the simulator writes it) gives no
    waveform; the others are processed as before."""
    m = 60
    cubes = np.zeros((3, 12, 12, m))
    cubes[:, 4:8, 4:8, :] = _gauss(m, 10.0, 1.2, 1.0) + _gauss(m, 30.0, 1.0, 0.8)
    cubes += np.random.default_rng(2).normal(0.0, 0.01, cubes.shape)
    top = np.array([100.0, np.nan, 100.0])
    data = EsflCubes(cubes, top, 0.75, np.array([0.0, 8.4, 16.8]), np.zeros(3), (1.0, 0.0),
                     0.7)
    for cell in (0.0, 5.0):
        wf, res = esfl_chain(data, EsflParams(cell=cell, mcc=None))
        assert np.all(np.isfinite(wf.top))
        assert not np.any((wf.x > 4.2) & (wf.x < 12.6))     # nothing from footprint 1
        np.testing.assert_allclose(res["ground_gauss"], 100 - 30 * 0.75, atol=0.1)
