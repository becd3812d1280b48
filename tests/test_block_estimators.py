"""Estimators beyond the paper (DESIGN 1.10) against brute force and synthetic truth."""

from __future__ import annotations

import numpy as np
import pytest

from canopyblocks.blocks import BlockParams, compute_blocks
from canopyblocks.blocks.density_filter import DensityParams, density_filter
from canopyblocks.blocks.estimators import (
    PRESETS,
    Estimators,
    estimate_blocks,
    percentile_by_block,
    preset,
)
from canopyblocks.blocks.ground_surface import (
    GroundSurfaceParams,
    block_mean_ground,
    fit_ground_surface,
)
from canopyblocks.errors import InputError
from canopyblocks.photons import PhotonTrack

pytestmark = pytest.mark.filterwarnings("ignore::canopyblocks.errors.SparseBlockWarning")


def _track(s: np.ndarray, z: np.ndarray, conf: np.ndarray | None = None) -> PhotonTrack:
    order = np.argsort(s, kind="stable")
    s, z = s[order], z[order]
    x = 500_000.0 + s * np.cos(0.3)
    y = 4_500_000.0 + s * np.sin(0.3)
    return PhotonTrack.from_xy(x, y, z, track="gt1r", crs=32612, s=s,
                               signal_conf=None if conf is None else conf[order])


def _forest(rng: np.random.Generator, n: int = 6000, length: float = 500.0,
            ground=lambda s: 100.0 + 0.05 * s, canopy: float = 20.0):
    """Photons over known terrain: 40 % ground (sigma 0.25 m), 60 % canopy up to 20 m."""
    s = rng.uniform(0, length, n)
    is_ground = rng.random(n) < 0.4
    h = np.where(is_ground, 0.0, rng.uniform(2.0, canopy, n) * (rng.random(n) ** 0.3))
    z = ground(s) + h + rng.normal(0, 0.25, n)
    return s, z, is_ground


def test_percentile_by_block_matches_numpy():
    rng = np.random.default_rng(1)
    block = rng.integers(0, 40, 3000)
    block[block == 7] = 8  # an empty block
    z = rng.normal(0, 10, 3000)
    for q in (0.0, 50.0, 95.0, 98.0, 99.0, 100.0):
        got = percentile_by_block(block, z, q, 40)
        for b in range(40):
            if b == 7:
                assert np.isnan(got[b])
            else:
                assert got[b] == pytest.approx(np.percentile(z[block == b], q), abs=1e-12)


@pytest.mark.parametrize("top", ["p95", "p98", "p99", "p100"])
def test_percentile_top_and_h90_brute_force(top):
    rng = np.random.default_rng(2)
    s, z, _ = _forest(rng, n=3000, length=300.0)
    track = _track(s, z)
    params = BlockParams(lengths=(25.0,))
    est = Estimators(noise="none", ground="paper", top=top)  # type: ignore[arg-type]
    got = estimate_blocks(track, params, est)
    paper = compute_blocks(track, BlockParams(lengths=(25.0,), noise="none"))
    q = float(top[1:])
    for _, row in got.iterrows():
        sel = (track.s >= row.s_start) & (track.s < row.s_end)
        zz = track.h[sel]
        assert row.top == pytest.approx(np.percentile(zz, q), abs=1e-9)
        # ground stays the paper's (ground="paper")
        prow = paper[paper.block == row.block].iloc[0]
        assert row.ground == prow.ground
        between = np.sort(zz[(zz >= row.ground) & (zz <= row.top)])
        assert row.n_between == between.size
        assert row.z90 == between[int(np.floor(0.9 * (between.size - 1)))]
        assert row.hmax == pytest.approx(row.top - row.ground)
        assert row.flag == "ok"
    assert (got["estimators"] == f"noise=none,ground=paper,top={top}").all()


def test_paper_estimators_are_the_paper_engine_bit_for_bit():
    rng = np.random.default_rng(3)
    s, z, _ = _forest(rng, n=2000, length=250.0)
    track = _track(s, z)
    params = BlockParams(lengths=(10.0, 25.0, 50.0))
    a = compute_blocks(track, params)
    b = estimate_blocks(track, params, PRESETS["paper"])
    cols = [c for c in a.columns if c != "geometry"]
    assert a[cols].equals(b[cols])


@pytest.mark.parametrize("terrain", ["slope", "step", "wave"])
def test_ground_surface_recovers_known_terrain(terrain):
    rng = np.random.default_rng(4)
    g = {"slope": lambda s: 100.0 + 0.12 * s,
         "step": lambda s: 100.0 + np.where(s > 250.0, 3.0, 0.0),
         "wave": lambda s: 100.0 + 4.0 * np.sin(s / 40.0)}[terrain]
    s, z, _ = _forest(rng, n=5000, length=500.0, ground=g)
    surf = fit_ground_surface(s, z, GroundSurfaceParams())
    edges = np.arange(0.0, 500.0, 25.0)
    got = block_mean_ground(surf, edges, edges + 25.0)
    # truth: the mean of the terrain over each block (fine numeric integral)
    fine = np.linspace(0, 25, 2501)
    truth = np.array([g(e + fine).mean() for e in edges])
    err = got - truth
    if terrain == "step":  # the 25 m blocks either side of the step carry its smoothing
        near = np.abs(edges + 12.5 - 250.0) < 30.0
        err = err[~near]
    assert np.abs(err).max() < 0.15
    assert np.sqrt(np.mean(err ** 2)) < 0.1


