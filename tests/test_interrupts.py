"""Interrupted commands leave nothing behind (issue 10).

SIGINT (Ctrl-C: to the process, or to its whole process group as a terminal does) and
SIGTERM (``kill``, ``timeout``, SLURM, containers) are sent at several points of
``run``, ``rasters`` (real PDAL) and ``simulate``, each run as a subprocess with the
project's interpreter and a private TMPDIR.  Afterwards: no output (or exactly the
complete outputs the last line names), no ``*.part*`` file, nothing in the TMPDIR, no
live process of the run's session (PDAL included), exit status 130 / 143 and one line.

Also here: the all-or-nothing writers these commands rely on (``atomic_outputs``,
GeoPackage layers kept, several CSV layers written together).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

TOPO = "als/lidR_Topography.laz"
BCTS = "als/lasR_bcts_2.laz"  # the largest sample: a few seconds of PDAL


# ---- the subprocess and what it leaves -----------------------------------------------------------


def _session_processes(sid: int) -> list[str]:
    """Live (not zombie) processes of session ``sid``, as 'pid name'."""
    live = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if os.getsid(int(d.name)) != sid:
                continue
            stat = (d / "stat").read_text()
        except (OSError, ProcessLookupError):
            continue
        state = stat.rsplit(")", 1)[1].split()[0]
        if state not in ("Z", "X"):
            live.append(f"{d.name} {stat.split('(', 1)[1].split(')')[0]}")
    return live


def _children(pid: int) -> list[tuple[int, str]]:
    """(pid, command line) of the live descendants of ``pid``."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if os.getsid(int(d.name)) != pid or int(d.name) == pid:
                continue
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, ProcessLookupError):
            continue
        out.append((int(d.name), cmd))
    return out


class Run:
    """``python -m canopyblocks -q ARGS`` in its own session with a private TMPDIR."""

    def __init__(self, args: list[str], tmp: Path) -> None:
        self.tmp = tmp
        self.tmpdir = tmp / "tmpdir"
        self.tmpdir.mkdir()
        env = dict(os.environ, TMPDIR=str(self.tmpdir), TMP=str(self.tmpdir),
                   TEMP=str(self.tmpdir))
        self.start = time.monotonic()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "canopyblocks", "-q", *args], stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True, env=env, cwd=tmp, start_new_session=True)

    def wait_until(self, ready: Callable[[], bool], timeout: float = 120.0) -> bool:
        """Poll ``ready`` every 5 ms; False when the process ended first."""
        while not ready():
            if self.proc.poll() is not None:
                return False
            if time.monotonic() - self.start > timeout:
                raise AssertionError("the stage never came")
            time.sleep(0.005)
        return True

    def send(self, sig: int, group: bool) -> None:
        if group:
            os.killpg(self.proc.pid, sig)
        else:
            self.proc.send_signal(sig)

    def finish(self, timeout: float = 60.0) -> tuple[int, str]:
        try:
            _, err = self.proc.communicate(timeout=timeout)
        finally:
            if self.proc.poll() is None:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        return self.proc.returncode, err

    def no_live_process(self) -> None:
        t0 = time.monotonic()
        while (live := _session_processes(self.proc.pid)) and time.monotonic() - t0 < 10:
            time.sleep(0.05)
        if live:
            os.killpg(self.proc.pid, signal.SIGKILL)
        assert not live, f"still running after the command ended: {live}"


def assert_interrupted_cleanly(run: Run, sig: int, outputs: list[Path], code: int,
                               err: str, *, may_die: bool = False) -> None:
    """Exit 128+sig with one line; no output unless that line names it complete."""
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if may_die and code == -sig:  # killed before the handler was installed: nothing written
        assert lines == [], err
    elif code == 0:  # the run ended before the signal arrived: everything must be there
        for p in outputs:
            assert p.exists(), f"exit 0 but {p} missing"
    else:
        assert code == 128 + sig, (code, err)
        assert len(lines) == 1, err
        line = lines[0]
        assert line.startswith("canopyblocks: error: interrupted"), line
        assert ("SIGTERM" in line) == (sig == signal.SIGTERM), line
        for p in outputs:
            if p.exists():
                assert str(p) in line or str(p.name) in line, \
                    f"{p} left behind, not named complete: {line}"
        if "complete outputs" not in line:
            assert "no output was written" in line, line
            for p in outputs:
                assert not p.exists(), f"{p} left after: {line}"
    assert [p for p in run.tmp.rglob("*") if ".part" in p.name] == []
    assert list(run.tmpdir.iterdir()) == [], f"left in TMPDIR: {list(run.tmpdir.iterdir())}"
    run.no_live_process()


