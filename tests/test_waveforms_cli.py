"""``canopyblocks waveforms`` on the real GEDI L1B subset reproduces the official L2A a1
values of the same shots (issue 8's bars), writes a PointZ footprints layer with the
DESIGN 5 columns, draws waveform plots, and ``info`` describes the file."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import h5py
import numpy as np

from canopyblocks.schema import FOOTPRINT_COLUMNS


def _cli(*args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "canopyblocks", *map(str, args)],
                          capture_output=True, text=True, timeout=600)


def _l2a(path: Path) -> dict[int, tuple[float, float, float, float, bool]]:
    out = {}
    with h5py.File(path) as f:
        for beam in (k for k in f if k.startswith("BEAM")):
            g = f[beam]
            sn = g["shot_number"][:]
            ground = g["geolocation/elev_lowestmode_a1"][:]
            top = g["geolocation/elev_highestreturn_a1"][:]
            rh = g["geolocation/rh_a1"][:] / 100.0
            valid = (g["quality_flag"][:] == 1) & (g["rx_processing_a1/rx_algrunflag"][:] == 1)
            for i, s in enumerate(sn):
                out[int(s)] = (float(ground[i]), float(rh[i, 50]), float(rh[i, 98]),
                               float(top[i]), bool(valid[i]))
    return out


def test_waveforms_reproduce_l2a(gedi_l1b: Path, gedi_l2a: Path, tmp_path: Path) -> None:
    out = tmp_path / "fp.gpkg"
    plots = tmp_path / "plots"
    r = _cli("waveforms", gedi_l1b, "-o", out, "--plots", plots, "--l2a", gedi_l2a)
    assert r.returncode == 0, r.stderr
    fp = gpd.read_file(out, layer="footprints")
    assert list(fp.columns[:len(FOOTPRINT_COLUMNS)]) == list(FOOTPRINT_COLUMNS)
    assert fp.geometry.has_z.all() and fp.crs.is_projected
    np.testing.assert_allclose(fp.geometry.z, fp["ground"])
    ref = _l2a(gedi_l2a)
    with h5py.File(gedi_l1b) as f:   # L1B quality flags, read independently
        bad = {int(s) for b in f if b.startswith("BEAM")
               for s, st, dg in zip(f[b]["shot_number"][:], f[b]["stale_return_flag"][:],
                                    f[b]["geolocation/degrade"][:]) if st or dg}
    for beam, sub in fp.groupby("beam"):
        rows = [(row, ref[int(row.shot_number)]) for row in sub.itertuples()
                if int(row.shot_number) in ref and ref[int(row.shot_number)][4]
                and int(row.shot_number) not in bad]
        assert len(rows) >= 10, beam
        for k, name in enumerate(("ground", "rh50", "rh98", "top")):
            d = np.array([getattr(row, name) - r_[k] for row, r_ in rows])
            assert np.sqrt(np.mean(d ** 2)) <= 0.05, (beam, name)
            assert abs(d.mean()) <= 0.02, (beam, name)
            assert np.mean(np.abs(d) <= 0.10) >= 0.98, (beam, name)
    cmp = gpd.read_file(out, layer="l2a_comparison")
    assert set(cmp["metric"]) == {"ground", "rh50", "rh98", "top"}
    pngs = sorted(plots.glob("waveform_*.png"))
    assert len(pngs) >= 7 and (plots / "waveforms.html").exists()
    assert "vs L2A" in r.stderr and "footprints" in r.stderr


def test_waveforms_other_setting_and_beam(gedi_l1b: Path, gedi_l2a: Path,
                                          tmp_path: Path) -> None:
    out = tmp_path / "a5.parquet"
    r = _cli("waveforms", gedi_l1b, "--beam", "BEAM0110", "--setting", "a5", "--all-rh",
             "-o", out)
    assert r.returncode == 0, r.stderr
    import pandas as pd

    fp = pd.read_parquet(out)
    assert set(fp["beam"]) == {"BEAM0110"} and set(fp["setting"]) == {"a5"}
    assert "rh0" in fp.columns and "rh100" in fp.columns
    with h5py.File(gedi_l2a) as f:
        g = f["BEAM0110"]
        ref = dict(zip(g["shot_number"][:].tolist(), g["geolocation/elev_lowestmode_a5"][:]))
    d = np.array([row.ground - ref[int(row.shot_number)] for row in fp.itertuples()
                  if row.flag == "ok" and int(row.shot_number) in ref])
    assert d.size >= 30 and np.sqrt(np.mean(d ** 2)) <= 0.05


def test_info_and_bad_input(gedi_l1b: Path, tmp_path: Path) -> None:
    r = _cli("info", gedi_l1b)
    assert r.returncode == 0, r.stderr
    assert "GEDI L1B" in r.stdout and "BEAM0101: full power, 73 shots" in r.stdout
    assert "shots: 300" in r.stdout
    trunc = tmp_path / "trunc.h5"
    trunc.write_bytes(gedi_l1b.read_bytes()[:50_000])
    for args, msg in (((trunc, "-o", tmp_path / "a.gpkg"), "trunc.h5"),
                      ((gedi_l1b, "--beam", "BEAM9", "-o", tmp_path / "b.gpkg"), "no beam"),
                      ((gedi_l1b, "-o", tmp_path / "c.txt"), "c.txt")):
        r = _cli("waveforms", *args)
        assert r.returncode == 2, r.stderr
        assert msg in r.stderr and "Traceback" not in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1
    assert not list(tmp_path.glob("*.gpkg"))
