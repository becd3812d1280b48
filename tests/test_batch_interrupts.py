"""``batch --workers 2`` interrupted for real (issue 23, Interruption): process and Dask workers.

SIGTERM (to the command) or SIGINT (to its process group, as a terminal's Ctrl-C) is sent
while PDAL builds the reference rasters in a worker, or a few seconds in.  Afterwards: no
``*.part*`` file anywhere under the output, nothing in the TMPDIR (no
``canopyblocks-pdal-*`` or Dask scratch folder), no live process of the run's session,
exit status 128+signal with one line, and that line names complete outputs exactly when
complete outputs remain ("no output was written" only when none does).  A rerun then
completes and leaves no partial file.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_interrupts import SIGNALS, Run, _after, _children

pytestmark = [pytest.mark.pdal, pytest.mark.slow]


@pytest.fixture(scope="module")
def batch_inputs(tmp_path_factory, sample, pdal_bin):
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03

    root = tmp_path_factory.mktemp("batch_int")
    tiles = root / "tiles"
    tiles.mkdir()
    for name in ("lasR_bcts_1.laz", "lasR_bcts_2.laz"):
        shutil.copy(sample(f"als/{name}"), tiles / name)
    pts = read_las(sorted(str(p) for p in tiles.iterdir()))
    b = pts.bounds
    cx, cy = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2
    granules = root / "granules"
    granules.mkdir()
    for i, dx in enumerate((-40.0, 30.0)):
        tr = line_through(b, 10.0, centre=(cx + dx, cy), inset=7, name="gt1r")
        sim = simulate_photons(pts, tr, SimParams(), realisations=1, seed=40 + i)
        write_simulation_atl03(sim, granules / f"ATL03_int{i}.h5")
    return granules, tiles


def _pdal_in_a_worker(run: Run):
    return lambda: any(" pipeline " in cmd for _, cmd in _children(run.proc.pid))


def _leftovers(run: Run, out: Path) -> list[Path]:
    return [p for p in run.tmp.rglob("*") if ".part" in p.name]


CASES = [(backend, stage, how) for backend in ("processes", "dask")
         for stage, how in (("pdal", "term"), ("pdal", "int-group"), ("seconds", "term"),
                            ("seconds", "int-group"))] + [("serial", "pdal", "term")]


@pytest.mark.parametrize("backend,stage,how", CASES)
def test_batch_interrupted(batch_inputs, tmp_path, backend, stage, how) -> None:
    if backend == "dask":
        pytest.importorskip("distributed")
    granules, tiles = batch_inputs
    out = tmp_path / "out"
    args = ["batch", str(granules), "--tiles", str(tiles), "-o", str(out), "--offset", "0",
            "--backend", backend, "--workers", "2", "--resolution", "1"]
    # the serial backend runs PDAL itself, not in a worker: the same test finds it
    run = Run(args, tmp_path)
    ready = _pdal_in_a_worker(run) if stage == "pdal" else _after(run, 5.0)
    sig, group = SIGNALS[how]
    reached = run.wait_until(ready, timeout=180)
    if reached:
        time.sleep(0.3 if stage == "pdal" else 0.0)
        run.send(sig, group)
    code, err = run.finish(timeout=120)
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    complete = sorted(p for p in out.rglob("*") if p.is_file()) if out.exists() else []
    if code == 0:
        assert not reached or stage == "seconds", err
        assert (out / "stats.csv").exists()
    else:
        assert code == 128 + sig, (code, err)
        assert len(lines) == 1, err
        line = lines[0]
        assert line.startswith("canopyblocks: error: interrupted"), line
        if complete:
            assert "complete outputs were written" in line, (line, complete)
            named = line.split("written: ", 1)[1]
            for name in named.split(", "):
                name = name.split(" and ")[0].strip()
                assert Path(name).exists(), (name, line)
        else:
            assert "no output was written" in line, line
    assert _leftovers(run, out) == []
    assert list(run.tmpdir.iterdir()) == [], f"left in TMPDIR: {list(run.tmpdir.iterdir())}"
    run.no_live_process()
    # a rerun completes from what was kept and leaves no partial file
    again = subprocess.run([sys.executable, "-m", "canopyblocks", "-q", *args[:-6],
                            "--backend", "serial", "--resolution", "1"],
                           capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert again.returncode == 0, again.stderr
    assert (out / "stats.csv").exists()
    assert _leftovers(run, out) == []


@pytest.mark.filterwarnings("ignore::canopyblocks.errors.CanopyBlocksWarning")
def test_rerun_removes_partial_files_a_killed_batch_left(batch_inputs, tmp_path) -> None:
    """A batch killed with SIGKILL cannot clean up; the next run removes its parts."""
    from canopyblocks.workflows.batch import BatchConfig, run_batch

    granules, tiles = batch_inputs
    out = tmp_path / "out"
    stale = [out / "rasters" / "lasR_bcts_1-0" / ".dtm.x1y2z3.part.tif",
             out / "parts" / "ATL03_int0" / "gt1r" / ".blocks.abc.part.parquet"]
    for p in stale:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"half a file")
    run_batch([granules], [tiles], out, BatchConfig(offset=0.0))
    assert not any(p.exists() for p in stale)
    assert [p for p in out.rglob("*") if ".part" in p.name] == []
