"""The block reference pooled like the estimate (DESIGN 2.7): brute force on a small
synthetic point set, the footprint-mean kept by name, and simulated photons' truth."""

from __future__ import annotations

import math

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest

from canopyblocks.errors import InputError
from canopyblocks.readers.las import LasPoints, read_las
from canopyblocks.reference.footprint_blocks import (
    CANOPY_THRESHOLD,
    block_footprint_reference,
    estimate_statistic,
)
from canopyblocks.reference.footprint_params import FootprintReferenceParams

X0, Y0 = 500_000.0, 5_000_000.0
CRS = "EPSG:32610"


def _points(seed: int = 3) -> LasPoints:
    """Ground on an exact tilted plane (1.5 m points) and scattered canopy returns of
    random heights (0-25 m above the plane, some below the canopy threshold)."""
    rng = np.random.default_rng(seed)
    g = np.arange(-30.0, 30.0 + 1e-9, 1.5)
    gx, gy = (a.ravel() for a in np.meshgrid(g, np.arange(-15.0, 15.0 + 1e-9, 1.5)))
    n = 900
    cx, cy = rng.uniform(-30, 30, n), rng.uniform(-15, 15, n)
    ch = np.where(rng.random(n) < 0.1, rng.uniform(0.0, 1.0, n), rng.uniform(1.0, 25.0, n))
    x, y = np.concatenate([gx, cx]), np.concatenate([gy, cy])

    def plane(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return 200.0 + 0.12 * a - 0.05 * b

    z = plane(x, y) + np.concatenate([np.zeros(gx.size), ch])
    cls = np.concatenate([np.full(gx.size, 2), np.full(n, 1)])
    return LasPoints.from_arrays(x + X0, y + Y0, z, crs=CRS, classification=cls)


def _blocks(length: float, n: int, s_first: float = -22.0) -> gpd.GeoDataFrame:
    s_start = s_first + np.arange(n) * length
    mid = s_start + length / 2
    df = pd.DataFrame({"track": "t", "length": length, "block": np.arange(n),
                       "s_start": s_start, "s_end": s_start + length,
                       "x": X0 + mid, "y": np.full(n, Y0)})
    return gpd.GeoDataFrame(df, geometry=gpd.points_from_xy(df.x, df.y), crs=CRS)


def _brute_force(pts: LasPoints, s0: float, s1: float, diameter: float, threshold: float,
                 levels: tuple[int, ...]) -> tuple[float, list[float]]:
    """Mean footprint ground and the pooled weighted percentiles, one footprint and one
    point at a time (footprints at (k + 0.5) 0.7 m on the line y = Y0, x = X0 + s)."""
    R = diameter / 2
    heights: list[float] = []
    weights: list[float] = []
    grounds = []
    for k in range(-100, 100):
        s = (k + 0.5) * 0.7
        if not (s0 <= s < s1):
            continue
        cx, cy = X0 + s, Y0
        members = []
        for i in range(len(pts)):
            r2 = (pts.x[i] - cx) ** 2 + (pts.y[i] - cy) ** 2
            if r2 <= R * R:
                members.append((i, math.exp(-2 * r2 / R ** 2)))
        # the exact plane through the class-2 points (they lie on it): weighted LSQ
        gi = [(i, w) for i, w in members if pts.classification[i] == 2]
        A = np.array([[1.0, pts.x[i] - cx, pts.y[i] - cy] for i, _ in gi])
        W = np.array([w for _, w in gi])
        zg = np.array([pts.z[i] for i, _ in gi])
        coef = np.linalg.lstsq(A * np.sqrt(W)[:, None], zg * np.sqrt(W), rcond=None)[0]
        grounds.append(float(np.sum(W * zg) / np.sum(W)))
        total = sum(w for _, w in members)
        for i, w in members:
            h = pts.z[i] - (coef[0] + coef[1] * (pts.x[i] - cx) + coef[2] * (pts.y[i] - cy))
            if h > threshold:
                heights.append(float(h))
                weights.append(w / total)
    order = np.argsort(heights)
    hs, ws = np.asarray(heights)[order], np.asarray(weights)[order]
    cdf = np.cumsum(ws) / np.sum(ws)
    pct = [float(hs[np.searchsorted(cdf, q / 100.0 - 1e-12)]) for q in levels]
    return float(np.mean(grounds)), pct


@pytest.mark.parametrize("length", [10.0, 20.0])
def test_pooled_reference_is_the_brute_force_pooled_percentile(length: float) -> None:
    pts = _points()
    blocks = _blocks(length, int(44 // length))
    params = FootprintReferenceParams(diameter=13.0, min_coverage=0.0)
    got = block_footprint_reference(blocks, pts, params)
    assert (got["ref_statistic"] == "pooled").all()
    assert CANOPY_THRESHOLD == pytest.approx(0.6)
    for b in range(len(blocks)):
        s0 = float(blocks["s_start"].iloc[b])
        ground, (p98, p90) = _brute_force(pts, s0, s0 + length, 13.0, CANOPY_THRESHOLD,
                                          (98, 90))
        assert got["ref_ground"].iloc[b] == pytest.approx(ground, abs=1e-9)
        assert got["ref_hmax"].iloc[b] == pytest.approx(p98, abs=1e-9)
        assert got["ref_h90"].iloc[b] == pytest.approx(p90, abs=1e-9)
        assert got["ref_top"].iloc[b] == pytest.approx(ground + p98, abs=1e-9)
        assert got["ref_top90"].iloc[b] == pytest.approx(ground + p90, abs=1e-9)
    # every return (ground included) for a percentile top, as the pNN estimators
    allr = block_footprint_reference(blocks, pts, params, canopy_threshold=None,
                                     top_level=95)
    _, (p95,) = _brute_force(pts, float(blocks["s_start"].iloc[0]),
                             float(blocks["s_end"].iloc[0]), 13.0, -math.inf, (95,))
    assert allr["ref_hmax"].iloc[0] == pytest.approx(p95, abs=1e-9)


def test_footprint_mean_kept_by_name_and_statistics_checked() -> None:
    pts = _points()
    blocks = _blocks(20.0, 2)
    params = FootprintReferenceParams(diameter=13.0, min_coverage=0.0)
    mean = block_footprint_reference(blocks, pts, params, statistic="footprint-mean")
    old = block_footprint_reference(blocks, pts, params, statistic="mean")
    pd.testing.assert_frame_equal(mean, old)
    assert (mean["ref_statistic"] == "footprint-mean").all()
    pooled = block_footprint_reference(blocks, pts, params)
    # the same ground; another Hmax (the mean of footprint RH98 over all returns)
    np.testing.assert_allclose(mean["ref_ground"], pooled["ref_ground"])
    assert not np.allclose(mean["ref_hmax"], pooled["ref_hmax"])
    with pytest.raises(InputError, match="statistic"):
        block_footprint_reference(blocks, pts, params, statistic="median")


def test_no_canopy_gives_zero_like_the_estimate() -> None:
    g = np.arange(-30.0, 30.0 + 1e-9, 1.0)
    gx, gy = (a.ravel() for a in np.meshgrid(g, np.arange(-12.0, 12.0 + 1e-9, 1.0)))
    pts = LasPoints.from_arrays(gx + X0, gy + Y0, 50.0 + 0.3 * (gx == 0), crs=CRS,
                                classification=np.full(gx.size, 2))
    got = block_footprint_reference(_blocks(10.0, 4), pts,
                                    FootprintReferenceParams(diameter=13.0, min_coverage=0.0))
    np.testing.assert_allclose(got["ref_hmax"], 0.0)
    np.testing.assert_allclose(got["ref_h90"], 0.0)


def test_estimate_statistic_follows_the_estimators() -> None:
    assert estimate_statistic("noise=atl08,ground=atl08,top=atl08") == (CANOPY_THRESHOLD, 98)
    assert estimate_statistic("noise=density,ground=paper,top=p95") == (None, 95)
    assert estimate_statistic("noise=sigma,ground=paper,top=paper") == (None, 98)
    assert estimate_statistic(None) == (CANOPY_THRESHOLD, 98)


def test_pooled_reference_is_what_simulated_photons_sample(sample) -> None:  # noqa: ANN001
    """Simulation truth: noise-free photons drawn over a real tile (60 a shot); per
    50 m block the 98th / 90th percentile of their source points' heights above the
    footprint's ground, canopy photons only, is the pooled reference to within what
    the ground definitions (the simulator's lowest waveform peak vs the class-2 plane)
    and a finite draw leave."""
    from canopyblocks.simulate import SimParams, line_through, simulate_photons

    pts = read_las(sample("als/lasR_bcts_1.laz"))
    line = line_through(pts.bounds, 30.0, inset=10.0)
    sim = simulate_photons(pts, line, SimParams(mean_photons=60.0), seed=7)
    ph = sim.photons
    sig = ~ph["noise"] & (ph["realisation"] == 0)
    h = ph["src_z"][sig] - sim.truth["ground"][ph["shot"][sig]]
    s = ph["s"][sig]
    n = int(line.length // 50.0)
    blocks = _blocks_on(line, n, pts.crs)
    ref = block_footprint_reference(blocks, pts, FootprintReferenceParams(diameter=13.0))
    k = np.floor(s / 50.0).astype(int)
    can = h > CANOPY_THRESHOLD
    diffs = []
    for b in range(n):
        if ref["ref_flag"].iloc[b] != "ok":
            continue
        hb = h[can & (k == b)]
        diffs.append((np.percentile(hb, 98) - ref["ref_hmax"].iloc[b],
                      np.percentile(hb, 90) - ref["ref_h90"].iloc[b]))
    d = np.asarray(diffs)
    assert len(d) >= 3
    assert abs(d[:, 0].mean()) < 0.3 and abs(d[:, 1].mean()) < 0.3
    assert np.abs(d).max() < 1.0


def _blocks_on(line, n: int, crs) -> gpd.GeoDataFrame:  # noqa: ANN001
    (xa, ya), (xb, yb) = line.vertices
    ux, uy = (xb - xa) / line.length, (yb - ya) / line.length
    s_start = np.arange(n) * 50.0
    mid = s_start + 25.0
    df = pd.DataFrame({"track": "t", "length": 50.0, "block": np.arange(n),
                       "s_start": s_start, "s_end": s_start + 50.0,
                       "x": xa + mid * ux, "y": ya + mid * uy})
    return gpd.GeoDataFrame(df, geometry=gpd.points_from_xy(df.x, df.y), crs=crs)


def test_one_reason_per_block_by_the_stated_precedence() -> None:
    """A block both sparse and outside the reference is 'reference outside' in the
    residuals layer, in the facts and in the map legend alike."""
    from canopyblocks.outputs.footprint_maps import _hatched_label
    from canopyblocks.validation.facts import fact_rows
    from canopyblocks.validation.residuals import (
        LEFT_OUT_PRECEDENCE,
        RESIDUAL_PAIRS,
        compute_residuals,
    )

    blocks = _blocks(10.0, 5)
    blocks["flag"] = ["sparse", "sparse", "low_confidence", "ok", "ok"]
    blocks["use"] = [False, False, False, True, True]
    for m in RESIDUAL_PAIRS:
        blocks[m] = np.where(blocks["flag"] == "sparse", np.nan, 10.0)
    blocks["hmax_sigma"] = 1.0
    blocks["ground_sigma"] = 0.5
    ref = blocks[["track", "length", "block"]].copy()
    for r in RESIDUAL_PAIRS.values():
        ref[r] = 9.0
    ref["ref_flag"] = ["outside", "ok", "outside", "ok", "nodata"]
    res = compute_residuals(blocks, ref)
    want = ["reference outside", "sparse", "reference outside", "", "reference nodata"]
    assert list(res["reason"]) == want
    assert all(w in LEFT_OUT_PRECEDENCE for w in want if w)
    facts = fact_rows(res, estimators="atl08", reference="footprint", layer="x",
                      pairs=RESIDUAL_PAIRS, metrics=("hmax",))
    assert facts[0]["left_out"] == "reference nodata 1; reference outside 2; sparse 1"
    hatched = ~res["use"].to_numpy(bool)
    assert _hatched_label(res, hatched, True) == (
        "not in the statistics: reference nodata 1; reference outside 2; sparse 1")


def test_block_bootstrap_widens_the_interval_of_autocorrelated_residuals() -> None:
    """AR(1) residuals along a track (phi 0.6): the 95 % interval of the mean is
    1.96 sigma / (1 - phi) / sqrt(n) by theory; resampling single blocks gives about half
    of it, runs of adjacent blocks most of it. Independent residuals: both about alike."""
    from scipy.signal import lfilter

    from canopyblocks.validation.facts import interval95

    n, phi = 400, 0.6
    theory = 1.96 / (1 - phi) / math.sqrt(n)
    single, runs = [], []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        e = lfilter([1.0], [1.0, -phi], rng.normal(size=n))  # e[i] = phi e[i-1] + noise
        a = interval95(e)
        b = interval95(e, track=np.zeros(n), run=10)
        assert a[4] == "bootstrap" and b[4] == "block bootstrap"
        single.append((a[1] - a[0]) / 2 / theory)
        runs.append((b[1] - b[0]) / 2 / theory)
    assert np.mean(single) < 0.55 and 0.6 < np.mean(runs) < 1.2
    iid = np.random.default_rng(5).normal(size=n)
    a, b = interval95(iid), interval95(iid, track=np.zeros(n), run=10)
    assert (b[1] - b[0]) / (a[1] - a[0]) == pytest.approx(1.0, abs=0.25)
    # circular runs inside each track: every value drawn equally often, so a track whose
    # end differs from its middle keeps its mean at the middle of the interval
    ends = np.where(np.arange(n) % 100 < 10, 5.0, 0.0) + np.random.default_rng(6).normal(
        size=n) * 0.1
    lo, hi, _, _, how = interval95(ends, track=np.arange(n) // 100, run=10)
    assert how == "block bootstrap" and lo < ends.mean() < hi
    assert abs((lo + hi) / 2 - ends.mean()) < 0.1 * (hi - lo)
