"""``waveforms --workers``: the beams of a granule processed in worker processes give the
same footprints, byte for byte, as one process (and the same plots)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from canopyblocks.workflows.waveforms_beams import beams_for_workers


def _run(l1b: Path, out: Path, workers: int, plots: Path | None = None) -> None:
    args = ["-q", "waveforms", str(l1b), "-o", str(out), "--workers", str(workers),
            "--setting", "a2", "--all-rh"]
    if plots is not None:
        args += ["--plots", str(plots)]
    res = subprocess.run([sys.executable, "-m", "canopyblocks", *args], capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stderr


def test_workers_write_the_same_bytes(gedi_l1b: Path, tmp_path: Path) -> None:
    assert len(beams_for_workers(gedi_l1b, None, 2)) >= 2   # the pool is really used
    one, two = tmp_path / "one.csv", tmp_path / "two.csv"
    _run(gedi_l1b, one, 1, tmp_path / "p1")
    _run(gedi_l1b, two, 2, tmp_path / "p2")
    assert one.read_bytes() == two.read_bytes()
    assert len(one.read_text().splitlines()) > 250
    assert sorted(p.name for p in (tmp_path / "p1").iterdir()) == \
        sorted(p.name for p in (tmp_path / "p2").iterdir())


def test_one_beam_or_one_worker_stays_in_this_process(gedi_l1b: Path) -> None:
    assert beams_for_workers(gedi_l1b, ["BEAM0101"], 4) == []
    assert beams_for_workers(gedi_l1b, None, 1) == []