def _pdal_running(run: Run, name: str = "") -> Callable[[], bool]:
    return lambda: any(" pipeline " in cmd and name in cmd
                       for _, cmd in _children(run.proc.pid))


def _exists(p: Path) -> Callable[[], bool]:
    return p.exists


def _after(run: Run, seconds: float) -> Callable[[], bool]:
    return lambda: time.monotonic() - run.start >= seconds


def _opened_then(run: Run, path: Path, seconds: float) -> Callable[[], bool]:
    """``seconds`` after the process was first seen holding ``path`` open (reading it)."""
    seen: list[float] = []
    target = str(path.resolve())

    def ready() -> bool:
        if not seen:
            try:
                fds = list(Path(f"/proc/{run.proc.pid}/fd").iterdir())
                if any(os.readlink(fd) == target for fd in fds):
                    seen.append(time.monotonic())
            except OSError:
                pass
            return False
        return time.monotonic() - seen[0] >= seconds
    return ready


SIGNALS = {"int": (signal.SIGINT, False), "int-group": (signal.SIGINT, True),
           "term": (signal.SIGTERM, False), "term-group": (signal.SIGTERM, True)}

# ---- run -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("stage,how", [
    ("startup", "int"), ("startup", "term"),
    ("photons_atl03.h5", "term"), ("blocks.gpkg", "int-group"), ("pdal", "term"),
    ("rasters", "term-group")])
def test_run_interrupted(sample, pdal_bin, tmp_path, stage, how) -> None:
    out = tmp_path / "run"
    run = Run(["run", str(sample(TOPO)), "-o", str(out), "--realisations", "3",
               "--length", "25"], tmp_path)
    ready = {"startup": _after(run, 0.3), "pdal": _pdal_running(run)}.get(
        stage, _exists(out / stage))
    sig, group = SIGNALS[how]
    if run.wait_until(ready):
        run.send(sig, group)
    code, err = run.finish()
    assert_interrupted_cleanly(run, sig, [out / "report.html", out / "blocks.gpkg"], code, err,
                               may_die=stage == "startup" and sig == signal.SIGTERM)
    if code != 0:
        assert not out.exists(), sorted(p.name for p in out.rglob("*"))


# ---- rasters ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("stage,how", [
    ("startup", "int"), ("tiles", "int"), ("tiles", "term"), ("tiles", "int-group"),
    ("tiles", "term-group")])
def test_rasters_interrupted(sample, pdal_bin, tmp_path, stage, how) -> None:
    out = tmp_path / "rasters"
    run = Run(["rasters", str(sample(BCTS)), "-o", str(out), "--resolution", "1"], tmp_path)
    # "tiles": a second in, while the tiles are read and binned (no PDAL: one pass each)
    ready = {"startup": _after(run, 0.3), "tiles": _after(run, 1.0)}[stage]
    sig, group = SIGNALS[how]
    assert run.wait_until(ready), "rasters ended before the stage"
    t_signal = time.monotonic()
    run.send(sig, group)
    code, err = run.finish()
    assert code != 0, "the signal was ignored: rasters ran to its end"
    assert time.monotonic() - t_signal < 5.0, "the run did not stop within 5 s of the signal"
    assert_interrupted_cleanly(run, sig, [out / n for n in ("dtm.tif", "dsm_max.tif",
                                                            "dsm_p90.tif")], code, err)
    assert not out.exists(), sorted(p.name for p in out.rglob("*"))


