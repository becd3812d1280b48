"""Simulated photons through ATL03/MABEL files and tables, and the ``simulate`` command."""

from __future__ import annotations

import geopandas as gpd
import h5py
import numpy as np
import pandas as pd
import pytest

from canopyblocks.geo import from_metric
from canopyblocks.readers import read_atl03, read_mabel
from canopyblocks.readers.las import LasPoints
from canopyblocks.simulate import SimParams, SimTrack, simulate_photons
from canopyblocks.simulate.writers import (
    write_photon_table,
    write_simulation_atl03,
    write_simulation_mabel,
)

CRS = 32610
X0, Y0 = 500_000.0, 5_000_000.0


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(0)
    n = 20_000
    x = X0 + rng.random(n) * 60
    y = Y0 + rng.random(n) * 60
    z = 50.0 + 0.1 * (x - X0) + np.where(rng.random(n) < 0.4, rng.random(n) * 20, 0.0)
    pts = LasPoints.from_arrays(x, y, z, crs=CRS)
    track = SimTrack.line(X0 + 10, Y0 + 10, X0 + 50, Y0 + 50)
    return simulate_photons(pts, track, SimParams(background_rate_mhz=3.0),
                            realisations=3, seed=5)


def _key(h, src, shot):
    return np.lexsort((np.asarray(h, np.float32), src, shot))


def test_atl03_round_trip(sim, tmp_path):
    p = write_simulation_atl03(sim, tmp_path / "sim.h5", realisations=[0, 2])
    c = sim.photon_columns(0)
    t = read_atl03(p, "gt1r", crs=CRS)
    assert len(t) == c["h"].size
    a = _key(c["h"], c["src_index"], c["shot"])
    b = _key(t.h, t.extra["src_index"], t.extra["shot"])
    assert np.array_equal(t.extra["shot"][b], c["shot"][a])
    assert np.array_equal(t.extra["src_index"][b], c["src_index"][a])
    assert np.allclose(t.h[b], c["h"][a], atol=1e-4)  # h_ph is float32
    assert np.allclose(t.time[b], c["time"][a])
    assert np.allclose(t.s[b], c["s"][a], atol=1e-4)
    lon, lat = from_metric(c["x"], c["y"], sim.crs)
    assert np.allclose(t.lon[b], lon[a], atol=1e-12) and np.allclose(t.lat[b], lat[a], atol=1e-12)
    assert np.allclose(t.x[b], c["x"][a], atol=1e-6)
    assert np.array_equal(t.extra["noise"][b].astype(bool), c["noise"][a])
    assert np.allclose(t.extra["truth_ground"][b], c["truth_ground"][a])
    # second realisation went to the next beam of the same side (same strength)
    t2 = read_atl03(p, "gt2r", crs=CRS)
    assert len(t2) == sim.photon_columns(2)["h"].size
    with h5py.File(p) as f:
        assert f["gt1r"].attrs["atlas_beam_type"] in (b"strong", "strong")
        # as in real granules: forward orientation makes the right beams strong
        assert int(f["orbit_info/sc_orient"][0]) == 1


def test_atl03_file_is_deterministic(sim, tmp_path):
    a = write_simulation_atl03(sim, tmp_path / "a.h5").read_bytes()
    b = write_simulation_atl03(sim, tmp_path / "b.h5").read_bytes()
    assert a == b


def test_same_seed_gives_identical_file(tmp_path):
    x, y = np.meshgrid(np.arange(0, 40, 0.5), np.arange(0, 40, 0.5))
    pts = LasPoints.from_arrays(X0 + x.ravel(), Y0 + y.ravel(), np.zeros(x.size), crs=CRS)
    track = SimTrack.line(X0 + 8, Y0 + 20, X0 + 32, Y0 + 20)
    files = []
    for i, seed in enumerate((7, 7, 8)):
        s = simulate_photons(pts, track, realisations=2, seed=seed)
        files.append(write_simulation_atl03(s, tmp_path / f"f{i}.h5").read_bytes())
    assert files[0] == files[1]
    assert files[0] != files[2]


def test_mabel_round_trip(sim, tmp_path):
    p = write_simulation_mabel(sim, tmp_path / "mabel.h5", realisations=[1])
    c = sim.photon_columns(1)
    t = read_mabel(p, 1, crs=CRS)
    assert len(t) == c["h"].size
    a = _key(c["h"], c["src_index"], c["shot"])
    b = _key(t.h, t.extra["src_index"], t.extra["shot"])
    assert np.allclose(t.h[b], c["h"][a], atol=1e-4)
    assert np.array_equal(t.extra["shot"][b], c["shot"][a])


def test_photon_table_round_trip(sim, tmp_path):
    p = write_photon_table(sim, tmp_path / "ph.parquet")
    df = gpd.read_parquet(p)
    assert len(df) == sim.photons["h"].size
    assert df.crs.to_epsg() == CRS
    assert np.allclose(df["h"], sim.photons["h"])
    assert np.array_equal(df["realisation"], sim.photons["realisation"])
    assert {"src_z", "truth_ground", "truth_cover", "noise"} <= set(df.columns)


