"""The QGIS simulate algorithm's background noise rate (MHz), through ``qgis_process``:
the same default as the command line (off) and the rate written where ATL03 has it."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import h5py
import laspy
import numpy as np
import pytest

pytestmark = [pytest.mark.qgis]

ROOT = Path(__file__).resolve().parents[2]
TILE = ROOT / "tests" / "data" / "als" / "lasR_bcts_1.laz"


def _run(env: dict[str, str], **params: object) -> None:
    args = ["qgis_process", "run", "canopyblocks:simulate", "--"]
    args += [f"{k}={v}" for k, v in params.items()]
    r = subprocess.run(args, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, f"{r.stdout}\n{r.stderr}"
    assert "Traceback" not in r.stderr, r.stderr


def test_background_rate_in_mhz(qgis_profile: Path, qgis_process_env: Any,
                                tmp_path: Path) -> None:
    env = qgis_process_env(qgis_profile)
    quiet, day = tmp_path / "quiet.h5", tmp_path / "day.h5"
    _run(env, INPUT=TILE, AZIMUTH=0, SEED=1, OUTPUT=quiet)
    _run(env, INPUT=TILE, AZIMUTH=0, SEED=1, BACKGROUND_RATE=1.5, OUTPUT=day)
    top = float(laspy.read(TILE).z.max())
    with h5py.File(quiet) as f:
        assert np.all(f["gt1r/bckgrd_atlas/bckgrd_rate"][:] == 0.0)
        assert f["gt1r/heights/h_ph"][:].max() <= top + 2.0  # no photon above the canopy
    with h5py.File(day) as f:
        assert np.allclose(f["gt1r/bckgrd_atlas/bckgrd_rate"][:], 1.5e6)
        h = f["gt1r/heights/h_ph"][:].astype(float)
        band_top = f["gt1r/bckgrd_atlas/tlm_top_band1"][:].astype(float)
        shots = f["gt1r/heights/delta_time"][:]
    # photons between the highest airborne point + 5 m and the window top are background:
    # at 1.5 MHz, 2e6 * 1.5 / c photons per shot per metre
    floor = top + 5.0
    n_shots = int(round(shots.max() * 10_000)) + 1
    expected = 1.5e6 * 2 / 299_792_458.0 * (float(np.median(band_top)) - floor) * n_shots
    got = int(np.sum(h > floor))
    assert abs(got - expected) < 5 * np.sqrt(expected), (got, expected)
