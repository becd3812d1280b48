"""``--diameter`` with a waveform sensor: refused in one line (it was silently ignored, the
GEDI truth and reference staying 22 m), nothing written."""

from __future__ import annotations

import subprocess
import sys

import pytest


def _cli(*args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "canopyblocks", *map(str, args)],
                          capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("command", ["simulate", "run"])
def test_gedi_diameter_refused(sample, tmp_path, command):
    las = sample("als/lasR_bcts_1.laz")
    out = tmp_path / ("g.h5" if command == "simulate" else "run")
    r = _cli(command, las, "--sensor", "gedi", "--azimuth", "10", "--diameter", "30",
             "-o", out)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--diameter" in lines[0] and "22 m" in lines[0]
    assert "Traceback" not in r.stderr
    assert not out.exists()


def test_gedi_without_diameter_still_simulates(sample, tmp_path):
    out = tmp_path / "g.h5"
    r = _cli("simulate", sample("als/lasR_bcts_1.laz"), "--sensor", "gedi", "--azimuth",
             "10", "-o", out)
    assert r.returncode == 0, r.stderr
    assert out.exists()