def test_cli_simulate(sample, tmp_path):
    from canopyblocks.cli import main

    out = tmp_path / "out.h5"
    rep = tmp_path / "report"
    rc = main(["-q", "simulate", str(sample("als/lasR_bcts_1.laz")),
               "--line", "885080,629200,885080,629260", "--diameter", "13", "--diameter", "17",
               "--realisations", "5", "--seed", "3", "-o", str(out), "--report", str(rep)])
    assert rc == 0
    t = read_atl03(out, "gt1r", crs=3005)
    assert len(t) > 50
    assert t.x.min() == pytest.approx(885080, abs=0.01) and t.s.max() <= 60.0
    table = pd.read_csv(rep / "truth_residuals.csv")
    assert table["diameter"].tolist() == [13.0, 17.0]
    assert (table["realisations"] == 5).all()
    assert (rep / "residuals_by_cover.png").stat().st_size > 1000
    assert (rep / "residuals_by_cover.csv").exists() and (rep / "truth_13m.csv").exists()
    # same arguments, same file
    out2 = tmp_path / "out2.h5"
    assert main(["-q", "simulate", str(sample("als/lasR_bcts_1.laz")),
                 "--line", "885080,629200,885080,629260", "--realisations", "5",
                 "--diameter", "13", "--seed", "3", "-o", str(out2)]) == 0
    assert out.read_bytes() == out2.read_bytes()


def test_cli_simulate_bad_input(sample, tmp_path, capsys):
    from canopyblocks.cli import main

    las = str(sample("als/lasR_bcts_1.laz"))
    assert main(["simulate", las, "-o", str(tmp_path / "x.h5")]) == 2
    assert main(["simulate", las, "--azimuth", "0", "--line", "1,2,3,4",
                 "-o", str(tmp_path / "x.h5")]) == 2
    assert main(["simulate", las, "--line", "1,2,3", "-o", str(tmp_path / "x.h5")]) == 2
    assert main(["simulate", las, "--line", "0,0,10,0", "-o", str(tmp_path / "x.h5")]) == 2
    err = capsys.readouterr().err
    assert "no points inside bbox" in err
    assert main(["simulate", str(tmp_path / "none.laz"), "--azimuth", "0",
                 "-o", str(tmp_path / "x.h5")]) == 2
    assert main(["simulate", las, "--azimuth", "0", "-o", str(tmp_path / "x.txt")]) == 2
    assert not list(tmp_path.glob("*.h5"))


def test_progress_and_cancel(tmp_path):
    from canopyblocks.errors import CancelledError
    from canopyblocks.progress import Progress

    x, y = np.meshgrid(np.arange(0, 200, 1.0), np.arange(0, 40, 1.0))
    pts = LasPoints.from_arrays(X0 + x.ravel(), Y0 + y.ravel(), np.zeros(x.size), crs=CRS)
    track = SimTrack.line(X0 + 8, Y0 + 20, X0 + 192, Y0 + 20)
    seen: list[float] = []
    simulate_photons(pts, track, progress=Progress(callback=lambda f, m: seen.append(f)))
    assert len(seen) >= 3 and seen[-1] == pytest.approx(1.0) and seen == sorted(seen)
    calls = iter(range(100))
    with pytest.raises(CancelledError):
        simulate_photons(pts, track, progress=Progress(cancelled=lambda: next(calls) >= 1))


def test_cli_polyline_and_table_output(sample, tmp_path):
    from canopyblocks.cli import main

    out = tmp_path / "ph.parquet"
    rc = main(["-q", "simulate", str(sample("als/lasR_bcts_1.laz")),
               str(sample("als/lasR_bcts_2.laz")),
               "--polyline", "885080,629380;885080,629420;885120,629420", "--realisations", "2",
               "--preset", "boreal", "--beam", "weak", "-o", str(out)])
    assert rc == 0
    df = gpd.read_parquet(out)
    assert df.crs.to_epsg() == 3005 and (df["realisation"] == 0).all()
    # the track crosses the tile boundary at y = 629400 and turns east
    assert df["s"].max() <= 80.0 and df["x"].max() > 885100
    assert df["src_z"].between(320, 370).all()
    assert main(["simulate", str(sample("als/lasR_bcts_1.laz")), "--polyline", "885080,629380",
                 "-o", str(out)]) == 2


def test_block_engine_runs_on_simulated_track():
    from canopyblocks.blocks import BlockParams, compute_blocks

    g = np.arange(0.0, 200.0, 0.5)
    gx, gy = np.meshgrid(g, g)
    x, y = X0 + gx.ravel(), Y0 + gy.ravel()
    can = np.random.default_rng(0).random(x.size) < 0.4
    pts = LasPoints.from_arrays(np.concatenate([x, x[can]]), np.concatenate([y, y[can]]),
                                np.concatenate([np.zeros(x.size), np.full(can.sum(), 20.0)]),
                                crs=CRS)
    sim = simulate_photons(pts, SimTrack.line(X0 + 10, Y0 + 100, X0 + 190, Y0 + 100),
                           SimParams(mean_photons=3.0), seed=1)
    track = sim.photon_track()
    blocks = compute_blocks(track, BlockParams(lengths=(25.0,)))
    assert int(blocks["n_photons"].sum()) == len(track)
    full = blocks[blocks["n_photons"] > 50]
    assert len(full) >= 6
    # ground layer at 0 m, canopy layer at 20 m (+- the 0.5 m histogram bins and the PSF)
    assert np.all(np.abs(full["ground"]) < 2.0) and np.all(np.abs(full["top"] - 20.0) < 2.0)
