"""Cancellation leaves nothing behind: ``Progress(cancelled=...)`` at every stage of the core
functions, and Ctrl-C (SIGINT) sent to a running ``canopyblocks run``.

The cancel probe counts its calls; a first run without cancelling counts how many checks
the operation makes, then the operation is cancelled at checks spread over that whole
range and must raise :class:`CancelledError` and leave its output folder as it was.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from canopyblocks import BlockParams
from canopyblocks.blocks import compute_blocks
from canopyblocks.errors import CancelledError
from canopyblocks.progress import Progress

TOPO = "als/lidR_Topography.laz"
ATL03 = "icesat2/vegr_atl03_clip.h5"
N_POINTS = 6  # cancellation points tried per operation (spread over all its checks)


class CancelAt:
    """``cancelled()`` probe: True from its ``at``-th call on (never when ``at`` is None)."""

    def __init__(self, at: int | None = None) -> None:
        self.at, self.calls = at, 0

    def __call__(self) -> bool:
        self.calls += 1
        return self.at is not None and self.calls >= self.at


def spread(total: int) -> list[int]:
    """Up to N_POINTS distinct check numbers from the first to the last of ``total``."""
    assert total >= 1
    return sorted({int(round(v)) for v in np.linspace(1, total, N_POINTS)})


def files_under(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")} if root.exists() else set()


def assert_cancels_everywhere(op, root: Path, skip_last: int = 1) -> int:
    """``op(progress)`` makes >= 3 checks; cancelled at any of them it raises and leaves
    ``root`` as it was.  Returns the number of checks of an uncancelled run.

    The last ``skip_last`` checks are left to the ``*_at_the_very_end`` tests: where a
    subprocess is polled, the number of checks varies by a few between runs.
    """
    before = files_under(root)
    probe = CancelAt()
    op(Progress(cancelled=probe))  # a full run: counts the checks
    total = probe.calls
    assert total >= 3, "the operation hardly checks for cancellation"
    for at in spread(total - skip_last):
        leftover = files_under(root) - before
        for rel in sorted(leftover, key=len, reverse=True):  # undo the full run's outputs
            p = root / rel
            p.rmdir() if p.is_dir() else p.unlink()
        probe = CancelAt(at)
        try:
            op(Progress(cancelled=probe))
        except CancelledError:
            # (one re-check is allowed: a caller may confirm a cancellation it was told of)
            assert at <= probe.calls <= at + 1, f"kept working after cancelling at {at}"
            assert files_under(root) == before, f"cancelled at check {at} of {total}"
        else:  # some checks poll a subprocess, so their number varies a little
            assert probe.calls < at, f"cancellation at check {at} of {total} was ignored"
    return total


@pytest.fixture(scope="module")
def track(sample):
    from canopyblocks.readers import read_atl03

    return read_atl03(sample(ATL03), "gt1r")


def test_compute_blocks_cancels(track, tmp_path) -> None:
    params = BlockParams(lengths=(10.0, 25.0, 50.0))
    assert_cancels_everywhere(lambda p: compute_blocks(track, params, progress=p), tmp_path)


@pytest.mark.filterwarnings("ignore::canopyblocks.errors.SparseBlockWarning")  # the clip's
def test_blocks_from_file_cancels_without_output(sample, tmp_path) -> None:
    from canopyblocks.workflows.blocks import blocks_from_file

    out = tmp_path / "out"
    out.mkdir()
    params = BlockParams(lengths=(10.0, 25.0))
    assert_cancels_everywhere(
        lambda p: blocks_from_file(sample(ATL03), params, output=out / "b.gpkg",
                                   with_photons=True, profile=out / "profile.png",
                                   progress=p), out)


def test_read_las_cancels(sample) -> None:
    from canopyblocks.readers.las import read_las

    with pytest.raises(CancelledError):
        read_las([sample(TOPO)], progress=Progress(cancelled=CancelAt(2)))


def test_simulate_photons_cancels(sample, tmp_path) -> None:
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons

    points = read_las([sample(TOPO)])
    track = line_through(points.bounds, 0.0, inset=10.0)
    assert_cancels_everywhere(
        lambda p: simulate_photons(points, track, SimParams(), realisations=2, seed=1,
                                   progress=p), tmp_path)


@pytest.fixture(scope="module")
def chain_out(sample, tmp_path_factory):
    """A simulated chain over the Topography tile (photons, blocks, rasters)."""
    from canopyblocks.workflows.chain import run_chain

    out = tmp_path_factory.mktemp("chain") / "run"
    run_chain([sample(TOPO)], out, params=BlockParams(lengths=(25.0,)), realisations=0)
    return out


def test_make_reference_rasters_cancels_without_output(sample, tmp_path) -> None:
    from canopyblocks.reference.rasters import make_reference_rasters

    out = tmp_path / "rasters"
    out.mkdir()
    assert_cancels_everywhere(
        lambda p: make_reference_rasters([sample(TOPO)], out, resolution=4.0, progress=p), out,
        skip_last=5)


def test_make_reference_rasters_cancelled_at_the_very_end(sample, tmp_path) -> None:
    """A cancel asked once the outputs exist is too late: the run completes, whole."""
    import rasterio

    from canopyblocks.reference.rasters import make_reference_rasters

    out = tmp_path / "rasters"
    out.mkdir()
    res = make_reference_rasters([sample(TOPO)], out, resolution=4.0, progress=Progress(
        cancelled=lambda: (out / "dtm.tif").exists()))
    assert files_under(out) == {"dtm.tif", "dsm_max.tif", "dsm_p90.tif", "dtm_fill_mask.tif"}
    for p in (res.dtm, res.dsm_max, res.dsm_p90, res.dtm_fill_mask):
        with rasterio.open(p) as src:
            assert src.read(1).shape == (res.grid.height, res.grid.width)


def test_blocks_from_file_cancelled_at_the_very_end(sample, tmp_path) -> None:
    """A check after the outputs are written would leave them: there is none (or it cleans)."""
    from canopyblocks.workflows.blocks import blocks_from_file

    out = tmp_path / "out"
    out.mkdir()
    probe = lambda: (out / "b.gpkg").exists()  # noqa: E731
    try:
        blocks_from_file(sample(ATL03), BlockParams(), output=out / "b.gpkg",
                         profile=out / "p.png", progress=Progress(cancelled=probe))
    except CancelledError:
        assert files_under(out) == set()
    else:
        assert files_under(out) == {"b.gpkg", "p.png"}


def test_run_chain_cancelled_at_the_very_end(sample, tmp_path) -> None:
    from canopyblocks.workflows.chain import run_chain

    out = tmp_path / "run"
    with pytest.raises(CancelledError):
        run_chain([sample(TOPO)], out, params=BlockParams(lengths=(25.0,)), realisations=0,
                  progress=Progress(cancelled=lambda: (out / "report.html").exists()))
    assert not out.exists()


def test_validate_blocks_cancels(chain_out, tmp_path) -> None:
    import geopandas as gpd

    from canopyblocks.validation.block_validation import validate_blocks

    blocks = gpd.read_file(chain_out / "blocks.gpkg", layer="blocks")
    r = chain_out / "rasters"
    assert_cancels_everywhere(
        lambda p: validate_blocks(blocks, dtm=r / "dtm.tif", dsm_max=r / "dsm_max.tif",
                                  dsm_p90=r / "dsm_p90.tif", width=13.0, offset=0.0,
                                  photon_vertical_crs=blocks.crs, progress=p), tmp_path)


@pytest.mark.parametrize("existing", [False, True], ids=["new-folder", "existing-folder"])
def test_run_chain_cancels_without_output(sample, tmp_path, existing) -> None:
    from canopyblocks.workflows.chain import run_chain

    root = tmp_path / "parent"
    root.mkdir()
    out = root / "run"
    if existing:
        out.mkdir()
        (out / "notes.txt").write_text("mine")
    total = assert_cancels_everywhere(
        lambda p: run_chain([sample(TOPO)], out, params=BlockParams(lengths=(25.0,)),
                            realisations=2, progress=p), root)
    assert total > 10
    if existing:
        assert (out / "notes.txt").read_text() == "mine"


def _wait_for(path: Path, timeout: float) -> None:
    t0 = time.monotonic()
    while not path.exists():
        if time.monotonic() - t0 > timeout:
            raise AssertionError(f"{path} never appeared")
        time.sleep(0.05)


@pytest.mark.parametrize("whole_group", [False, True], ids=["python-only", "process-group"])
@pytest.mark.parametrize("stage", ["photons_atl03.h5", "blocks.gpkg", "rasters"])
def test_ctrl_c_during_run_leaves_no_files(sample, tmp_path, stage, whole_group) -> None:
    """SIGINT once ``stage`` exists under the output folder (the run is then mid-way)."""
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "canopyblocks", "-q", "run", str(sample(TOPO)), "-o", str(out),
         "--realisations", "3", "--length", "25"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=whole_group)
    try:
        _wait_for(out / stage, 120)
        if whole_group:  # what a terminal does: the PDAL child gets it too
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("canopyblocks: error:"), err
    assert sum(ln.startswith("canopyblocks: error:") for ln in lines) == 1, err
    assert not out.exists(), files_under(out)
    assert list(tmp_path.rglob("*.part*")) == []