def test_block_mean_ground_is_an_exact_integral():
    from canopyblocks.blocks.ground_surface import GroundSurface

    ns = np.arange(0.0, 11.0)
    nz = ns ** 2
    surf = GroundSurface(ns, nz, np.ones(11, bool), np.zeros(0, bool))
    # piecewise-linear integral of x^2 sampled at integers over [2.5, 7.5)
    xs = np.linspace(2.5, 7.5, 200001)
    want = np.trapezoid(np.interp(xs, ns, nz), xs) / 5.0 if hasattr(np, "trapezoid") \
        else np.trapz(np.interp(xs, ns, nz), xs) / 5.0
    assert block_mean_ground(surf, np.array([2.5]), np.array([7.5]))[0] == \
        pytest.approx(want, abs=1e-6)


def test_surface_ground_beats_paper_ground():
    rng = np.random.default_rng(5)
    g = lambda s: 200.0 + 0.08 * s  # noqa: E731
    s, z, _ = _forest(rng, n=1500, length=500.0, ground=g)  # sparse: 3 photons/m
    track = _track(s, z)
    params = BlockParams(lengths=(25.0,))
    paper = compute_blocks(track, params)
    surf = estimate_blocks(track, params, Estimators(noise="none", ground="surface", top="paper"))
    truth = g(paper["s_start"].to_numpy() + 12.5)
    e_paper = paper["ground"].to_numpy() - truth
    e_surf = surf["ground"].to_numpy() - truth
    assert np.sqrt(np.nanmean(e_surf ** 2)) < 0.2
    assert np.sqrt(np.nanmean(e_paper ** 2)) > 0.5  # the window's floor: biased high


def test_density_filter_known_background():
    """Signal band (ground + canopy) under uniform noise of a known rate."""
    rng = np.random.default_rng(6)
    length, zlo, zhi = 2000.0, 0.0, 400.0
    rate = 0.01  # photons per m along-track per m height
    n_noise = rng.poisson(rate * length * (zhi - zlo))
    ns = rng.uniform(0, length, n_noise)
    nz = rng.uniform(zlo, zhi, n_noise)
    n_sig = 20000  # 10 photons/m along-track in a ~15 m band
    ss = rng.uniform(0, length, n_sig)
    sz = 200.0 + 0.02 * ss + np.where(rng.random(n_sig) < 0.5, rng.normal(0, 0.3, n_sig),
                                      rng.uniform(0, 15, n_sig))
    s = np.concatenate([ns, ss])
    z = np.concatenate([nz, sz])
    is_sig = np.concatenate([np.zeros(n_noise, bool), np.ones(n_sig, bool)])
    for params in (DensityParams(), DensityParams(background=rate)):
        res = density_filter(s, z, params)
        kept_signal = res.keep[is_sig].mean()
        # noise inside the signal's own band (+- the box height) is indistinguishable
        band = 200.0 + 0.02 * s
        away = ~is_sig & ((z < band - 4.0) | (z > band + 19.0))
        assert kept_signal > 0.95, kept_signal
        assert 1 - res.keep[away].mean() > 0.99
        assert 1 - res.keep[~is_sig].mean() > 0.9
    # the estimated rate is the true one within 15 %
    est = density_filter(s, z).rate
    assert np.median(est) == pytest.approx(rate, rel=0.15)


def test_density_filter_keeps_everything_without_background():
    rng = np.random.default_rng(7)
    s = rng.uniform(0, 500, 3000)
    z = 50 + rng.uniform(0, 20, 3000)
    assert density_filter(s, z).keep.all()


def test_estimator_validation_messages():
    with pytest.raises(InputError, match="top estimator must be one of"):
        Estimators(top="p90")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="unknown preset"):
        preset("gedi")
    with pytest.raises(InputError, match="quantile"):
        DensityParams(quantile=1.5)
    rng = np.random.default_rng(8)
    s, z, _ = _forest(rng, n=500, length=100.0)
    with pytest.raises(InputError, match="signal_conf"):
        estimate_blocks(_track(s, z), BlockParams(), Estimators(noise="conf", ground="paper", top="paper"))


def test_poisson_quantile_equals_scipy_stats():
    """The density filter's threshold (numpy, no scipy.stats import) against scipy's ppf."""
    from scipy import stats

    from canopyblocks.blocks.density_filter import poisson_quantile

    for q in (0.5, 0.9, 0.99, 0.999, 0.99999):
        for mu in np.concatenate([np.geomspace(1e-5, 5000, 300), [0.5, 1, 2, 7, 100]]):
            assert poisson_quantile(q, mu) == stats.poisson.ppf(q, mu), (q, mu)
    assert poisson_quantile(0.99, 0.0) == 0.0
