"""``--bbox`` gives the full run's blocks: the same along-track grid (the origin a run of
the whole track takes, not the box's first photon) and every block meeting the box whole.

Independent check: the full run (no box) of the same file with the same estimators is the
truth; every block of the box run must be one of its blocks (same track, length, index,
start and end) with every column equal: photon counts, heights, flag, centre.  Boxes in the
middle of a track and at its far end (further from the track's start than any margin read,
so the origin must come from the track's start).  The paper's method, at 10, 25 and 50 m,
on a simulated track over the bundled survey and on the bundled real ATL03 clip; the
icesat2 preset (density filter) on the clip.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from canopyblocks import BlockParams, blocks_from_file
from canopyblocks.blocks.estimators import preset

ATL03 = "icesat2/vegr_atl03_clip.h5"
LENGTHS = (10.0, 25.0, 50.0)
#: boxes on the clip (it runs north to south, 820 m): its middle; its southern end, 684 m
#: after its start
CLIP_BOXES = {"middle": (-106.58, 41.5335, -106.56, 41.5365),
              "far end": (-106.58, 41.5310, -106.56, 41.5330)}
COLUMNS = ("s_start", "s_end", "n_photons", "n_kept", "n_between", "top", "ground", "hmax",
           "z90", "h90", "flag", "x", "y", "lon", "lat")


@pytest.fixture(scope="module")
def simulated(tmp_path_factory, sample) -> str:
    """A simulated ATL03-layout granule over the bundled survey: two beams (realisations)
    along one line at 10 degrees."""
    from canopyblocks.readers import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03

    pts = read_las([sample("als/lasR_bcts_1.laz"), sample("als/lasR_bcts_2.laz")])
    track = line_through(pts.bounds, 10.0, inset=7, name="gt1r")
    sim = simulate_photons(pts, track, SimParams(), realisations=2, seed=1)
    out = tmp_path_factory.mktemp("bbox_grid") / "sim.h5"
    write_simulation_atl03(sim, out, realisations=(0, 1))
    return str(out)


def _runs(path: str, box: tuple[float, float, float, float], name: str,
          s0: float | None = None, workers: int = 1) -> tuple[pd.DataFrame, pd.DataFrame]:
    params = BlockParams(lengths=LENGTHS, s0=s0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = blocks_from_file(path, params, estimators=preset(name), workers=1).blocks
        part = blocks_from_file(path, params, estimators=preset(name), bbox=box,
                                workers=workers).blocks
    return pd.DataFrame(full), pd.DataFrame(part)


def _assert_full_run_blocks(full: pd.DataFrame, part: pd.DataFrame, per_length: int = 3
                            ) -> None:
    key = ["track", "length", "block"]
    m = part.merge(full, on=key, how="left", suffixes=("_box", "_full"), indicator=True)
    assert (m["_merge"] == "both").all(), "box blocks that are not blocks of the full run"
    for col in COLUMNS:
        a, b = m[f"{col}_box"], m[f"{col}_full"]
        if pd.api.types.is_numeric_dtype(b):
            np.testing.assert_allclose(a.to_numpy(float), b.to_numpy(float), rtol=0,
                                       atol=1e-9, equal_nan=True, err_msg=col)
        else:
            assert (a.to_numpy() == b.to_numpy()).all(), col
    for length in LENGTHS:  # a stretch of the track at each length, not a stray block
        assert int((part["length"] == length).sum()) >= per_length, length


def _box_of(path: str, lo: float, hi: float) -> tuple[float, float, float, float]:
    """A box over the fraction ``lo``..``hi`` of the track's latitudes."""
    from canopyblocks.readers import open_track

    t = open_track(path)
    a, b = float(np.min(t.lat)), float(np.max(t.lat))
    return (float(np.min(t.lon)) - 0.01, a + lo * (b - a), float(np.max(t.lon)) + 0.01,
            a + hi * (b - a))


@pytest.mark.parametrize("where", sorted(CLIP_BOXES))
def test_paper_box_blocks_are_the_full_runs_on_the_real_clip(where, sample) -> None:
    full, part = _runs(str(sample(ATL03)), CLIP_BOXES[where], "paper")
    _assert_full_run_blocks(full, part)


@pytest.mark.parametrize("s0", [None, 0.0])
@pytest.mark.parametrize("span", [(0.3, 0.6), (0.0, 0.2)])
def test_paper_box_blocks_are_the_full_runs_on_a_simulated_track(simulated, s0, span) -> None:
    full, part = _runs(simulated, _box_of(simulated, *span), "paper", s0=s0)
    assert part["track"].nunique() == 2
    _assert_full_run_blocks(full, part)


def test_beams_blocked_in_worker_processes_give_the_same_blocks(simulated) -> None:
    full, part = _runs(simulated, _box_of(simulated, 0.3, 0.6), "paper", workers=2)
    assert part["track"].nunique() == 2
    _assert_full_run_blocks(full, part)


