"""Damaged ATL03 background rates (``gtXX/bckgrd_atlas``) on the real clip: the reader never
fails on them and never passes a damaged rate on; the ATL08-style classifier then estimates
the rate from the photons (as for a file without the group)."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from canopyblocks.blocks.atl08_classify import classify_photons
from canopyblocks.errors import CanopyBlocksWarning
from canopyblocks.readers import read_atl03
from canopyblocks.readers.atl03_background import RATE_LIMIT_HZ

CLIP = Path("tests/data/icesat2/vegr_atl03_clip.h5")
G = "gt1r/bckgrd_atlas"


def _set(name: str, fn):  # noqa: ANN001, ANN202
    def edit(f: h5py.File) -> None:
        data = f[name][()]
        del f[name]
        out = fn(data)
        if out is not None:
            f[name] = out
    return edit


def _values(value: float, share: float):  # noqa: ANN202
    def fn(a: np.ndarray) -> np.ndarray:
        a = a.astype(np.float64)
        k = max(1, int(share * a.size))
        a[np.random.default_rng(1).choice(a.size, k, replace=False)] = value
        return a
    return fn


DAMAGE = {
    "rate-deleted": (_set(f"{G}/bckgrd_rate", lambda a: None), "none"),
    "time-deleted": (_set(f"{G}/delta_time", lambda a: None), "none"),
    "group-deleted": (lambda f: f.__delitem__(G), "none"),
    "rate-short": (_set(f"{G}/bckgrd_rate", lambda a: a[:-3]), "none"),
    "rate-2d": (_set(f"{G}/bckgrd_rate", lambda a: np.stack([a, a], 1)), "none"),
    "rate-nan-all": (_set(f"{G}/bckgrd_rate", _values(np.nan, 1.0)), "none"),
    "rate-fill-all": (_set(f"{G}/bckgrd_rate", _values(3.4028235e38, 1.0)), "none"),
    "rate-negative-all": (_set(f"{G}/bckgrd_rate", _values(-1.0, 1.0)), "none"),
    "rate-nan-part": (_set(f"{G}/bckgrd_rate", _values(np.nan, 0.3)), "valid"),
    "rate-fill-part": (_set(f"{G}/bckgrd_rate", _values(3.4028235e38, 0.3)), "valid"),
    "rate-inf-part": (_set(f"{G}/bckgrd_rate", _values(np.inf, 0.3)), "valid"),
    "time-nan-part": (_set(f"{G}/delta_time", _values(np.nan, 0.3)), "valid"),
    "time-far-away": (_set(f"{G}/delta_time", lambda a: a + 1e6), "none"),
    "time-reversed": (_set(f"{G}/delta_time", lambda a: a[::-1].copy()), "valid"),
    "rate-empty": (_set(f"{G}/bckgrd_rate", lambda a: a[:0]), "none"),
}


@pytest.mark.parametrize("case", sorted(DAMAGE))
def test_damaged_background_rate(tmp_path, case):
    edit, expect = DAMAGE[case]
    path = tmp_path / f"{case}.h5"
    shutil.copy(CLIP, path)
    with h5py.File(path, "r+") as f:
        edit(f)
    if expect == "none":  # said, and counted from the photons of the whole track
        with pytest.warns(CanopyBlocksWarning, match="no usable bckgrd_atlas/bckgrd_rate"):
            track = read_atl03(path, "gt1r")
        assert track.background is not None and track.background.settled
        # the clip's own file rate is 1.5-2.6 MHz (a day pass): the photons' count agrees
        assert 1.0e6 < float(np.median(track.background.rate)) < 3.0e6
    else:
        track = read_atl03(path, "gt1r")
        bg = track.background
        assert bg is not None
        assert np.all(np.isfinite(bg.rate)) and np.all(bg.rate >= 0)
        assert np.all(bg.rate < RATE_LIMIT_HZ) and np.all(np.diff(bg.time) >= 0)
    res = classify_photons(track)
    assert res.rate_source == "bckgrd_rate"
    assert np.all(np.isfinite(res.background)) and (res.classes == 1).sum() > 100
