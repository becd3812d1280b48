"""GEDI L1B/L2A readers on the real subsets (DESIGN 4.1), checked against plain h5py,
and damaged copies that must end in the project's own one-line errors or flags."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from canopyblocks.errors import FileFormatError, InputError, NoUsableDataError
from canopyblocks.readers.gedi import (
    gedi_beam_info,
    gedi_beams,
    is_gedi_l1b,
    iter_gedi_l1b,
    read_gedi_l1b,
)
from canopyblocks.readers.gedi_l2 import read_gedi_l2a, read_gedi_l2b

BEAMS = ("BEAM0001", "BEAM0010", "BEAM0011", "BEAM0101", "BEAM0110", "BEAM1000", "BEAM1011")


def test_l1b_matches_plain_h5py(gedi_l1b: Path) -> None:
    assert is_gedi_l1b(gedi_l1b) and gedi_beams(gedi_l1b) == list(BEAMS)
    info = {b.name: b for b in gedi_beam_info(gedi_l1b)}
    assert info["BEAM0101"].power == "full" and info["BEAM0001"].power == "coverage"
    with h5py.File(gedi_l1b) as f:
        for beam in BEAMS:
            g = f[beam]
            b = read_gedi_l1b(gedi_l1b, beam)
            start = g["rx_sample_start_index"][:].astype(np.int64)
            count = g["rx_sample_count"][:].astype(np.int64)
            rx = g["rxwaveform"][:]
            assert len(b) == len(start) == info[beam].n_shots
            for i in range(len(b)):   # plain per-shot slicing: the independent check
                s = start[i] - start[0]
                np.testing.assert_array_equal(b.waveforms[i, :count[i]], rx[s:s + count[i]])
                assert np.all(b.waveforms[i, count[i]:] == np.float32(b.noise_mean[i]))
            assert b.shot_number.dtype == np.uint64
            np.testing.assert_array_equal(b.shot_number, g["shot_number"][:])
            np.testing.assert_array_equal(b.elev_bin0, g["geolocation/elevation_bin0"][:])
            np.testing.assert_array_equal(b.lon_lastbin, g["geolocation/longitude_lastbin"][:])
            np.testing.assert_array_equal(b.noise_sd, g["noise_stddev_corrected"][:])
            np.testing.assert_array_equal(b.n_samples, count)


def test_chunks_bbox_and_quality(gedi_l1b: Path) -> None:
    whole = read_gedi_l1b(gedi_l1b, "BEAM0101")
    parts = list(iter_gedi_l1b(gedi_l1b, "BEAM0101", chunk_shots=10))
    assert [len(p) for p in parts] == [10] * 7 + [3]
    sn = np.concatenate([p.shot_number for p in parts])
    np.testing.assert_array_equal(sn, whole.shot_number)
    for p in parts:
        where = {int(v): k for k, v in enumerate(whole.shot_number)}
        for j, i in enumerate(where[int(v)] for v in p.shot_number):
            n = whole.n_samples[i]
            np.testing.assert_array_equal(p.waveforms[j, :n], whole.waveforms[i, :n])
    lon, lat = whole.lon_bin0, whole.lat_bin0
    box = (lon.min(), lat.min(), float(np.median(lon)), float(np.median(lat)))
    sub = read_gedi_l1b(gedi_l1b, "BEAM0101", bbox=box)
    inside = (lon >= box[0]) & (lon <= box[2]) & (lat >= box[1]) & (lat <= box[3])
    assert 0 < len(sub) == int(inside.sum()) < len(whole)
    with pytest.raises(NoUsableDataError, match="inside the bbox"):
        read_gedi_l1b(gedi_l1b, "BEAM0101", bbox=(0.0, 0.0, 1.0, 1.0))
    with pytest.raises(InputError, match="bbox must be"):
        read_gedi_l1b(gedi_l1b, "BEAM0101", bbox=(1.0, 0.0, 0.0, 1.0))


def test_l2a_reader(gedi_l2a: Path) -> None:
    d = read_gedi_l2a(gedi_l2a, "BEAM0101")
    with h5py.File(gedi_l2a) as f:
        g = f["BEAM0101"]
        np.testing.assert_array_equal(d["shot_number"].to_numpy(), g["shot_number"][:])
        np.testing.assert_allclose(d["rh98"], g["geolocation/rh_a1"][:, 98] / 100.0)
        np.testing.assert_allclose(d["ground"], g["geolocation/elev_lowestmode_a1"][:])
        sel = read_gedi_l2a(gedi_l2a, "BEAM0101", setting=None)
        np.testing.assert_allclose(sel["rh50"], g["rh"][:, 50])
    assert d["shot_number"].dtype == np.int64
    with pytest.raises(InputError, match="setting must be"):
        read_gedi_l2a(gedi_l2a, setting="a9")


def test_l2b_reader_on_a_file_in_the_l2b_layout(tmp_path: Path) -> None:
    p = tmp_path / "l2b.h5"
    with h5py.File(p, "w") as f:
        g = f.create_group("BEAM0101")
        g["shot_number"] = np.array([2**60 + 1, 2**60 + 2], dtype=np.uint64)
        g["cover"] = np.array([0.25, -9999.0], dtype=np.float32)
        g["pai"] = np.array([1.5, 0.2], dtype=np.float32)
        g["rh100"] = np.array([1520, 800], dtype=np.int16)
        g["l2b_quality_flag"] = np.array([1, 0], dtype=np.uint8)
        g["geolocation/lat_lowestmode"] = np.array([-13.7, -13.71])
        g["geolocation/lon_lowestmode"] = np.array([-44.1, -44.11])
    d = read_gedi_l2b(p)
    assert d["shot_number"].tolist() == [2**60 + 1, 2**60 + 2]   # exact, not via float
    assert d["cover"].iloc[0] == pytest.approx(0.25) and np.isnan(d["cover"].iloc[1])
    assert d["rh100"].tolist() == pytest.approx([15.2, 8.0])


def _copy(src: Path, dst: Path) -> Path:
    shutil.copy(src, dst)
    return dst


def test_damaged_l1b_files(gedi_l1b: Path, tmp_path: Path) -> None:
    # truncated file
    trunc = tmp_path / "trunc.h5"
    trunc.write_bytes(gedi_l1b.read_bytes()[: gedi_l1b.stat().st_size // 3])
    with pytest.raises(FileFormatError, match="trunc.h5"):
        read_gedi_l1b(trunc, "BEAM0101")
    # a dataset missing
    miss = _copy(gedi_l1b, tmp_path / "missing.h5")
    with h5py.File(miss, "a") as f:
        del f["BEAM0101/noise_mean_corrected"]
    with pytest.raises(FileFormatError, match="lacks noise_mean_corrected"):
        read_gedi_l1b(miss, "BEAM0101")
    # start indices beyond rxwaveform
    bad = _copy(gedi_l1b, tmp_path / "bad_start.h5")
    with h5py.File(bad, "a") as f:
        f["BEAM0101/rx_sample_start_index"][5] = 10**9
    with pytest.raises(FileFormatError, match="do not match rxwaveform"):
        read_gedi_l1b(bad, "BEAM0101")
    # arrays of different lengths
    short = _copy(gedi_l1b, tmp_path / "short.h5")
    with h5py.File(short, "a") as f:
        a = f["BEAM0101/delta_time"][:-3]
        del f["BEAM0101/delta_time"]
        f["BEAM0101/delta_time"] = a
    with pytest.raises(FileFormatError, match="disagree"):
        read_gedi_l1b(short, "BEAM0101")
    # unknown beam, and not a GEDI file
    with pytest.raises(InputError, match="no beam 'BEAM9999'.*BEAM0001"):
        read_gedi_l1b(gedi_l1b, "BEAM9999")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = [1]
    with pytest.raises(FileFormatError, match="not a GEDI L1B"):
        read_gedi_l1b(other, "BEAM0101")


def test_zero_sample_and_all_noise_shots_are_flagged(gedi_l1b: Path, tmp_path: Path) -> None:
    from canopyblocks.waveforms.process import process_waveforms

    p = _copy(gedi_l1b, tmp_path / "zero.h5")
    with h5py.File(p, "a") as f:
        f["BEAM0101/rx_sample_count"][3] = 0
        g = f["BEAM0101"]
        s = int(g["rx_sample_start_index"][7] - g["rx_sample_start_index"][0])
        n = int(g["rx_sample_count"][7])
        rx = g["rxwaveform"][:]
        rng = np.random.default_rng(0)
        rx[s:s + n] = rng.normal(g["noise_mean_corrected"][7], 1.0, n)   # noise only
        g["rxwaveform"][:] = rx
    b = read_gedi_l1b(p, "BEAM0101")
    assert b.n_samples[3] == 0
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = process_waveforms(b)
    assert res["flag"].iloc[3] == "no_signal" and np.isnan(res["ground"].iloc[3])
    assert res["flag"].iloc[7] == "no_signal"
    assert (res["flag"].drop(index=[3, 7]) == "ok").all()


def test_l1b_dem_reaches_the_terrain_outlier_check(gedi_l1b: Path) -> None:
    """The L1B's per-shot DEM (geolocation/digital_elevation_model) is read as the file holds
    it, and a ground far from it is a terrain outlier from the file path too."""
    import warnings
    from dataclasses import replace

    from canopyblocks.readers.gedi import DEM
    from canopyblocks.waveforms.process import process_waveforms

    beam = "BEAM0101"
    with h5py.File(gedi_l1b) as f:
        dem = f[f"{beam}/geolocation/digital_elevation_model"][:].astype(np.float64)
    b = read_gedi_l1b(gedi_l1b, beam)
    np.testing.assert_array_equal(b.extra[DEM], np.where(dem < -1000.0, np.nan, dem))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fp = process_waveforms(b)
        ok = fp["flag"] == "ok"
        assert ok.sum() >= 10   # the real shots agree with the DEM (within 100 m)
        fp2 = process_waveforms(replace(b, extra={**b.extra, DEM: b.extra[DEM] + 500.0}))
    assert (fp2.loc[ok.to_numpy(), "flag"] == "terrain_outlier").all()
