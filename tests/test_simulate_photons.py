"""Photon draws: Poisson counts, heights from the footprint PDF, noise, geolocation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from canopyblocks.errors import InputError, NoUsableDataError
from canopyblocks.readers.las import LasPoints
from canopyblocks.simulate import SimParams, SimTrack, simulate_photons

CRS = 32610
X0, Y0 = 500_000.0, 5_000_000.0


def grid_cloud(size: float = 60.0, step: float = 0.5, z: float = 0.0):
    g = np.arange(0.0, size, step)
    gx, gy = np.meshgrid(g, g)
    x, y = X0 + gx.ravel(), Y0 + gy.ravel()
    return x, y, np.full(x.size, z)


def flat_points(size: float = 60.0) -> LasPoints:
    x, y, z = grid_cloud(size)
    return LasPoints.from_arrays(x, y, z, crs=CRS)


def two_layer_points() -> tuple[LasPoints, np.ndarray]:
    """Ground at 0 m everywhere; a canopy layer at 20 m where x >= X0 + 30 m."""
    x, y, z = grid_cloud(60.0)
    can = x >= X0 + 30.0
    xs = np.concatenate([x, x[can]])
    ys = np.concatenate([y, y[can]])
    zs = np.concatenate([z, np.full(can.sum(), 20.0)])
    return LasPoints.from_arrays(xs, ys, zs, crs=CRS), zs


def shot_counts(sim) -> np.ndarray:
    ph = sim.photons
    sig = ~ph["noise"]
    return np.bincount(ph["realisation"][sig] * sim.n_shots + ph["shot"][sig],
                       minlength=sim.n_realisations * sim.n_shots)


@pytest.mark.parametrize("preset, beam, mean", [("temperate", "strong", 1.9),
                                                ("boreal", "weak", 0.25),
                                                ("tropical", "strong", 0.6)])
def test_photons_per_shot_are_poisson(preset, beam, mean):
    track = SimTrack.line(X0 + 10, Y0 + 30, X0 + 50, Y0 + 30)  # 58 shots
    sim = simulate_photons(flat_points(), track, SimParams(photon_rate=preset, beam=beam),
                           realisations=300, seed=11)
    c = shot_counts(sim)
    n = c.size
    assert n == 300 * sim.n_shots > 15_000
    # mean within 4 standard errors of the Poisson mean; variance = mean (dispersion)
    assert abs(c.mean() - mean) < 4 * np.sqrt(mean / n)
    assert abs(c.var(ddof=1) / mean - 1) < 4 * np.sqrt(2.0 / n) + 0.01
    # frequencies of 0, 1, 2 photons
    for k in range(3):
        p = stats.poisson.pmf(k, mean)
        assert abs(np.mean(c == k) - p) < 4 * np.sqrt(p * (1 - p) / n)


def test_flat_ground_heights_are_psf_gaussian():
    track = SimTrack.line(X0 + 10, Y0 + 30, X0 + 50, Y0 + 30)
    sim = simulate_photons(flat_points(), track, SimParams(psf=0.25), realisations=50, seed=2)
    h = sim.photons["h"]
    assert h.size > 4000
    assert stats.kstest(h / 0.25, "norm").pvalue > 1e-3
    assert np.all(sim.photons["src_z"] == 0.0) and not sim.photons["noise"].any()


def test_source_points_follow_footprint_weights():
    """Five points in one footprint: chosen with probability proportional to the weight."""
    r = np.array([0.0, 1.0, 3.0, 5.0, 6.4])
    x, y = X0 + r, np.full(r.size, Y0)
    z = np.arange(5.0) * 10.0
    pts = LasPoints.from_arrays(x, y, z, crs=CRS)
    track = SimTrack.line(X0, Y0, X0, Y0 + 0.5)  # one shot at (X0, Y0)
    sim = simulate_photons(pts, track, SimParams(mean_photons=5.0), realisations=4000, seed=5)
    assert sim.n_shots == 1
    w = np.exp(-2 * r ** 2 / 6.5 ** 2)
    expected = w / w.sum()
    counts = np.bincount(sim.photons["src_index"], minlength=5)
    chi = stats.chisquare(counts, expected * counts.sum())
    assert chi.pvalue > 1e-3
    # heights are the source's height plus the PSF
    res = sim.photons["h"] - sim.photons["src_z"]
    assert abs(res.std() - 0.25) < 0.01


def test_two_layer_canopy_split():
    """Photon share from the 20 m layer = weighted canopy share of each footprint."""
    pts, _ = two_layer_points()
    track = SimTrack.line(X0 + 15, Y0 + 30, X0 + 45, Y0 + 30)  # crosses the canopy edge
    sim = simulate_photons(pts, track, SimParams(mean_photons=2.0), realisations=200, seed=8)
    # brute force weighted canopy share per shot
    d2 = (sim.shot_x[:, None] - pts.x[None, :]) ** 2 + (sim.shot_y[:, None] - pts.y[None, :]) ** 2
    w = np.where(d2 <= 6.5 ** 2, np.exp(-2 * d2 / 6.5 ** 2), 0.0)
    p_can = (w * (pts.z[None, :] > 10)).sum(axis=1) / w.sum(axis=1)
    assert p_can.min() == 0.0 and p_can.max() > 0.49 and 0.05 < p_can.mean() < 0.45
    ph = sim.photons
    from_canopy = ph["h"] > 10.0
    assert np.array_equal(from_canopy, ph["src_z"] == 20.0)
    n = from_canopy.size
    expected = p_can[ph["shot"]].mean()  # photons per shot are identically distributed
    assert abs(from_canopy.mean() - expected) < 4 * np.sqrt(expected * (1 - expected) / n)
    # per shot class: far from the canopy nothing, under full canopy about half
    left = sim.shot_x < X0 + 23
    assert not from_canopy[left[ph["shot"]]].any()


def test_noise_photons_rate_and_window():
    """Background photons: uniform in the telemetry window around the coarse terrain
    (ground at 0 m here, so -10..+10 m), at the requested MHz (1 MHz = 2e6 / c photons
    per shot per metre)."""
    track = SimTrack.line(X0 + 10, Y0 + 30, X0 + 50, Y0 + 30)
    params = SimParams(background_rate_mhz=15.0, telemetry_window=10.0, mean_photons=1.0)
    sim = simulate_photons(flat_points(), track, params, realisations=100, seed=3)
    ph = sim.photons
    noise = ph["noise"]
    per_shot_per_m = 15.0e6 * 2.0 / 299_792_458.0
    expected = per_shot_per_m * 20.0 * sim.n_shots * 100
    assert abs(noise.sum() - expected) < 4 * np.sqrt(expected)
    hn = ph["h"][noise]
    assert hn.min() >= -10.0 and hn.max() <= 10.0
    assert stats.kstest((hn + 10.0) / 20.0, "uniform").pvalue > 1e-3
    assert np.all(ph["src_index"][noise] == -1) and np.all(np.isnan(ph["src_z"][noise]))
    # signal photons are unchanged in number
    c = shot_counts(sim)
    assert abs(c.mean() - 1.0) < 4 * np.sqrt(1.0 / c.size)


def test_noise_rate_is_a_deprecated_spelling_of_the_rate_in_mhz():
    a = SimParams(noise_rate=0.02)
    assert a.background_rate_mhz == pytest.approx(0.02 * 299_792_458.0 / 2e6)
    assert a.noise_rate is None and a.noise_per_shot_per_m == pytest.approx(0.02)
    with pytest.raises(InputError, match="once"):
        SimParams(noise_rate=0.02, background_rate_mhz=1.0)
    with pytest.raises(InputError, match="background_rate_mhz"):
        SimParams(background_rate_mhz=-1.0)
    with pytest.raises(InputError, match="telemetry_window"):
        SimParams(telemetry_window=0.0)


def test_geolocation_error():
    track = SimTrack.line(X0 + 10, Y0 + 30, X0 + 50, Y0 + 30)
    sim = simulate_photons(flat_points(), track, SimParams(geolocation_sigma=3.0),
                           realisations=100, seed=4)
    ph = sim.photons
    dx, dy = ph["x"] - ph["x_true"], ph["y"] - ph["y_true"]
    # one offset per shot and realisation: photons of the same shot share it
    key = ph["realisation"] * sim.n_shots + ph["shot"]
    first = np.unique(key, return_index=True)[1]
    assert abs(dx[first].std() - 3.0) < 0.15 and abs(dy[first].std() - 3.0) < 0.15
    same = key[1:] == key[:-1]
    assert np.all(dx[1:][same] == dx[:-1][same])
    exact = simulate_photons(flat_points(), track, SimParams(), seed=4).photons
    assert np.array_equal(exact["x"], exact["x_true"])


def test_determinism_and_ordering():
    pts, _ = two_layer_points()
    track = SimTrack.line(X0 + 15, Y0 + 30, X0 + 45, Y0 + 30)
    a = simulate_photons(pts, track, realisations=3, seed=99)
    b = simulate_photons(pts, track, realisations=3, seed=99)
    c = simulate_photons(pts, track, realisations=3, seed=100)
    for k in a.photons:
        assert np.array_equal(a.photons[k], b.photons[k], equal_nan=True)
    assert not np.array_equal(a.photons["h"][:100], c.photons["h"][:100])
    r, s = a.photons["realisation"], a.photons["shot"]
    assert np.all(np.diff(r) >= 0)
    assert np.all(np.diff(s)[np.diff(r) == 0] >= 0)
    assert np.allclose(a.photons["time"], s / 10_000.0)
    assert np.allclose(a.photons["s"], s * 0.7)


def test_photon_track_for_block_engine():
    pts, _ = two_layer_points()
    track = SimTrack.line(X0 + 15, Y0 + 30, X0 + 45, Y0 + 30, name="gt2l")
    sim = simulate_photons(pts, track, realisations=2, seed=1)
    t = sim.photon_track(1)
    assert t.track == "gt2l" and t.crs.to_epsg() == CRS
    c = sim.photon_columns(1)
    assert len(t) == c["h"].size
    assert np.all(np.diff(t.s) >= 0)
    assert np.allclose(t.x, c["x"]) and np.allclose(t.h, c["h"])
    assert set(t.extra) >= {"src_z", "truth_ground", "truth_top", "noise"}
    t.validate()
    with pytest.raises(InputError, match="realisation"):
        sim.photon_track(2)


def test_track_missing_the_cloud_and_bad_arguments():
    pts = flat_points(20.0)
    far = SimTrack.line(X0 + 500, Y0, X0 + 600, Y0)
    with pytest.raises(NoUsableDataError, match="misses the point cloud"):
        simulate_photons(pts, far)
    with pytest.raises(InputError, match="realisations"):
        simulate_photons(pts, SimTrack.line(X0, Y0, X0 + 10, Y0), realisations=0)


def test_excluded_classes_and_nan_points_are_ignored():
    x, y, z = grid_cloud(40.0)
    cls = np.ones(x.size, np.uint8)
    rng = np.random.default_rng(0)
    noisy = rng.random(x.size) < 0.1
    z = z.copy()
    z[noisy] = -30.0  # low noise points (class 7) would make a false ground
    cls[noisy] = 7
    z[5] = np.nan
    pts = LasPoints.from_arrays(x, y, z, crs=CRS, classification=cls)
    track = SimTrack.line(X0 + 10, Y0 + 20, X0 + 30, Y0 + 20)
    sim = simulate_photons(pts, track, realisations=20, seed=2)
    src = sim.photons["src_index"]
    assert np.all(pts.classification[src] == 1)
    assert np.array_equal(pts.z[src], sim.photons["src_z"])  # ids of the input cloud
    assert np.allclose(sim.truth["ground"], 0.0, atol=1e-6)
    with_noise = simulate_photons(pts, track, SimParams(exclude_classes=()), seed=2)
    assert np.all(with_noise.truth["ground"] < -29)