# ---- simulate --------------------------------------------------------------------------------------


@pytest.mark.parametrize("stage,how", [("simulating", "int"), ("simulating", "term"),
                                       ("writing", "term"), ("writing", "int")])
def test_simulate_interrupted(sample, tmp_path, stage, how) -> None:
    out = tmp_path / "out"
    outputs = [out / "sim.h5", out / "photons.parquet", out / "report"]
    run = Run(["simulate", str(sample(TOPO)), "--azimuth", "30", "--realisations", "200",
               "--diameter", "13", "--diameter", "17", "-o", str(outputs[0]),
               "--photon-table", str(outputs[1]), "--report", str(outputs[2])], tmp_path)
    if stage == "simulating":  # the tile is read, the photons are being drawn
        ready = _opened_then(run, sample(TOPO), 0.3)
    else:
        def ready() -> bool:
            return out.exists() and any(".part" in p.name for p in out.rglob("*"))
    sig, group = SIGNALS[how]
    if run.wait_until(ready):
        run.send(sig, group)
    code, err = run.finish()
    assert_interrupted_cleanly(run, sig, outputs, code, err)
    if code != 0 and "complete outputs" not in err:
        assert not any(out.rglob("*")) if out.exists() else True, list(out.rglob("*"))


# ---- all outputs or none ---------------------------------------------------------------------------


def test_atomic_outputs_all_or_none(tmp_path) -> None:
    from canopyblocks.atomic import atomic_output, atomic_outputs
    from canopyblocks.errors import CancelledError
    from canopyblocks.progress import Progress

    a, b = tmp_path / "a.txt", tmp_path / "new" / "deep" / "b.txt"
    a.write_text("old")
    with pytest.raises(RuntimeError), atomic_outputs():
        with atomic_output(a) as t:
            t.write_text("new a")
        with atomic_output(b) as t:
            t.write_text("new b")
        assert a.read_text() == "old" and not b.exists()  # nothing renamed yet
        raise RuntimeError("the third output failed")
    assert a.read_text() == "old" and not (tmp_path / "new").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]
    # cancelled while writing: the last check before the renames stops it
    flag = {"cancel": False}
    with pytest.raises(CancelledError), \
            atomic_outputs(b, progress=Progress(cancelled=lambda: flag["cancel"])) as (tb,):
        tb.write_text("b")
        flag["cancel"] = True
    assert not b.exists() and not (tmp_path / "new").exists()
    with atomic_outputs(a, b) as (ta, tb):
        ta.write_text("A")
        tb.write_text("B")
    assert (a.read_text(), b.read_text()) == ("A", "B")
    assert [p for p in tmp_path.rglob("*") if ".part" in p.name] == []


def test_interrupt_while_writing_leaves_nothing(tmp_path) -> None:
    """KeyboardInterrupt (Ctrl-C or SIGTERM in the CLI) in the middle of the second file."""
    from canopyblocks.atomic import atomic_outputs
    from canopyblocks.outputs.tables import write_table

    df = pd.DataFrame({"x": np.arange(5.0)})
    with pytest.raises(KeyboardInterrupt), atomic_outputs():
        write_table(df, tmp_path / "one.csv")
        with atomic_outputs(tmp_path / "two.csv") as (t,):
            t.write_text("half")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_simulation_outputs_all_or_none(sample, tmp_path) -> None:
    """simulate's writer: an unwritable report leaves no HDF5 and no photon table."""
    from canopyblocks.errors import FileFormatError
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, seed002_experiment
    from canopyblocks.simulate.writers import write_simulation_outputs

    pts = read_las([sample(TOPO)])
    res = seed002_experiment(pts, line_through(pts.bounds, 0.0, inset=10.0), SimParams(),
                             diameters=(13.0,), realisations=2, seed=1)
    blocker = tmp_path / "report_is_a_file"
    blocker.write_text("x")
    with pytest.raises(FileFormatError, match="report_is_a_file"):
        write_simulation_outputs(res, tmp_path / "sim.h5", photon_table=tmp_path / "p.parquet",
                                 report=blocker)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report_is_a_file"]
    written = write_simulation_outputs(res, tmp_path / "sim.h5",
                                       photon_table=tmp_path / "p.parquet",
                                       report=tmp_path / "rep")
    assert {p.name for p in written} >= {"sim.h5", "p.parquet", "truth_residuals.csv",
                                         "residuals_by_cover.png", "truth_13m.csv"}
    assert all(p.exists() for p in written)


