"""The dual-wavelength footprint reference reads its pairs as the footprints' were: a
simulation scored against its own reference, at the paper's noise and noise free."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from canopyblocks.readers.flash_dual import read_dual_file
from canopyblocks.readers.las import read_las
from canopyblocks.reference.dual_reference import DualFormParams, dual_reference
from canopyblocks.simulate.sensor_files import DualAlsParams, simulate_sensor_over_tiles
from canopyblocks.validation.flash_footprints import validate_sensor_footprints
from canopyblocks.workflows.waveforms_flash_dual import dual_footprints


def _simulated(sample, tmp_path, noise):
    tiles = [sample("als/lasR_bcts_1.laz"), sample("als/lasR_bcts_2.laz")]
    path = tmp_path / f"dual{noise}.h5"
    simulate_sensor_over_tiles(tiles, "dual", path, azimuth=100.0, seed=2,
                               params=DualAlsParams(noise=noise))
    return tiles, path, dual_footprints(path)


def test_noise_free_simulation_matches_its_reference(sample, tmp_path):
    tiles, path, fp = _simulated(sample, tmp_path, 0.0)
    assert fp.attrs["noise"] == 0.0
    res = validate_sensor_footprints(fp, tiles, offset=0.0).residuals
    used = res[res["use"]]
    # every footprint the pair's reading kept is in use (5 % thresholds lost 3 of 17 and
    # put the ground 7.9 m off)
    assert len(used) == len(fp) == 17
    d = np.abs(used[["res_ground", "res_height", "res_top"]].to_numpy(float))
    # the same pair at the same centres read alike: zero (5 % thresholds said +7.9 m)
    np.testing.assert_allclose(d, 0.0, atol=1e-6)
    # at the file's own centres the reference reads exactly the pairs the file holds
    f = read_dual_file(path)
    pts = read_las(tiles)
    ref = dual_reference(pts, f.x, f.y, DualFormParams(noise=0.0, bin_size=f.bin_size))
    assert (ref["ref_waveform_flag"] == "ok").all()
    np.testing.assert_allclose(ref["ref_ground"], fp["ground"], atol=1e-9)
    np.testing.assert_allclose(ref["ref_height"], fp["height"], atol=1e-9)
    # unrounded (as before the file's float32 was applied) every footprint keeps its ground
    # too: a canopy of one constant ratio is no edge (its gradients are float rounding)
    raw = dual_reference(pts, f.x, f.y, DualFormParams(noise=0.0), stored=np.float64)
    assert (raw["ref_waveform_flag"] == "ok").all()
    assert np.abs(raw["ref_ground"].to_numpy(float) - fp["ground"].to_numpy(float)).max() < 0.5


def test_paper_noise_simulation_near_its_reference(sample, tmp_path):
    tiles, _, fp = _simulated(sample, tmp_path, 0.05)
    assert fp.attrs["noise"] == 0.05
    res = validate_sensor_footprints(fp, tiles, offset=0.0).residuals
    used = res[res["use"]]
    assert len(used) >= 3
    assert np.median(np.abs(used["res_ground"].to_numpy(float))) < 0.5


def test_layer_without_noise_level_warns(sample, tmp_path, caplog):
    tiles, _, fp = _simulated(sample, tmp_path, 0.0)
    fp.attrs.clear()
    with caplog.at_level(logging.WARNING):
        try:
            validate_sensor_footprints(fp, tiles, offset=0.0)
        except Exception as e:  # noqa: BLE001 - the project's errors only
            pytest.fail(f"raised {e!r}")
    assert "noise level" in caplog.text
