"""A background rate the file gets wrong (``bckgrd_atlas/bckgrd_rate`` set to 0, divided by
1000, multiplied by 1000): the photons' own count of the background in the telemetry window
disagrees, a warning names both rates, and the ATL08-style classifier then uses the
photons' rate -- segments and blocks stay near the clean run instead of giving canopy
heights of 50-180 m.  A right rate (simulation, the real clip) passes without a word."""

from __future__ import annotations

import shutil
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest

from canopyblocks import classify_photons
from canopyblocks.blocks.atl08_segments import atl08_segments
from canopyblocks.blocks.background_check import photon_background
from canopyblocks.errors import CanopyBlocksWarning, InputError
from canopyblocks.photons import BackgroundRate

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_atl08_classifier import slope, synthetic  # noqa: E402

CLIP = Path("tests/data/icesat2/vegr_atl03_clip.h5")
LAZ = Path("tests/data/als/lasR_bcts_1.laz")


def _scaled(track, factor):  # noqa: ANN001, ANN202
    bg = track.background
    return replace(track, background=BackgroundRate(bg.time, bg.rate * factor))


@pytest.fixture(scope="module")
def day():  # noqa: ANN201
    return synthetic(3e6, slope, seed=3)[0]  # 3 MHz, canopy 2.5-15 m: truth known


def test_right_rate_passes_silently(day):
    chk = photon_background(day)
    assert not chk.disagree.any()
    # the photons' own rate: within 20 % of the simulated 3 MHz in every full stretch
    seen = np.isfinite(chk.photons_hz)
    assert seen.sum() >= 8
    assert np.all(np.abs(chk.photons_hz[seen] / 3e6 - 1.0) < 0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        classify_photons(day)


def test_real_clip_rate_agrees_with_its_photons():
    from canopyblocks.readers import read_atl03
    chk = photon_background(read_atl03(CLIP, "gt1r"))
    seen = np.isfinite(chk.photons_hz)
    assert seen.sum() == 4 and not chk.disagree.any()
    # measured: the photons give 0.86-0.87 of the file's rate in each stretch
    assert np.all(np.abs(chk.photons_hz[seen] / chk.file_hz[seen] - 1.0) < 0.3)


@pytest.mark.parametrize("factor", [0.0, 1e-3, 1e3])
def test_wrong_rate_is_named_and_replaced(day, factor):
    clean = atl08_segments(day, classify_photons(day), 100.0)
    bad = _scaled(day, factor)
    with pytest.warns(CanopyBlocksWarning, match=r"file's background rate .* disagrees with "
                      r"the photons' own \((2\.\d+|3\.\d+) MHz"):
        res = classify_photons(bad)
    seg = atl08_segments(bad, res, 100.0)
    # simulated canopy: 2.5-15 m; the clean run's h_canopy; never the 50-180 m of a
    # classifier that takes background for canopy
    ok = np.isfinite(clean.h_canopy.to_numpy())
    assert ok.sum() >= 15
    assert np.nanmax(np.abs(seg.h_canopy.to_numpy()[ok] - clean.h_canopy.to_numpy()[ok])) < 2.0
    assert np.nanmax(seg.h_canopy.to_numpy()) < 20.0


def test_bright_rate_the_photons_confirm_is_named(day):
    from test_atl08_classifier import synthetic as syn
    bright = syn(40e6, slope, seed=4, length=600.0)[0]
    with pytest.warns(CanopyBlocksWarning, match=r"background rate is 4\d(\.\d+)? MHz"):
        classify_photons(bright)


def test_background_must_be_a_rate(day):
    bad = replace(day)
    bad.background = "3 MHz"  # type: ignore[assignment]
    with pytest.raises(InputError, match="background must be a BackgroundRate"):
        classify_photons(bad)


@pytest.fixture(scope="module")
def day_file(tmp_path_factory):  # noqa: ANN001, ANN201
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, SimTrack, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03
    pts = read_las(LAZ)
    track = SimTrack.line(885120.0, 629170.0, 885120.0, 629690.0)
    sim = simulate_photons(pts, track, SimParams(background_rate_mhz=3.0), seed=7)
    return write_simulation_atl03(sim, tmp_path_factory.mktemp("day") / "day.h5")


def _edited(src: Path, dst: Path, factor: float) -> Path:
    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        f["gt1r/bckgrd_atlas/bckgrd_rate"][...] = f["gt1r/bckgrd_atlas/bckgrd_rate"][()] * factor
    return dst


@pytest.mark.parametrize("factor", [0.0, 1e-3])
def test_simulated_day_file_segments_and_blocks(day_file, tmp_path, factor):
    from canopyblocks.blocks.estimators import preset
    from canopyblocks.workflows.blocks import blocks_from_file
    from canopyblocks.workflows.segments import segments_from_file
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the clean run's sparse-block notes
        clean = segments_from_file(day_file, length=100.0)
        clean_b = blocks_from_file(day_file, None, estimators=preset("atl08")).blocks
    bad = _edited(day_file, tmp_path / f"bad{factor:g}.h5", factor)
    with pytest.warns(CanopyBlocksWarning, match=r"disagrees with the photons' own"):
        seg = segments_from_file(bad, length=100.0)
    hc, hc0 = seg.h_canopy.to_numpy(), clean.h_canopy.to_numpy()
    both = np.isfinite(hc) & np.isfinite(hc0)
    assert both.sum() >= 3
    # the airborne canopy here is at most ~34 m tall
    assert np.nanmax(np.abs(hc[both] - hc0[both])) < 3.0 and np.nanmax(hc) < 40.0
    with pytest.warns(CanopyBlocksWarning, match=r"disagrees with the photons' own"):
        b = blocks_from_file(bad, None, estimators=preset("atl08")).blocks
    used = b[b["flag"] == "ok"]
    assert len(used) >= 0.5 * (clean_b["flag"] == "ok").sum()
    assert used["hmax"].max() < 40.0


def test_unreadable_background_does_not_cost_the_photons(day_file, tmp_path, caplog):
    """A damaged (unreadable) bckgrd_atlas: the paper's method never uses it, and the
    classifier estimates the rate from the photons; a warning says so."""
    from canopyblocks.readers import read_atl03
    p = tmp_path / "flip.h5"
    shutil.copy(day_file, p)
    with h5py.File(p, "r+") as f:
        r = f["gt1r/bckgrd_atlas/bckgrd_rate"][()]
        del f["gt1r/bckgrd_atlas/bckgrd_rate"]
        f.create_dataset("gt1r/bckgrd_atlas/bckgrd_rate", data=r, chunks=(max(r.size // 4, 1),),
                         compression="gzip")
        off = f["gt1r/bckgrd_atlas/bckgrd_rate"].id.get_chunk_info(0).byte_offset
    raw = bytearray(p.read_bytes())
    for k in range(8):
        raw[off + 2 + k] ^= 0xFF  # flip bits inside the compressed chunk
    p.write_bytes(bytes(raw))
    with caplog.at_level("WARNING"), pytest.warns(CanopyBlocksWarning,
                                                  match="counted from the photons"):
        track = read_atl03(p, "gt1r")
    assert len(track) > 1000 and track.background is not None and track.background.settled
    # the photons' count agrees with the rate the file held before the damage
    ratio = float(np.median(track.background.rate)) / float(np.median(r))
    assert 0.7 < ratio < 1.3, ratio
    assert "bckgrd_atlas cannot be read" in caplog.text
