"""The compiled loops' guards: a far height outlier is refused in one line with numba and
without (the compiled box counts would index outside their grid), and a machine where
numba cannot cache its code runs the numpy code instead of failing."""

from __future__ import annotations

import numpy as np
import pytest

from canopyblocks.blocks import kernels
from canopyblocks.blocks.density_filter import density_filter
from canopyblocks.errors import InputError


def _track(outlier: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    s = np.sort(rng.random(1000) * 100.0)
    z = rng.normal(0.0, 1.0, 1000)
    z[5] = outlier
    return s, z


@pytest.mark.parametrize("numba", ["1", "0"])
@pytest.mark.parametrize("outlier", [3e9, 1e300])
def test_far_outlier_refused_both_ways(monkeypatch, numba, outlier) -> None:
    monkeypatch.setenv("CANOPYBLOCKS_NUMBA", numba)
    s, z = _track(outlier)
    with pytest.raises(InputError, match="too large"):
        density_filter(s, z)


def test_both_ways_agree_on_a_plain_track(monkeypatch) -> None:
    s, z = _track(3.0)
    monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "0")
    a = density_filter(s, z)
    monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "1")
    b = density_filter(s, z)
    assert np.array_equal(a.count, b.count) and np.array_equal(a.keep, b.keep)


def test_no_cache_folder_falls_back_to_numpy(monkeypatch) -> None:
    def refuse(name: str):  # what numba says where no folder can hold its cache
        raise RuntimeError("cannot cache function '_interp_at': no locator available")

    monkeypatch.setattr(kernels, "_STATE", {})
    monkeypatch.setattr(kernels.importlib, "import_module", refuse)
    monkeypatch.setenv("CANOPYBLOCKS_NUMBA", "1")
    assert kernels.compiled() is None and not kernels.enabled()
    s, z = _track(3.0)
    assert density_filter(s, z).count.sum() > 0
