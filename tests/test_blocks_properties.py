"""Properties of the block engine that must hold for any input (hypothesis)."""

from __future__ import annotations

import warnings

import numpy as np
import pyproj
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canopyblocks import PhotonTrack
from canopyblocks.blocks import LABEL_OUTSIDE, BlockParams, compute_blocks
from canopyblocks.errors import SparseBlockWarning
from canopyblocks.schema import LABEL_BETWEEN, LABEL_CANOPY, LABEL_GROUND, LABEL_NOISE

CRS = pyproj.CRS.from_epsg(32633)


@st.composite
def tracks(draw):
    """Photons on a grid of s (m) and z (m), so ties and edge hits are common."""
    n = draw(st.integers(1, 250))
    s = np.array(draw(st.lists(st.integers(0, 4000), min_size=n, max_size=n)), float) * 0.05
    z = np.array(draw(st.lists(st.integers(-200, 400), min_size=n, max_size=n)), float) * 0.1
    z += draw(st.sampled_from([0.0, 1500.0]))
    params = BlockParams(
        lengths=tuple(draw(st.sets(st.sampled_from([5.0, 10.0, 25.0, 33.3]), min_size=1,
                                   max_size=3))),
        min_photons=draw(st.integers(1, 12)),
        noise=draw(st.sampled_from(["sigma", "none"])),
        top_cutoff=draw(st.one_of(st.none(), st.floats(0.01, 0.9))),
        ground_cutoff=draw(st.one_of(st.none(), st.floats(0.01, 0.9))),
    )
    return s, z, params


def _track(s, z):
    return PhotonTrack(time=s.copy(), lat=np.zeros_like(s), lon=np.zeros_like(s), h=z,
                       x=400000.0 + s, y=np.full_like(s, 5_000_000.0) + 0.1 * s, s=s,
                       track="gt3r", crs=CRS)


def _run(s, z, params):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SparseBlockWarning)
        return compute_blocks(_track(s, z), params, labels=True)


SETTINGS = settings(max_examples=100, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(tracks(), st.randoms(use_true_random=False))
def test_unchanged_by_photon_order(data, rnd):
    s, z, params = data
    base, lab = _run(s, z, params)
    perm = np.array(rnd.sample(range(s.size), s.size))
    other, lab2 = _run(s[perm], z[perm], params)
    cols = ["length", "block", "n_photons", "n_kept", "n_between", "top", "ground", "z90",
            "flag"]
    assert base[cols].equals(other[cols])
    np.testing.assert_allclose(base["x"], other["x"], rtol=0, atol=1e-6)
    for length in params.lengths:
        np.testing.assert_array_equal(lab[length][perm], lab2[length])


@SETTINGS
@given(tracks())
def test_counts_add_up_and_ground_below_top(data):
    s, z, params = data
    out, labels = _run(s, z, params)
    s0 = s.min()
    for length in params.lengths:
        rows = out[out["length"] == length]
        # every photon is in exactly one block of each length (s0 = track start)
        assert rows["n_photons"].sum() == s.size
        assert (rows["n_kept"] <= rows["n_photons"]).all()
        assert (rows["n_between"] <= rows["n_kept"]).all()
        assert rows["block"].is_monotonic_increasing and rows["block"].is_unique
        np.testing.assert_array_equal(np.floor((s - s0) / length).max(), rows["block"].max())
        lab = labels[length]
        assert (lab != LABEL_OUTSIDE).all()
        assert np.count_nonzero(lab != LABEL_NOISE) == rows["n_kept"].sum()
        ok = rows[rows["flag"] == "ok"]
        assert (ok["ground"] < ok["top"]).all()
        assert (ok["n_between"] > 0).all()
        assert (ok["ground"] <= ok["z90"]).all() and (ok["z90"] <= ok["top"]).all()
        assert ((ok["h90"] >= 0) & (ok["h90"] <= ok["hmax"])).all()
        sparse = rows[rows["flag"] == "sparse"]
        assert (sparse["n_kept"] < params.min_photons).all()
        assert sparse["top"].isna().all()
        assert (rows.loc[rows["flag"] != "sparse", "n_kept"] >= params.min_photons).all()
        # top/ground lie on the 0.5 m grid of the block's lowest kept photon, inside its span
        valid = rows[rows["flag"] != "sparse"]
        assert valid["top"].notna().all() and valid["ground"].notna().all()
        assert set(np.unique(lab)) <= {LABEL_NOISE, LABEL_GROUND, LABEL_CANOPY, LABEL_BETWEEN}


@SETTINGS
@given(tracks())
def test_noise_none_keeps_everything_and_sigma_never_adds(data):
    s, z, params = data
    from dataclasses import replace

    none, _ = _run(s, z, replace(params, noise="none"))
    sig, _ = _run(s, z, replace(params, noise="sigma"))
    assert (none["n_kept"] == none["n_photons"]).all()
    assert (sig["n_kept"] <= none["n_kept"]).all()
    assert (sig["n_kept"] >= 1).all()          # k = 2.5 >= 1 always keeps a photon