def test_simulation_outputs_removed_when_the_last_one_fails(sample, tmp_path,
                                                             monkeypatch) -> None:
    """The report fails after the HDF5, the photon table and one report file were written."""
    from canopyblocks.outputs.tables import write_table
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, seed002_experiment, writers

    pts = read_las([sample(TOPO)])
    res = seed002_experiment(pts, line_through(pts.bounds, 0.0, inset=10.0), SimParams(),
                             diameters=(13.0,), realisations=2, seed=1)

    def failing_report(folder, result):  # noqa: ANN001, ANN202
        write_table(result.table, Path(folder) / "truth_residuals.csv")
        raise OSError(28, "No space left on device", str(Path(folder) / "x.png"))

    monkeypatch.setattr(writers, "write_seed002_report", failing_report)
    out = tmp_path / "out"
    with pytest.raises(OSError, match="No space"):
        writers.write_simulation_outputs(res, out / "sim.h5", photon_table=out / "p.parquet",
                                         report=out / "rep")
    assert not out.exists(), sorted(str(p) for p in out.rglob("*"))


def test_geopackage_keeps_other_layers(tmp_path, caplog) -> None:
    import geopandas as gpd
    import pyogrio

    from canopyblocks.outputs.tables import write_table

    p = tmp_path / "out.gpkg"
    g = gpd.GeoDataFrame({"v": [1.0, 2.0]}, geometry=gpd.points_from_xy([0, 1], [0, 1]),
                         crs="EPSG:32612")
    write_table(g, p, layer="blocks")
    write_table(g, p, layer="photons", append=True)
    write_table(g.iloc[:1], p, layer="blocks")  # replaces blocks, keeps photons, says so
    assert sorted(n for n, _ in pyogrio.list_layers(p)) == ["blocks", "photons"]
    assert len(gpd.read_file(p, layer="blocks")) == 1
    assert len(gpd.read_file(p, layer="photons")) == 2
    assert any("photons" in r.getMessage() and "kept" in r.getMessage()
               for r in caplog.records if r.levelname == "WARNING")


def test_several_csv_layers_are_named_and_written_together(tmp_path) -> None:
    from canopyblocks.errors import InputError
    from canopyblocks.outputs.tables import check_output_path, layer_files, write_layers

    layers = {"residuals": pd.DataFrame({"a": [1.0]}), "stats": pd.DataFrame({"b": [2.0]})}
    files = layer_files(tmp_path / "v.csv", layers)
    assert [p.name for p in files.values()] == ["v_residuals.csv", "v_stats.csv"]
    first = write_layers(layers, tmp_path / "v.csv")
    assert first == files["residuals"] and first.exists() and files["stats"].exists()
    assert not (tmp_path / "v.csv").exists()
    # an output that would replace an input table is refused before any work
    src = tmp_path / "blocks.csv"
    src.write_text("x,y\n1,2\n")
    with pytest.raises(InputError, match="blocks.csv"):
        check_output_path(src, layers=["residuals"], reads=[(src, None)])
    gpkg = tmp_path / "b.gpkg"
    gpkg.write_bytes(b"")
    check_output_path(gpkg, layers=["residuals", "stats"], reads=[(gpkg, "blocks")])
    with pytest.raises(InputError, match="blocks"):
        check_output_path(gpkg, layers=["blocks"], reads=[(gpkg, "blocks")])


