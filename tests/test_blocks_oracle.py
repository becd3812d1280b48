"""The vectorised block engine against a plain per-block implementation of the paper.

The oracle below loops over blocks and literally runs the expansion-window loop of
seed 001 section 2.3 (start with 4 bins, add one bin while the fraction is below
the cut-off), sorts the photons between ground and top and takes the 90 % index.
It shares no code with ``canopyblocks.blocks``; it evaluates the same float64
expressions that DESIGN.md section 1 fixes as the definition (block =
floor((s - s0)/L), bin = min(floor((z - zmin)/0.5), nb - 1)), so results must agree
exactly, on random tracks that include empty, one-photon, flat (std == 0),
all-noise blocks and photons exactly on bin and block edges.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pyproj
import pytest

from canopyblocks import PhotonTrack
from canopyblocks.blocks import BlockParams, compute_blocks
from canopyblocks.blocks import histogram as hist_mod
from canopyblocks.errors import SparseBlockWarning
from canopyblocks.schema import LABEL_BETWEEN, LABEL_CANOPY, LABEL_GROUND, LABEL_NOISE

CRS = pyproj.CRS.from_epsg(32612)


# ----------------------------------------------------------------------------- oracle
def oracle_block(z: np.ndarray, conf_ok: np.ndarray | None, p: BlockParams, top_c: float,
                 ground_c: float) -> tuple[dict, np.ndarray]:
    """One block the slow way. Returns (row, per-photon labels)."""
    n = z.size
    labels = np.full(n, LABEL_NOISE, np.int8)
    cand = np.ones(n, bool) if conf_ok is None else conf_ok.copy()
    kept = cand.copy()
    if p.noise == "sigma" and cand.sum() > 1:
        zc = z[cand]
        mu = np.mean(zc)
        sd = np.std(zc, ddof=1)
        if sd > 0:
            kept = cand & (np.abs(z - mu) <= p.k_sigma * sd)
    zk = z[kept]
    row = {"n_photons": n, "n_kept": int(kept.sum())}
    nan = float("nan")
    if zk.size < p.min_photons:
        labels[kept] = LABEL_BETWEEN
        row.update(n_between=0, top=nan, ground=nan, z90=nan, flag="sparse")
        return row, labels
    bs = p.bin_size
    zmin, zmax = zk.min(), zk.max()
    nb = max(1, math.ceil((zmax - zmin) / bs))
    bins = [min(math.floor((v - zmin) / bs), nb - 1) for v in zk]
    hist = [0] * nb
    for b in bins:
        hist[b] += 1
    w = min(p.window_bins, nb)
    # canopy top: window covers bins lo..nb-1, grows downward
    lo = nb - w
    while sum(hist[lo:]) / zk.size < top_c and lo > 0:
        lo -= 1
    # ground: window covers bins 0..hi, grows upward
    hi = w - 1
    while sum(hist[: hi + 1]) / zk.size < ground_c and hi < nb - 1:
        hi += 1
    top = zmin + lo * bs
    ground = zmin + (hi + 1) * bs
    between = sorted(v for v in zk if ground <= v <= top)
    z90 = between[math.floor(0.9 * (len(between) - 1))] if between else nan
    flag = "inverted" if (top <= ground or not between) else "ok"
    row.update(n_between=len(between), top=top, ground=ground, z90=z90, flag=flag)
    lk = np.array([LABEL_GROUND if b <= hi else LABEL_CANOPY if b >= lo else LABEL_BETWEEN
                   for b in bins], np.int8)
    labels[kept] = lk
    return row, labels


def oracle(s, z, conf, p: BlockParams, length: float):
    s0 = float(np.min(s)) if p.s0 is None else p.s0
    top_c, ground_c = p.cutoffs_for(length)
    conf_ok = None if p.min_signal_conf is None else conf >= p.min_signal_conf
    labels = np.full(s.size, -1, np.int8)
    rows = []
    inside = s >= s0
    bidx = np.floor((s - s0) / length)
    for blk in sorted(set(bidx[inside].astype(int).tolist())):
        sel = np.flatnonzero(inside & (bidx == blk))
        row, lab = oracle_block(z[sel], None if conf_ok is None else conf_ok[sel], p,
                                top_c, ground_c)
        row["block"] = blk
        row["x"] = float(np.mean(500000.0 + s[sel]))
        rows.append(row)
        labels[sel] = lab
    return rows, labels


# ----------------------------------------------------------------------------- tracks
def random_track(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """A random track mixing every awkward case; returns s, z, conf, params kwargs."""
    rng = np.random.default_rng(seed)
    length = float(rng.choice([10.0, 25.0, 7.3, 50.0]))
    nblk = int(rng.integers(1, 40))
    parts_s, parts_z = [], []
    for i in range(nblk):
        kind = rng.choice(["empty", "one", "flat", "noise", "canopy", "canopy", "tiny"])
        g = 2000.0 + rng.normal(0, 3)
        if kind == "empty":
            continue
        if kind == "one":
            m = 1
        elif kind == "tiny":
            m = int(rng.integers(2, 12))
        else:
            m = int(rng.integers(5, 300))
        ss = (i + rng.random(m)) * length
        if kind == "flat":
            zz = np.full(m, round(g, 1))
        elif kind == "noise":
            zz = g + rng.uniform(-50, 80, m)
        else:
            h = rng.uniform(2, 30)
            r = rng.random(m)
            zz = np.where(r < 0.4, g + rng.normal(0, 0.3, m),
                          np.where(r < 0.95, g + rng.uniform(0, h, m), g + rng.uniform(-60, 90, m)))
        if rng.random() < 0.5:               # heights on the 0.5 m grid: photons on bin edges
            zz = np.round(zz * 2) / 2
        parts_s.append(ss)
        parts_z.append(zz)
    s = np.concatenate(parts_s) if parts_s else np.array([0.0])
    z = np.concatenate(parts_z) if parts_z else np.array([2000.0])
    # photons exactly on block edges
    k = max(1, s.size // 20)
    pick = rng.choice(s.size, k, replace=False)
    s[pick] = np.floor(s[pick] / length) * length
    order = np.argsort(s, kind="stable")
    s, z = s[order], z[order]
    conf = rng.integers(-2, 5, s.size).astype(np.int8)
    kw: dict = {"lengths": (length,)}
    if rng.random() < 0.3:
        kw["s0"] = float(rng.choice([s.min(), s.min() + length * 1.5, -length]))
    kw["min_photons"] = int(rng.choice([1, 3, 10]))
    if rng.random() < 0.2:
        kw["noise"] = "none"
    if rng.random() < 0.2:
        kw["min_signal_conf"] = int(rng.integers(-1, 4))
    if rng.random() < 0.4:
        # random fractions, and fractions whose product with n is not exact in float64
        kw["top_cutoff"] = float(rng.choice([rng.uniform(0.01, 0.6), 0.07, 0.1, 0.3, 0.6]))
        kw["ground_cutoff"] = float(rng.choice([rng.uniform(0.01, 0.6), 0.07, 0.15, 0.2]))
    if rng.random() < 0.2:
        kw["k_sigma"] = float(rng.choice([1.0, 2.0, 3.0]))
    return s, z, conf, kw


MAX_TREE_M = 130.0  # taller than any tree: the engine flags such 'ok' blocks 'implausible'


def expected_flags(rows) -> list[str]:
    """The paper's flags, plus 'implausible' for its 'ok' blocks taller than any tree."""
    return ["implausible" if r["flag"] == "ok" and r["top"] - r["ground"] > MAX_TREE_M
            else r["flag"] for r in rows]


