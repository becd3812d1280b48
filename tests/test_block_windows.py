"""The engine run window by window equals the engine run over the whole track, value for
value, on random tracks with every block length and window size (windows smaller than a
block included), sorted or not, with NaN photons, confidence filter and labels."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from pyproj import CRS

from canopyblocks.blocks import BlockParams, compute_blocks
from canopyblocks.blocks.windows import window_cuts
from canopyblocks.photons import PhotonTrack

pytestmark = pytest.mark.filterwarnings("ignore::canopyblocks.errors.CanopyBlocksWarning")

LENGTH_SETS = [(25.0,), (10.0, 25.0, 100.0), (7.0, 30.0), (0.7, 3.3, 12.5), (1000.0,)]
WINDOWS = [1, 2, 7, 100, 999, 5000, 10**7]


def _track(seed: int, n: int, shuffled: bool = False, bad: bool = False) -> PhotonTrack:
    rng = np.random.default_rng(seed)
    s = np.sort(rng.random(n)) * rng.uniform(200, 3000) + rng.uniform(0, 50)
    # clumps and gaps along the track, like cloud cover
    s = np.where(rng.random(n) < 0.1, np.round(s, 0), s)
    ground = 300 + 15 * np.sin(s / 90)
    u = rng.random(n)
    h = ground + np.where(u < 0.5, rng.normal(0, 0.4, n),
                          np.where(u < 0.85, rng.random(n) * 20, rng.uniform(-30, 50, n)))
    x = 500_000 + s * 0.1
    y = 4_600_000 + s
    conf = np.where(u < 0.85, 4, rng.integers(0, 3, n)).astype(np.int8)
    if bad:
        h[rng.random(n) < 0.01] = np.nan
    if shuffled:
        p = rng.permutation(n)
        s, h, x, y, conf = s[p], h[p], x[p], y[p], conf[p]
    return PhotonTrack(time=s / 7000.0, lat=41.5 + y * 0.0, lon=-105.0 + x * 0.0, s=s, h=h,
                       x=x, y=y, crs=CRS.from_epsg(32613), track=f"t{seed}",
                       signal_conf=conf)


def _equal(a: pd.DataFrame, b: pd.DataFrame) -> None:
    pd.testing.assert_frame_equal(pd.DataFrame(a.drop(columns="geometry")),
                                  pd.DataFrame(b.drop(columns="geometry")), check_exact=True)


@pytest.mark.parametrize("lengths", LENGTH_SETS)
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_windows_equal_whole_track(lengths, seed):
    track = _track(seed, 6000, shuffled=seed == 2, bad=seed == 3)
    params = BlockParams(lengths=lengths, min_signal_conf=3 if seed == 1 else None,
                         noise="none" if seed == 3 else "sigma")
    whole, lab_whole = compute_blocks(track, params, labels=True, window_photons=None)
    assert (whole["flag"] == "ok").sum() > 0
    for window in WINDOWS:
        win, lab_win = compute_blocks(track, params, labels=True, window_photons=window)
        _equal(whole, win)
        for length in lengths:
            np.testing.assert_array_equal(lab_whole[length], lab_win[length])


def test_cuts_fall_on_block_boundaries_of_every_length():
    """Brute force: at each cut, the photon before and the photon after lie in different
    blocks of every length (block = floor((s - s0) / L) computed one by one in Python)."""
    import math

    track = _track(4, 3000)
    s = np.sort(track.s)
    s0 = float(s[0])
    lengths = (10.0, 25.0, 100.0)
    cuts = window_cuts(s, s0, lengths, 200)
    assert cuts[0] == 0 and cuts[-1] == s.size and len(cuts) > 5
    assert np.all(np.diff(cuts) > 0)
    for c in cuts[1:-1]:
        for length in lengths:
            assert math.floor((s[c] - s0) / length) != math.floor((s[c - 1] - s0) / length)
    # every window holds at least the target, except the last
    assert np.all(np.diff(cuts)[:-1] >= 200)