def test_cli_unwritable_report_is_one_line(sample, tmp_path) -> None:
    """simulate --report into a folder that cannot be made: exit 2, one line, nothing left."""
    from canopyblocks.cli import main

    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "-q", "simulate",
                        str(sample(TOPO)), "--azimuth", "0", "--realisations", "2",
                        "-o", str(tmp_path / "s.h5"), "--report", str(blocker / "report")],
                       capture_output=True, text=True, timeout=120)
    assert main is not None
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2, r.stderr
    assert len(lines) == 1 and lines[0].startswith("canopyblocks: error:"), r.stderr
    assert "report" in lines[0], lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_numpy_nan_warnings_do_not_reach_the_user(capsys) -> None:
    import warnings

    from canopyblocks.cli.log_setup import setup_logging

    with warnings.catch_warnings():
        warnings.simplefilter("default")
        setup_logging(0, False)
        np.nanmean(np.array([np.nan]))
        np.array([0.0]) / np.array([0.0])
        warnings.warn("something else", UserWarning, stacklevel=1)
    err = capsys.readouterr().err
    assert "Mean of empty slice" not in err and "invalid value" not in err, err
    assert "warning from test_interrupts (UserWarning): something else" in err


# ---- blocks in worker processes -----------------------------------------------------------------


@pytest.fixture(scope="module")
def six_beams(tmp_path_factory) -> Path:
    """A 6-beam granule large enough that its workers run for a while (~2.5 M photons)."""
    from canopyblocks.outputs.h5_layouts import Atl03BeamData, write_atl03

    rng = np.random.default_rng(11)
    beams = {}
    for i, b in enumerate(("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")):
        n = 700_000 if b.endswith("l") else 150_000
        s = np.sort(rng.random(n)) * (n / 15.0)
        h = 2400.0 + np.where(rng.random(n) < 0.5, rng.normal(0, 0.3, n), rng.random(n) * 25)
        beams[b] = Atl03BeamData(delta_time=s / 7000.0, lat=41.5 + s * 9e-6,
                                 lon=-106.57 + i * 1e-3 + s * 1e-7, h=h, s=s)
    return write_atl03(tmp_path_factory.mktemp("six") / "ATL03_six.h5", beams)


@pytest.mark.parametrize("how", ["term", "int-group"])
def test_blocks_with_workers_interrupted(six_beams, tmp_path, how) -> None:
    """SIGTERM to the command alone, or Ctrl-C to its process group, while its workers
    read and block beams: one line, exit 143/130, no output, no worker left running."""
    out = tmp_path / "blocks.gpkg"
    run = Run(["blocks", str(six_beams), "--length", "10", "--length", "25", "--workers",
               "2", "-o", str(out)], tmp_path)
    sig, group = SIGNALS[how]
    if run.wait_until(lambda: len(_children(run.proc.pid)) >= 2):
        time.sleep(0.2)
        run.send(sig, group)
    code, err = run.finish()
    assert_interrupted_cleanly(run, sig, [out], code, err)
    assert code != 0, "the run ended before its workers were interrupted: make it larger"


@pytest.mark.parametrize("forget", [False, True])
def test_interrupt_seen_by_an_extension_keeps_our_exit_status(forget, tmp_path) -> None:
    """A KeyboardInterrupt that went through code run with ``PyRun_*`` (as extension
    modules do) makes CPython 3.11 kill itself with SIGINT at exit when run as ``-m``, like
    the CLI; once reported, the CLI clears that record and exits 130 as it says (the
    ``rasters`` run interrupted at start-up ended -2 in 5 runs of 30)."""
    (tmp_path / "interrupted_cli.py").write_text(
        "import ctypes, sys\n"
        "ctypes.pythonapi.PyRun_SimpleString(b'raise KeyboardInterrupt')\n"
        + ("from canopyblocks.cli.common import _forget_native_interrupt\n"
           "_forget_native_interrupt()\n" if forget else "")
        + "sys.exit(130)\n")
    proc = subprocess.run([sys.executable, "-m", "interrupted_cli"], capture_output=True,
                          text=True, timeout=60, cwd=tmp_path)
    if not forget and proc.returncode == 130:
        pytest.skip("this Python does not record interrupts seen by PyRun_*")
    assert proc.returncode == (130 if forget else -signal.SIGINT), proc.stderr
