"""Honest simulated background noise (DESIGN 3.3): no leak of the truth, the rate in MHz
measured back from the written file, signal confidence from the photons alone, and a
file that describes its heights and beams as a real granule would."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from canopyblocks.readers import read_atl03
from canopyblocks.readers.atl03 import beam_strength
from canopyblocks.readers.las import read_las
from canopyblocks.simulate import SimParams, line_through, simulate_photons
from canopyblocks.simulate.confidence import signal_confidence
from canopyblocks.simulate.sampling import draw_noise
from canopyblocks.simulate.writers import write_simulation_atl03

TILES = [Path(__file__).parent / "data" / "als" / f"lasR_bcts_{i}.laz" for i in (1, 2)]
C = 299_792_458.0
RATE_MHZ = 3.0
BLOCK = 25.0


@pytest.fixture(scope="module")
def cloud():
    return read_las(TILES)


@pytest.fixture(scope="module")
def sims(cloud):
    """Day-time tracks at five azimuths over the bundled conifer tiles, 2 draws each."""
    out = []
    for i, az in enumerate((0.0, 15.0, 30.0, 150.0, 165.0)):
        track = line_through(cloud.bounds, az, inset=10.0)
        out.append(simulate_photons(cloud, track, SimParams(background_rate_mhz=RATE_MHZ),
                                    realisations=2, seed=i))
    return out


def _blocks(sim):
    """Block of each shot and the block's truth Hmax (highest footprint top minus the
    mean footprint ground), from the simulation's per-footprint truth."""
    blk = (sim.shot_s // BLOCK).astype(np.int64)
    nb = int(blk.max()) + 1
    top = np.full(nb, -np.inf)
    np.maximum.at(top, blk, np.where(np.isfinite(sim.truth["top"]), sim.truth["top"], -np.inf))
    g = sim.truth["ground"]
    ok = np.isfinite(g)
    ground = np.bincount(blk[ok], g[ok], nb) / np.maximum(np.bincount(blk[ok], minlength=nb), 1)
    return blk, top - ground


def _noise_only_hmax(blk_of_photon, h, nb):
    """An estimator that sees only noise photons: per block, p98 - p2 and max - min."""
    p = np.full((nb, 2), np.nan)
    for k in range(nb):  # a handful of blocks: the test's own brute force
        hk = h[blk_of_photon == k]
        if hk.size >= 20:
            p[k] = (np.percentile(hk, 98) - np.percentile(hk, 2), hk.max() - hk.min())
    return p


def test_an_estimator_fed_only_noise_has_no_skill(sims):
    honest, leaky, ref = [], [], []
    rng = np.random.default_rng(11)
    per_m = RATE_MHZ * 1e6 * 2 / C
    for sim in sims:
        blk, href = _blocks(sim)
        nb = href.size
        # the window the simulator used to draw (each footprint's truth +- 10 m): the
        # same estimator on it shows what a leak looks like, so this test can fail
        _, ls, lh = draw_noise(sim.truth["ground"] - 10.0, sim.truth["top"] + 10.0, per_m, 1,
                               rng)
        lk = _noise_only_hmax(blk[ls], lh, nb)
        for r in range(sim.n_realisations):
            c = sim.photon_columns(r)
            nz = c["noise"]
            honest.append(_noise_only_hmax(blk[c["shot"][nz]], c["h"][nz], nb))
            leaky.append(lk)
            ref.append(href)
    h, lk, y = np.vstack(honest), np.vstack(leaky), np.concatenate(ref)
    ok = np.isfinite(y) & np.all(np.isfinite(h), axis=1) & np.all(np.isfinite(lk), axis=1)
    assert ok.sum() >= 150
    for j in range(2):
        r_honest = np.corrcoef(y[ok], h[ok, j])[0, 1]
        r_leaky = np.corrcoef(y[ok], lk[ok, j])[0, 1]
        assert abs(r_honest) < 0.2, r_honest
        assert r_leaky > 0.5, r_leaky


def test_noise_window_ignores_the_footprints(sims, cloud):
    sim = sims[0]
    lo, hi = sim.telemetry_bottom, sim.telemetry_top
    ok = np.isfinite(lo)
    assert np.allclose(hi[ok] - lo[ok], 200.0)
    # a window that follows a 1 km smoothed terrain barely moves over 500 m of track,
    # while the footprints' truth ground and top vary by metres
    assert np.ptp(lo[ok]) < 2.0
    assert np.nanstd(sim.truth["top"]) > 3.0
    # and it holds every signal photon of the tiles
    c = sim.photon_columns(0)
    assert np.all(c["h"] >= lo[c["shot"]]) and np.all(c["h"] <= hi[c["shot"]])


def test_rate_measured_from_the_file_is_the_requested_rate(sims, cloud, tmp_path):
    sim = sims[0]
    path = write_simulation_atl03(sim, tmp_path / "day.h5")
    with h5py.File(path) as f:
        bg = f["gt1r/bckgrd_atlas"]
        assert bg["bckgrd_rate"].attrs["units"] in (b"counts / second", "counts / second")
        assert np.allclose(bg["bckgrd_rate"][:], RATE_MHZ * 1e6)
        span_t = bg["delta_time"][:]
        top = bg["tlm_top_band1"][:].astype(float)
        assert np.allclose(np.diff(span_t), 50 / 10_000.0)  # 50 shots at 10 kHz
        h = f["gt1r/heights/h_ph"][:].astype(float)
        t = f["gt1r/heights/delta_time"][:]
    # photons well above the highest airborne point can only be background: count them
    # between there and the window's top, per shot and metre, back to MHz
    floor = float(cloud.z.max()) + 5.0
    covered = np.isfinite(sim.telemetry_top)
    span = np.searchsorted(span_t, t, side="right") - 1
    above = (h > floor) & (h <= top[span])
    shots = np.flatnonzero(covered)
    height = top[shots // 50] - floor
    expected_per_mhz = np.sum(height) * 2e6 / C
    measured = above.sum() / expected_per_mhz
    sigma = np.sqrt(above.sum()) / expected_per_mhz
    assert abs(measured - RATE_MHZ) < 4 * sigma, (measured, sigma)


def test_signal_confidence_comes_from_the_photons_alone(sims, cloud, tmp_path):
    sim = sims[1]
    path = write_simulation_atl03(sim, tmp_path / "conf.h5")
    t = read_atl03(path, "gt1r", crs=sim.crs)
    # graded again from the file's own photons (float32 heights: a few may change grade)
    assert np.mean(t.signal_conf == signal_confidence(t.s, t.h)) > 0.99
    noise = t.extra["noise"].astype(bool)
    # graded blind, it still separates the classes it never saw: background away from
    # the surface rarely reaches medium (0.99 quantile: ~1 %), signal mostly low or more
    away = (t.h > cloud.z.max() + 5.0) | (t.h < cloud.z.min() - 5.0)
    assert np.mean(t.signal_conf[noise & away] >= 3) < 0.02
    assert np.mean(t.signal_conf[~noise] >= 2) > 0.85
    assert set(np.unique(t.signal_conf)) <= {0, 2, 3, 4}


@pytest.mark.parametrize("beam, orient", [("strong", 1), ("weak", 0)])
def test_beam_labels_follow_the_real_layout(cloud, tmp_path, beam, orient):
    track = line_through(cloud.bounds, 0.0, inset=10.0)
    sim = simulate_photons(cloud, track, SimParams(beam=beam, background_rate_mhz=0.15),
                           seed=2)
    path = write_simulation_atl03(sim, tmp_path / f"{beam}.h5")
    with h5py.File(path) as f:
        sc = int(f["orbit_info/sc_orient"][0])
        attr = f["gt1r"].attrs["atlas_beam_type"]
        desc = f["gt1r/heights/h_ph"].attrs["description"]
        vcrs = f.attrs["canopyblocks_height_crs"]
    assert sc == orient
    # the rule real granules follow (the bundled real clip: gt1r weak when backward)
    assert beam_strength("gt1r", sc) == beam
    assert (attr.decode() if isinstance(attr, bytes) else attr) == beam
    desc = desc.decode() if isinstance(desc, bytes) else desc
    vcrs = vcrs.decode() if isinstance(vcrs, bytes) else vcrs
    assert vcrs == cloud.vertical_datum == "EPSG:5713"
    assert "EPSG:5713" in desc and "not WGS-84" in desc


@pytest.mark.parametrize("opts, mhz", [(["--day"], 3.0), (["--night"], 0.15),
                                       (["--background-rate", "1.5"], 1.5),
                                       (["--noise-rate", "0.01"], 0.01 * C / 2e6)])
def test_cli_background_rate_in_mhz(tmp_path, capsys, opts, mhz):
    from canopyblocks.cli import main

    out = tmp_path / "sim.h5"
    rc = main(["simulate", str(TILES[0]), "--line", "885080,629300,885080,629380",
               "--realisations", "1", *opts, "-o", str(out)])
    assert rc == 0
    with h5py.File(out) as f:
        assert np.allclose(f["gt1r/bckgrd_atlas/bckgrd_rate"][:], mhz * 1e6, rtol=1e-6)
    err = capsys.readouterr().err
    assert ("deprecated" in err) == (opts[0] == "--noise-rate")
    # the seed-002 residual line is flagged: its rule classifies the background too
    assert "background noise included" in err


def test_cli_background_rate_given_twice_is_refused(tmp_path, capsys):
    from canopyblocks.cli import main

    rc = main(["simulate", str(TILES[0]), "--azimuth", "0", "--day", "--background-rate",
               "1", "-o", str(tmp_path / "x.h5")])
    assert rc == 2
    assert "once" in capsys.readouterr().err
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.parametrize("opt, value, needle", [("--background-rate", "nan", "background_rate_mhz"),
                                                ("--background-rate", "-1", "background_rate_mhz"),
                                                ("--telemetry-window", "0", "telemetry_window"),
                                                ("--noise-rate", "-1", "noise_rate")])
def test_cli_bad_background_numbers_are_refused(tmp_path, capsys, opt, value, needle):
    from canopyblocks.cli import main

    out = tmp_path / "x.h5"
    rc = main(["simulate", str(TILES[0]), "--azimuth", "0", opt, value, "-o", str(out)])
    assert rc == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err
    assert not out.exists()


def test_photon_track_carries_the_rate_a_written_file_gives(sims, tmp_path):
    sim = sims[2]
    direct = sim.photon_track()
    read = read_atl03(write_simulation_atl03(sim, tmp_path / "bg.h5"), "gt1r", crs=sim.crs)
    assert direct.background is not None and read.background is not None
    assert np.allclose(direct.background.at(direct.time), RATE_MHZ * 1e6)
    assert np.allclose(read.background.at(read.time), direct.background.at(read.time))


def test_reader_takes_the_vertical_crs_the_simulated_file_states(tmp_path):
    """A simulated ATL03 keeps the airborne tiles' heights; the reader must not call them WGS84."""
    from canopyblocks.readers.atl03 import read_atl03

    src = Path(__file__).parent / "data" / "icesat2" / "vegr_atl03_clip.h5"
    real = read_atl03(src, beam="gt1r")
    assert real.vertical_datum == "EPSG:4979"  # a real granule: ellipsoidal heights
    copy = tmp_path / "stated.h5"
    copy.write_bytes(src.read_bytes())
    with h5py.File(copy, "a") as f:
        f.attrs["canopyblocks_height_crs"] = "EPSG:5713"
    assert read_atl03(copy, beam="gt1r").vertical_datum == "EPSG:5713"


def test_api_simulation_over_an_all_noise_cloud_names_the_classes():
    """Every point classed noise: the message says so, not that the track misses the cloud."""
    from canopyblocks.errors import NoUsableDataError
    from canopyblocks.readers.las import LasPoints
    from canopyblocks.simulate import SimParams, simulate_photons
    from canopyblocks.simulate.tracks import SimTrack

    rng = np.random.default_rng(0)
    n = 2000
    pts = LasPoints.from_arrays(rng.uniform(0, 100, n), rng.uniform(0, 100, n),
                                rng.uniform(100, 120, n), classification=np.full(n, 7),
                                crs="EPSG:32610")
    with pytest.raises(NoUsableDataError, match="classed noise"):
        simulate_photons(pts, SimTrack.line(0.0, 50.0, 100.0, 50.0), SimParams())