def test_edge_blocks_are_whole(sample) -> None:
    """The first and last box blocks of each length reach beyond the box's photons and
    still hold all of the full run's photons (not the box's share of them)."""
    from canopyblocks.readers import read_atl03

    box = CLIP_BOXES["middle"]
    inside = read_atl03(sample(ATL03), "gt1r", bbox=box)
    lo, hi = float(np.min(inside.s)), float(np.max(inside.s))
    full, part = _runs(str(sample(ATL03)), box, "paper")
    reaching = part[(part["s_start"] < lo) | (part["s_end"] > hi)]
    _assert_full_run_blocks(full, reaching, per_length=2)  # one at each end


@pytest.mark.parametrize("where", sorted(CLIP_BOXES))
def test_density_filtered_box_blocks_are_the_full_runs(where, sample) -> None:
    """The icesat2 preset's density filter: its background segments start at the track's
    start in the box run too, so its blocks equal the full run's even far from it."""
    full, part = _runs(str(sample(ATL03)), CLIP_BOXES[where], "icesat2")
    _assert_full_run_blocks(full, part)


@pytest.mark.parametrize("name", ["atl08", "mabel"])
def test_the_grid_is_the_full_runs_far_from_the_track_start(name, sample) -> None:
    """Beyond the margin the classifier reads, the box's blocks still start where the
    full run's do; their heights may differ there (the classifier's and the ground
    surface's windows start at the first photon read), and a warning says so."""
    full, part = _runs(str(sample(ATL03)), CLIP_BOXES["far end"], name)
    m = part.merge(full, on=["track", "length", "s_start", "s_end"], how="left",
                   indicator=True)
    assert len(part) >= 9 and (m["_merge"] == "both").all()
    with pytest.warns(UserWarning, match="can differ from a run over the whole track"):
        blocks_from_file(str(sample(ATL03)), BlockParams(lengths=(25.0,)),
                         estimators=preset(name), bbox=CLIP_BOXES["far end"], workers=1)


@pytest.mark.parametrize(("name", "where"), [("paper", "far end"), ("icesat2", "far end"),
                                             ("atl08", "middle")])
def test_no_such_warning_where_the_blocks_equal_the_full_runs(name, where, sample) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        blocks_from_file(str(sample(ATL03)), BlockParams(lengths=(25.0,)),
                         estimators=preset(name), bbox=CLIP_BOXES[where], workers=1)
    assert not [w for w in caught if "whole track" in str(w.message)]


def test_the_origin_is_the_track_start_without_reading_the_track(sample) -> None:
    from canopyblocks.readers import open_track, read_atl03
    from canopyblocks.readers.atl03 import atl03_track_start
    from canopyblocks.workflows.box_context import grid_origin

    path = str(sample(ATL03))
    whole = read_atl03(path, "gt1r")
    start = atl03_track_start(path, "gt1r")
    assert start is not None and abs(start - float(np.min(whole.s))) < 25.0
    got, first = grid_origin(open_track, path, {"beam": "gt1r"},
                             box_start=float(whole.s.max()), margin=50.0,
                             estimators=preset("paper"), crs=whole.crs)
    assert got == first == float(np.min(whole.s))


@pytest.mark.parametrize("name", ["paper", "atl08"])
def test_warnings_count_the_box_blocks_only(name, sample) -> None:
    """The margin's blocks (cut away, some cut short) are not counted in the warnings."""
    import re

    from canopyblocks.errors import SparseBlockWarning

    params = BlockParams(lengths=LENGTHS, min_photons=60)  # some sparse blocks
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        part = blocks_from_file(str(sample(ATL03)), params, estimators=preset(name),
                                bbox=CLIP_BOXES["middle"], workers=1).blocks
    said = [str(w.message) for w in caught if issubclass(w.category, SparseBlockWarning)]
    n = int((part["flag"] == "sparse").sum())
    assert n > 0 and len(said) == 1, said
    assert re.search(rf"\b{n} of {len(part)} blocks\b", said[0]), said[0]


def test_the_density_filter_of_a_part_keeps_what_the_whole_keeps(sample) -> None:
    """With ``origin`` at the track's first photon, a part of the track read with 420 m
    each side (two segments and a box) keeps, away from its ends, exactly the photons the
    filter of the whole track keeps; anchored on its own first photon it does not."""
    from dataclasses import replace

    from canopyblocks.blocks.density_filter import DensityParams, density_filter
    from canopyblocks.readers import read_atl03

    t = read_atl03(sample(ATL03), "gt1r")
    s, h = np.asarray(t.s, float), np.asarray(t.h, float)
    p = DensityParams()
    whole = density_filter(s, h, p).keep
    assert np.array_equal(density_filter(s, h, replace(p, origin=float(s.min()))).keep, whole)
    lo = float(s.min()) + 110.0
    part = s >= lo
    inner = s[part] >= lo + 420.0
    anchored = density_filter(s[part], h[part], replace(p, origin=float(s.min()))).keep
    own = density_filter(s[part], h[part], p).keep
    assert inner.sum() > 1000
    assert np.array_equal(anchored[inner], whole[part][inner])
    assert not np.array_equal(own[inner], whole[part][inner])
    with pytest.raises(Exception, match="origin"):
        DensityParams(origin=float("nan"))
