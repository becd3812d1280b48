"""The fast paths of the ATL08-style classifier give the same bits as slow, plain ones.

- the density filter's box counts (many segments' grids stacked in one summed-area table,
  in groups and stacks of any size) equal a pair-by-pair count on each segment's grid;
- the ground surface, whose later passes look only at photons that can still weigh, in
  chunks, equals the plain loop over every photon in every pass (the fit as first written);
- the grouped sort equals ``np.lexsort``;
- the classes of a small fixed-seed track equal those of the classifier before it was
  made fast (a hash of them, recorded from that version).

Every test runs twice: with the compiled loops (numba; skipped where it is missing) and
with the numpy code they replace (``CANOPYBLOCKS_NUMBA=0``); the last tests compare the two
directly, on day and night tracks with known and estimated background.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pyproj
import pytest

import canopyblocks.blocks.atl08_surface as surface_mod
import canopyblocks.blocks.density_filter as density_mod
from canopyblocks.blocks.atl08_classify import classify_photons
from canopyblocks.blocks.atl08_surface import SurfaceParams, _start, fit_atl08_surface
from canopyblocks.blocks.density_filter import DensityParams, density_filter
from canopyblocks.blocks.ground_surface import _bridge, _kernel, _local_linear
from canopyblocks.blocks.grouped import sorted_groups
from canopyblocks.errors import NoUsableDataError
from canopyblocks.photons import SPEED_OF_LIGHT, BackgroundRate, PhotonTrack
from test_atl08_speed import _brute_counts  # the one brute-force box count

UTM = pyproj.CRS.from_epsg(32612)


@pytest.fixture(autouse=True, params=["numba", "numpy"])
def path(request, monkeypatch):
    """Each test with the compiled loops and with the numpy ones."""
    if request.param == "numba":
        pytest.importorskip("numba")
        monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "1")
    else:
        monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "0")
    return request.param


def _forest(seed: int, n_shots: int = 4000, rate_mhz: float = 3.0
            ) -> tuple[np.ndarray, np.ndarray]:
    """s, h of a strong beam over a sloped forest with background in a 150 m window."""
    rng = np.random.default_rng(seed)
    shots = np.arange(n_shots) * 0.7
    ss = np.repeat(shots, rng.poisson(2.0, n_shots))
    g = 100.0 + 0.1 * ss + 3.0 * np.sin(ss / 80.0)
    can = (np.sin(ss / 40.0) > -0.2) & (rng.random(ss.size) < 0.6)
    hs = np.where(can, g + rng.uniform(2.5, 18.0, ss.size), g + rng.normal(0, 0.25, ss.size))
    sn = np.repeat(shots, rng.poisson(rate_mhz * 1e6 * 2 / SPEED_OF_LIGHT * 150.0, n_shots))
    hn = 100.0 + 0.1 * sn + rng.uniform(-60.0, 90.0, sn.size)
    s = np.concatenate([ss, sn]) + rng.uniform(-0.1, 0.1, ss.size + sn.size)
    return s, np.concatenate([hs, hn])




@pytest.mark.parametrize("entries, cells", [(1 << 20, 1 << 22), (3000, 1), (1, 50_000)])
def test_stacked_box_counts_equal_brute_force(monkeypatch, entries, cells):
    # one stack for everything; one grid a stack; one segment a group
    monkeypatch.setattr(density_mod, "_ENTRIES", entries)
    monkeypatch.setattr(density_mod, "_CELLS", cells)
    s, z = _forest(5, n_shots=1500)
    for p in (DensityParams(along=10.0, height=1.5, quantile=0.999, segment=200.0),
              DensityParams(along=40.0, height=4.0, quantile=0.99, segment=100.0, cells=3)):
        res = density_filter(s, z, p)
        assert np.array_equal(res.count, _brute_counts(s, z, p))
        assert np.array_equal(res.keep, res.count - 1 > res.threshold)


def _plain_surface(s: np.ndarray, z: np.ndarray, p: SurfaceParams) -> tuple[np.ndarray, ...]:
    """fit_atl08_surface as first written: every photon in every pass."""
    order = np.argsort(s, kind="stable")
    ss, zz = s[order], z[order]
    nodes = np.arange(ss[0], ss[-1] + 1.0, 1.0)
    surf = _start(ss, zz, p, nodes)
    kernel = _kernel(p.bandwidth, 1.0)
    support = np.zeros(nodes.size)
    w = np.zeros(ss.size)
    for k, band in enumerate(p.bands):
        r = zz - np.interp(ss, nodes, surf)
        u = r / np.hypot(band, np.zeros(ss.size))
        w = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
        if k < len(p.bands) - 1:
            w = np.where(r > 0, w * p.above_weight, w)
        if not (w > 0).any():
            break
        level, support = _local_linear(ss, zz, w, nodes, 1.0, kernel)
        try:
            surf = _bridge(nodes, level, support >= p.min_support)
        except NoUsableDataError:
            break
    used = np.zeros(s.size, bool)
    used[order] = w > 0
    return nodes, surf, support >= p.min_support, used


@pytest.mark.parametrize("chunk", [1 << 16, 97])
@pytest.mark.parametrize("presorted", [False, True])
@pytest.mark.parametrize("reserve", [1.0, 0.05, 0.0])
@pytest.mark.parametrize("bands", [(3.0, 2.0, 1.0, 0.6), (1.0, 0.6), (0.6, 2.0, 0.3)])
def test_surface_passes_on_fewer_photons_are_the_same(monkeypatch, reserve, bands, presorted,
                                                      chunk):
    # reserve 0: every pass over all photons; 0.05 m: the photons looked at again often;
    # chunk 97: each pass in many chunks (cut between nodes)
    monkeypatch.setattr(surface_mod, "_RESERVE", reserve)
    monkeypatch.setattr(surface_mod, "_CHUNK", chunk)
    s, z = _forest(6, n_shots=3000, rate_mhz=0.03)
    if presorted:  # (as read from a file: then the fit works on the arrays themselves)
        o = np.argsort(s, kind="stable")
        s, z = s[o], z[o]
    p = SurfaceParams(bands=bands)
    got = fit_atl08_surface(s, z, p)
    want = _plain_surface(s, z, p)
    for a, b in zip((got.s, got.z, got.supported, got.candidates), want):
        assert np.array_equal(a, b)


def test_grouped_sort_equals_lexsort():
    rng = np.random.default_rng(8)
    for n, groups in ((2000, 7), (200_000, 70_000), (50, 1)):
        g = rng.integers(0, groups, n)
        v = np.round(rng.normal(0, 3, n), 1)  # many ties
        order, vs, starts, counts = sorted_groups(g, v, groups)
        ref = np.lexsort((v, g))
        assert np.array_equal(g[order], g[ref]) and np.array_equal(vs, v[ref])
        assert np.array_equal(counts, np.bincount(g, minlength=groups))


def test_classes_pinned_to_the_classifier_before_it_was_fast():
    s, z = _forest(7)
    o = np.argsort(s, kind="stable")
    s, z = s[o], z[o]
    t = s / 7000.0
    n = s.size
    for rate, want in ((3e6, PINNED_KNOWN_RATE), (None, PINNED_ESTIMATED)):
        bg = (None if rate is None
              else BackgroundRate(np.array([0.0, float(t.max()) + 1.0]), np.array([rate] * 2)))
        track = PhotonTrack(time=t, lat=np.zeros(n), lon=np.zeros(n), h=z, x=s.copy(),
                            y=np.zeros(n), s=s, track="gt1l", crs=UTM, background=bg)
        c = classify_photons(track)
        digest = hashlib.sha256(c.classes.tobytes()).hexdigest()
        assert digest[:16] == want


# sha256 (first 16 hex digits) of the classes (int8) from the classifier before it was
# made fast (counts: noise 10821 / 10833, ground 5299, canopy 3291 / 3274, top 597 / 602)
PINNED_KNOWN_RATE = "43136af316562db9"
PINNED_ESTIMATED = "1e53e1571a6f7aca"


@pytest.mark.parametrize("far", [False, True])
def test_block_rows_equal_a_sorted_search(far):
    from canopyblocks.blocks.atl08_blocks import _row_of_block

    rng = np.random.default_rng(9)
    nums = np.unique(rng.integers(-50, 400, 200))
    if far:  # a block far away: the lookup table would be huge, so it searches
        nums = np.append(nums, 10**12)
    bidx = np.floor(rng.uniform(-80, 450, 5000))
    bidx[::97] = np.nan
    ok = rng.random(bidx.size) < 0.9
    pos = np.searchsorted(nums, bidx)
    hit = ok & (pos < len(nums)) & (nums[np.minimum(pos, len(nums) - 1)] == bidx)
    assert np.array_equal(_row_of_block(nums, bidx, ok), np.where(hit, pos, -1))


def _both(monkeypatch, fn):
    """fn() with the numpy loops, then with the compiled ones."""
    monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "0")
    a = fn()
    monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "1")
    return a, fn()


@pytest.mark.parametrize("rate_mhz", [0.15, 3.0])
def test_compiled_loops_give_the_numpy_bits(monkeypatch, path, rate_mhz):
    pytest.importorskip("numba")
    from canopyblocks.blocks import kernels

    if path == "numpy":
        pytest.skip("one comparison is enough")
    assert kernels.enabled()
    s, z = _forest(11, n_shots=5000, rate_mhz=rate_mhz)
    for p in (DensityParams(), DensityParams(along=40.0, height=4.0, cells=3,
                                             edge_correction=True)):
        a, b = _both(monkeypatch, lambda p=p: density_filter(s, z, p))
        for x, y in zip((a.keep, a.count, a.rate, a.threshold),
                        (b.keep, b.count, b.rate, b.threshold)):
            assert np.array_equal(x, y)
        if not p.edge_correction:  # (the brute force counts without it)
            assert np.array_equal(b.count, _brute_counts(s, z, p))
    for sp in (SurfaceParams(), SurfaceParams(bands=(0.6, 2.0, 0.3)),
               SurfaceParams(footprint_radius=6.5)):
        a, b = _both(monkeypatch, lambda sp=sp: fit_atl08_surface(s, z, sp))
        for x, y in zip((a.s, a.z, a.supported, a.candidates),
                        (b.s, b.z, b.supported, b.candidates)):
            assert np.array_equal(x, y)
    o = np.argsort(s, kind="stable")
    t = s[o] / 7000.0
    n = s.size
    for rate in (rate_mhz * 1e6, None):
        bg = (None if rate is None
              else BackgroundRate(np.array([0.0, float(t.max()) + 1.0]), np.array([rate] * 2)))
        track = PhotonTrack(time=t, lat=np.zeros(n), lon=np.zeros(n), h=z[o], x=s[o].copy(),
                            y=np.zeros(n), s=s[o], track="gt1l", crs=UTM, background=bg)
        a, b = _both(monkeypatch, lambda track=track: classify_photons(track))
        assert np.array_equal(a.classes, b.classes)
        assert np.array_equal(a.height, b.height, equal_nan=True)


def test_an_oversized_grid_is_refused_the_same_way(monkeypatch):
    from canopyblocks.errors import InputError

    s = np.arange(0.0, 300.0, 0.5)
    z = np.where(np.arange(s.size) == 7, 1e7, 10.0)  # a far outlier: a huge grid
    with pytest.raises(InputError, match="too large; the height range is huge"):
        density_filter(s, z)


@pytest.mark.parametrize("q", [5.0, 50.0, 98.0, 0.0, 100.0])
def test_percentiles_of_runs_equal_numpy(monkeypatch, path, q):
    from canopyblocks.blocks.grouped import percentile_by_group

    rng = np.random.default_rng(12)
    g = np.sort(rng.integers(0, 400, 20_000))
    g = g[g != 7]  # a group without values: NaN
    v = np.round(rng.normal(0, 3, g.size), 1)  # many ties
    got = percentile_by_group(g, v, q, 402)
    want = np.array([np.percentile(v[g == k], q) if np.any(g == k) else np.nan
                     for k in range(402)])
    # (np.percentile interpolates from the upper value past the middle: last bits differ)
    assert np.allclose(got, want, rtol=0, atol=1e-12, equal_nan=True)
    a, b = _both(monkeypatch, lambda: percentile_by_group(g, v, q, 402))
    assert np.array_equal(a, b, equal_nan=True)


def test_compile_cache_goes_to_a_writable_folder(monkeypatch, tmp_path, path):
    # an installed package's folder may be read-only: the cache then goes to the user's
    import os
    from pathlib import Path

    from canopyblocks.blocks import kernels

    if path == "numba":
        pytest.skip("one check is enough")
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    here = Path(kernels.__file__).resolve().parent
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, m: False if Path(p) == here else real(p, m))
    kernels._cache_dir()
    assert os.environ["NUMBA_CACHE_DIR"] == str(tmp_path / "canopyblocks" / "numba")
    assert (tmp_path / "canopyblocks" / "numba").is_dir()
