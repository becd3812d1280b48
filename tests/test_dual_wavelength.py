"""Dual-wavelength ground (seed 004, DESIGN 4.8) on simulated visible/NIR pairs with truth."""

from __future__ import annotations

import numpy as np
import pytest

from canopyblocks.errors import InputError
from canopyblocks.simulate.dual_pairs import DualSimParams, simulate_dual_pairs
from canopyblocks.waveforms.dual_wavelength import DualParams, dual_wavelength_ground


def _centre_error(d, g):
    return d.position_to_elevation(g.centre) - d.ground_centre


@pytest.mark.parametrize("slope", [0.0, 10.0])
@pytest.mark.parametrize("cover", [0.1, 0.5, 0.9])
def test_noise_free_ground_within_one_bin(slope, cover):
    d = simulate_dual_pairs(20, DualSimParams(slope=slope, cover=cover), seed=3)
    g = dual_wavelength_ground(d.visible, d.nir, noise_mean=d.noise_mean, noise_sd=d.noise_sd)
    assert g.found.all()
    err = _centre_error(d, g)
    assert np.abs(err).max() <= d.bin_size + 1e-9, err
    # the start lies at the top of the ground return (its highest point plus the pulse),
    # the end at its bottom
    top = d.position_to_elevation(g.start)
    assert np.all(top >= d.ground_high - d.bin_size)
    assert np.all(d.position_to_elevation(g.end) <= d.ground_low + d.bin_size)


def test_error_grows_with_cover_on_a_30_degree_slope():
    """Seed 004 figure 8: on a 30 degree slope the ground error grows with canopy cover."""
    errs = []
    for i, cover in enumerate((0.1, 0.5, 0.9)):
        d = simulate_dual_pairs(40, DualSimParams(slope=30.0, cover=cover), seed=10 + i)
        g = dual_wavelength_ground(d.visible, d.nir, noise_mean=d.noise_mean,
                                   noise_sd=d.noise_sd)
        assert g.found.mean() >= 0.9
        errs.append(float(np.nanmean(np.abs(_centre_error(d, g)))))
    assert errs[0] < errs[1] < errs[2], errs
    assert errs[0] < 1.0 and errs[2] < 3.0  # metres, like the seed's few-metre errors


def test_with_noise_still_finds_most_grounds():
    d = simulate_dual_pairs(40, DualSimParams(slope=10.0, cover=0.5, noise=0.05), seed=4)
    g = dual_wavelength_ground(d.visible, d.nir, noise_mean=d.noise_mean, noise_sd=d.noise_sd)
    assert g.found.mean() >= 0.8
    assert np.nanmedian(np.abs(_centre_error(d, g))) < 0.5


def test_deterministic_and_validated():
    a = simulate_dual_pairs(5, DualSimParams(noise=0.05), seed=9)
    b = simulate_dual_pairs(5, DualSimParams(noise=0.05), seed=9)
    np.testing.assert_array_equal(a.visible, b.visible)
    np.testing.assert_array_equal(a.nir, b.nir)
    with pytest.raises(InputError, match="cover"):
        DualSimParams(cover=1.5)
    with pytest.raises(InputError, match="wide to narrow"):
        DualParams(widths=(1.0, 2.0))
    with pytest.raises(InputError, match="one shape"):
        dual_wavelength_ground(np.zeros((2, 5)), np.zeros((2, 6)),
                               noise_mean=(np.zeros(2), np.zeros(2)),
                               noise_sd=(np.ones(2), np.ones(2)))
