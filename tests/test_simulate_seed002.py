"""Seed 002 classification, residual statistics and the experiment table."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from canopyblocks.errors import InputError
from canopyblocks.readers.las import LasPoints, read_las
from canopyblocks.simulate import (
    TABLE_COLUMNS,
    SimParams,
    SimTrack,
    classify_seed002,
    cover_table,
    line_through,
    residual_stats,
    seed002_experiment,
    seed002_labels,
    simulate_photons,
)

CRS = 32610
X0, Y0 = 500_000.0, 5_000_000.0


def grid_cloud(size=60.0, step=0.5):
    g = np.arange(0.0, size, step)
    gx, gy = np.meshgrid(g, g)
    return X0 + gx.ravel(), Y0 + gy.ravel()


# ------------------------------------------------------------------ classification
def test_classification_by_hand():
    h = np.array([0.0, 0.5, 0.8, 10.0, 19.5, 20.0])
    g, t, step = classify_seed002(h, psf=0.25, step=20)
    # min 0 -> ground below 0.75; max 20 -> top above 19
    assert g.tolist() == [True, True, False, False, False, False]
    assert t.tolist() == [False, False, False, False, True, True]
    assert step.tolist() == [0] * 6
    g, t, step = classify_seed002(h, psf=0.25, step=3)
    # steps [0, .5, .8] (ground < .75, top > -.2) and [10, 19.5, 20] (ground < 10.75, top > 19)
    assert g.tolist() == [True, True, False, True, False, False]
    assert t.tolist() == [True, True, True, False, True, True]
    assert step.tolist() == [0, 0, 0, 1, 1, 1]
    # steps restart with each realisation: [0, .5] and [.8, 10, 19.5, 20]
    g, t, step = classify_seed002(h, np.array([0, 0, 1, 1, 1, 1]), psf=0.25, step=20)
    assert g.tolist() == [True, True, True, False, False, False]
    assert t.tolist() == [True, True, False, False, True, True]
    assert step.tolist() == [0, 0, 1, 1, 1, 1]
    assert seed002_labels(g, t).tolist() == [1, 1, 1, 2, 3, 3]
    with pytest.raises(InputError, match="sorted by group"):
        classify_seed002(h, np.array([1, 1, 0, 0, 0, 0]))


def test_residual_stats_by_hand():
    s = residual_stats(np.array([1.0, -1.0, 3.0, np.nan]))
    assert s == {"n": 3, "bias": 1.0, "std": pytest.approx(np.sqrt(8 / 3)),
                 "rms": pytest.approx(np.sqrt(11 / 3))}
    assert np.isnan(residual_stats(np.array([]))["bias"])


def test_cover_table_against_pandas():
    rng = np.random.default_rng(0)
    res = {"ground_res": rng.normal(size=500), "ground_cover": rng.random(500),
           "top_res": rng.normal(size=300), "top_cover": rng.random(300)}
    res["ground_cover"][:5] = 1.0  # the last class includes 1
    t = cover_table(res, diameter=13.0)
    for kind in ("ground", "top"):
        df = pd.DataFrame({"r": res[f"{kind}_res"], "c": res[f"{kind}_cover"]})
        df["cls"] = np.minimum((df["c"] * 10).astype(int), 9)
        g = df.groupby("cls")["r"]
        sub = t[t["kind"] == kind].reset_index(drop=True)
        assert sub["n"].tolist() == g.size().reindex(range(10), fill_value=0).tolist()
        assert np.allclose(sub["mean"], g.mean().reindex(range(10)))
        assert np.allclose(sub["std"], g.std(ddof=0).reindex(range(10)))


# ------------------------------------------------------------------ flat bare ground
def oracle_flat_ground(psf: float, step: int, n_groups: int, seed: int) -> tuple[float, float]:
    """Expected bias/RMS of the seed 002 ground estimator on flat ground, by Monte Carlo:
    photons N(0, psf) in steps of 20; ground photons below min + 3 psf."""
    z = np.random.default_rng(seed).normal(0.0, psf, size=(n_groups, step))
    sel = z < z.min(axis=1, keepdims=True) + 3 * psf
    r = z[sel]
    return float(r.mean()), float(np.sqrt(np.mean(r * r)))


def test_flat_bare_ground_bias_and_rms():
    x, y = grid_cloud()
    pts = LasPoints.from_arrays(x, y, np.full(x.size, 100.0), crs=CRS)
    track = SimTrack.line(X0 + 10, Y0 + 30, X0 + 50, Y0 + 30)
    sim = simulate_photons(pts, track, SimParams(psf=0.25), realisations=400, seed=21)
    assert np.allclose(sim.truth["ground"], 100.0, atol=1e-6)
    from canopyblocks.simulate.analysis import summarise

    row, res = summarise(sim)
    bias, rms = oracle_flat_ground(0.25, 20, 100_000, seed=1)
    # the estimator keeps the lower part of each step: biased low, RMS below the PSF
    assert -0.12 < bias < -0.02 and 0.15 < rms < 0.25
    assert row["ground_bias"] == pytest.approx(bias, abs=0.012)
    assert row["ground_rms"] == pytest.approx(rms, abs=0.012)
    assert row["n_ground"] > 0.8 * sim.photons["h"].size


def test_two_layer_classification():
    x, y = grid_cloud()
    can = x >= X0 + 30
    pts = LasPoints.from_arrays(np.concatenate([x, x[can]]), np.concatenate([y, y[can]]),
                                np.concatenate([np.zeros(x.size), np.full(can.sum(), 20.0)]),
                                crs=CRS)
    track = SimTrack.line(X0 + 32, Y0 + 10, X0 + 32, Y0 + 50)  # under the canopy, near its edge
    sim = simulate_photons(pts, track, realisations=100, seed=4)
    from canopyblocks.simulate.analysis import photon_residuals

    res = photon_residuals(sim)
    src = sim.photons["src_z"]
    _, _, step = classify_seed002(sim.photons["h"], sim.photons["realisation"])
    has_ground = np.bincount(step, weights=(src == 0.0))[step] > 0
    has_canopy = np.bincount(step, weights=(src == 20.0))[step] > 0
    assert has_ground.mean() > 0.99 and has_canopy.mean() > 0.9
    # in steps holding a ground photon, ground photons all come from the ground layer;
    # in steps holding a canopy photon, top photons all come from the canopy
    assert np.all(src[res["ground"] & has_ground] == 0.0)
    assert np.all(src[res["top"] & has_canopy] == 20.0)
    # truth top is 20 m; top photons are 20 m + N(0, PSF) cut 1 m below the step maximum
    top_res = sim.photons["h"][res["top"] & has_canopy] - 20.0
    assert abs(np.mean(top_res)) < 0.1 and 0.1 < np.std(top_res) < 0.3
    # most ground-layer photons are found (a step of 20 photons without ground is rare)
    assert res["ground"].sum() > 0.75 * np.sum(src == 0.0)


# ------------------------------------------------------------------ real survey
def test_experiment_on_real_tile(sample):
    pts = read_las(sample("als/lasR_bcts_1.laz"))
    track = line_through(pts.bounds, 0.0, inset=8.5)
    track = SimTrack.line(*track.vertices[0], track.vertices[0][0], track.vertices[0][1] + 80)
    r = seed002_experiment(pts, track, diameters=(13.0, 17.0), realisations=20, seed=0)
    assert list(r.table.columns) == list(TABLE_COLUMNS)
    assert r.table["diameter"].tolist() == [13.0, 17.0]
    assert set(r.cover["kind"]) == {"ground", "top"}
    sim = r.simulations[13.0]
    # truth ground against the class-2 (ground) points near each footprint centre
    g = pts.classification == 2
    gx, gy, gz = pts.x[g], pts.y[g], pts.z[g]
    diffs = []
    for k in range(0, sim.n_shots, 10):
        near = (gx - sim.shot_x[k]) ** 2 + (gy - sim.shot_y[k]) ** 2 <= 2.0 ** 2
        if near.sum() >= 3:
            diffs.append(sim.truth["ground"][k] - np.median(gz[near]))
    diffs = np.asarray(diffs)
    assert diffs.size >= 8
    assert np.median(np.abs(diffs)) < 0.5
    # truth top: the highest point of each footprint is above the ground
    assert np.all(sim.truth["top"] > sim.truth["ground"])
    assert np.all((sim.truth["cover"] >= 0) & (sim.truth["cover"] <= 1))
    assert np.all(np.diff(np.column_stack([sim.truth[f"rh{q}"] for q in (50, 60, 75, 90, 95)]),
                          axis=1) >= 0)
    # the ground residual RMS is of the order of the PSF, as in seed 002 for open conifers
    assert 0.1 < r.table["ground_rms"].iloc[0] < 1.5