def make_track(s, z, conf) -> PhotonTrack:
    return PhotonTrack(time=s.copy(), lat=np.zeros_like(s), lon=np.zeros_like(s), h=z,
                       x=500000.0 + s, y=np.full_like(s, 4_000_000.0), s=s, track="gt1r",
                       crs=CRS, signal_conf=conf)


def run_engine(track, params):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SparseBlockWarning)
        return compute_blocks(track, params, labels=True)


def assert_same(rows, labels_or, got, labels_got, length):
    assert list(got["block"]) == [r["block"] for r in rows]
    for col in ("n_photons", "n_kept", "n_between"):
        assert list(got[col]) == [r[col] for r in rows], col
    for col in ("top", "ground", "z90"):
        np.testing.assert_array_equal(got[col].to_numpy(), np.array([r[col] for r in rows]),
                                      err_msg=col)
    assert list(got["flag"]) == expected_flags(rows)
    np.testing.assert_allclose(got["x"].to_numpy(), [r["x"] for r in rows], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(labels_got[length], labels_or)


@pytest.fixture(params=["auto", "sorted"])
def histogram_mode(request, monkeypatch):
    """Run every oracle comparison with dense histograms and with sorted keys."""
    if request.param == "sorted":
        monkeypatch.setattr(hist_mod, "DENSE_FACTOR", 0)
        monkeypatch.setattr(hist_mod, "DENSE_FLOOR", -1)
    return request.param


@pytest.mark.parametrize("seed", range(60))
def test_engine_matches_oracle(seed, histogram_mode):
    s, z, conf, kw = random_track(seed)
    params = BlockParams(**kw)
    length = params.lengths[0]
    rows, lab = oracle(s, z, conf, params, length)
    got, labels = run_engine(make_track(s, z, conf), params)
    assert_same(rows, lab, got, labels, length)


def test_oracle_covers_the_awkward_cases():
    """The random tracks really contain what the oracle test claims to cover."""
    seen = {"sparse": 0, "inverted": 0, "ok": 0, "flat": 0, "one": 0, "edge_s": 0, "edge_z": 0}
    for seed in range(60):
        s, z, conf, kw = random_track(seed)
        p = BlockParams(**kw)
        rows, _ = oracle(s, z, conf, p, p.lengths[0])
        for r in rows:
            seen[r["flag"]] += 1
            seen["one"] += r["n_photons"] == 1
        s0 = s.min() if p.s0 is None else p.s0
        seen["edge_s"] += int(np.sum(((s - s0) / p.lengths[0]) % 1 == 0))
        seen["edge_z"] += int(np.sum((z * 2) % 1 == 0))
        bidx = np.floor((s - s0) / p.lengths[0])
        for b in np.unique(bidx):
            zb = z[bidx == b]
            seen["flat"] += zb.size > 1 and np.ptp(zb) == 0
    assert all(v > 0 for v in seen.values()), seen


def test_several_lengths_in_one_run_match_single_runs(histogram_mode):
    s, z, conf, _ = random_track(123)
    both, _ = run_engine(make_track(s, z, conf), BlockParams(lengths=(10.0, 25.0)))
    assert list(both["length"].unique()) == [10.0, 25.0]
    for length in (10.0, 25.0):
        p = BlockParams(lengths=(length,))
        rows, lab = oracle(s, z, conf, p, length)
        got = both[both["length"] == length].reset_index(drop=True)
        one, labels = run_engine(make_track(s, z, conf), p)
        assert_same(rows, lab, got, labels, length)


def test_unsorted_track_and_nan_photons_match_oracle():
    """Photons given out of s order, and photons with NaN height, lie where they should."""
    s, z, conf, kw = random_track(7)
    params = BlockParams(**kw)
    length = params.lengths[0]
    rows, lab = oracle(s, z, conf, params, length)
    rng = np.random.default_rng(3)
    perm = rng.permutation(s.size)
    s2 = np.append(s[perm], [s.max(), s.min()])
    z2 = np.append(z[perm], [np.nan, np.nan])
    c2 = np.append(conf[perm], [4, 4]).astype(np.int8)
    tr = make_track(s2, z2, c2)
    from canopyblocks.errors import CanopyBlocksWarning

    with pytest.warns(CanopyBlocksWarning, match="NaN"):
        got, labels = run_engine(tr, params)
    expect_lab = np.full(s2.size, -1, np.int8)
    expect_lab[: s.size] = lab[perm]
    # x is the mean of the block's photons: same set, so allclose
    assert list(got["n_photons"]) == [r["n_photons"] for r in rows]
    for col in ("top", "ground", "z90"):
        np.testing.assert_array_equal(got[col].to_numpy(), [r[col] for r in rows])
    np.testing.assert_array_equal(labels[length], expect_lab)


def test_top_bin_clipping_in_a_few_blocks(monkeypatch):
    """Blocks whose height span is a whole number of bins put the top photon in bin nb - 1.

    When few blocks need that clip the engine fixes only their photons; the oracle
    must still agree (and the test checks that this path ran).
    """
    rng = np.random.default_rng(11)
    s = np.sort(rng.uniform(0, 40 * 25.0, 8000))
    z = 900.0 + rng.uniform(0, 25, s.size)
    blk = np.floor((s - s.min()) / 25.0)
    for b in (3, 17):
        # two blocks with heights 900.0, 900.5, 901.0 only: span 1 m = exactly nb = 2 bins,
        # so the photons at 901.0 (floor(2.0) = 2) belong in bin 1; a ground cut-off of 0.9
        # makes the ground window stop on them
        sel = np.flatnonzero(blk == b)
        z[sel] = 900.0 + rng.integers(0, 3, sel.size) * 0.5
        z[sel[:2]] = [900.0, 901.0]
    calls = []
    orig = hist_mod._ranges
    monkeypatch.setattr(hist_mod, "_ranges", lambda *a: calls.append(1) or orig(*a))
    conf = np.full(s.size, 4, np.int8)
    params = BlockParams(lengths=(25.0,), noise="none", ground_cutoff=0.9)
    rows, lab = oracle(s, z, conf, params, 25.0)
    assert rows[3]["ground"] == 901.0      # upper edge of bin 1 (nb = 2: window = all)
    got, labels = run_engine(make_track(s, z, conf), params)
    assert calls, "the partial clip path did not run"
    assert_same(rows, lab, got, labels, 25.0)


def test_real_atl03_clip_matches_oracle_and_atl08(sample):
    """Real ICESat-2 photons (ATL03 v006, Wyoming conifers; shared/data/README.md).

    The engine agrees with the oracle on real float32 heights and signal_conf_ph, and
    its ground/top sit near NASA's own ATL08 classification of the same photons: the
    median ground photon and the 98th percentile of canopy photons per block.
    """
    import pandas as pd

    from canopyblocks.readers.atl03 import read_atl03

    track = read_atl03(sample("icesat2/vegr_atl03_clip.h5"), "gt1r",
                       atl08=sample("icesat2/vegr_atl08_clip.h5"))
    assert track.signal_conf is not None and track.classification is not None
    length = 25.0
    params = BlockParams(lengths=(length,), min_signal_conf=2)
    rows, lab = oracle(track.s, track.h, track.signal_conf, params, length)
    got, labels = run_engine(track, params)
    assert list(got["n_photons"]) == [r["n_photons"] for r in rows]
    for col in ("n_kept", "n_between"):
        assert list(got[col]) == [r[col] for r in rows], col
    for col in ("top", "ground", "z90"):
        np.testing.assert_array_equal(got[col].to_numpy(), [r[col] for r in rows])
    np.testing.assert_array_equal(labels[length], lab)

    blk = np.floor((track.s - track.s.min()) / length).astype(int)
    g = track.classification == 1
    c = track.classification >= 2
    atl08_ground = pd.Series(track.h[g]).groupby(blk[g]).median()
    atl08_top = pd.Series(track.h[c]).groupby(blk[c]).quantile(0.98)
    ok = got[got["flag"] == "ok"].set_index("block")
    assert len(ok) >= 25                                  # of 33 blocks
    dg = (ok["ground"] - atl08_ground.reindex(ok.index)).dropna()
    dt = (ok["top"] - atl08_top.reindex(ok.index)).dropna()
    assert len(dg) >= 25 and len(dt) >= 25
    assert dg.abs().median() < 1.0                         # measured 0.46 m
    assert dt.abs().median() < 4.0                         # measured 2.3 m
