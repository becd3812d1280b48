"""``--bbox`` keeps the classifier's along-track context: photons read inside a box with a
margin, classified, then cut to the box, keep the classes and block heights of the full run.

Independent check: the full run of the bundled ATL03 clip (no box) is the truth; photons are
matched by (time, height), blocks by their index on one grid (the same ``s0``).
"""

from __future__ import annotations

import numpy as np
import pytest

from canopyblocks import BlockParams, blocks_from_file
from canopyblocks.blocks.estimators import preset

ATL03 = "icesat2/vegr_atl03_clip.h5"
BOX = (-106.58, 41.5338, -106.56, 41.5378)  # the middle half of the clip's track
INSIDE = 50.0  # metres inside the box's photons: these keep their class


def _key(track) -> list[tuple[float, float]]:
    return [(round(float(a), 7), round(float(b), 3)) for a, b in zip(track.time, track.h)]


@pytest.fixture(scope="module")
def s0(sample) -> float:
    from canopyblocks.readers import read_atl03

    return float(np.min(read_atl03(sample(ATL03), "gt1r").s))


@pytest.mark.parametrize("name", ["atl08", "icesat2"])
def test_a_box_keeps_the_classes_and_heights_of_the_full_run(name, s0, sample) -> None:
    params = BlockParams(lengths=(25.0,), s0=s0)  # one block grid for both runs
    est = preset(name)
    full = blocks_from_file(sample(ATL03), params, estimators=est, beams=("gt1r",),
                            with_photons=True, workers=1)
    box = blocks_from_file(sample(ATL03), params, estimators=est, beams=("gt1r",),
                           with_photons=True, bbox=BOX, workers=1)
    ft, bt = full.tracks[0], box.tracks[0]
    lon, lat = bt.lon, bt.lat
    assert ((lon >= BOX[0]) & (lon <= BOX[2]) & (lat >= BOX[1]) & (lat <= BOX[3])).all(), \
        "photons outside the box were returned"
    assert 2000 < len(bt) < len(ft)
    if name == "atl08":
        cls_full = dict(zip(_key(ft), ft.extra["classed_pc_flag"]))
        lo, hi = float(bt.s.min()), float(bt.s.max())
        inner = (bt.s >= lo + INSIDE) & (bt.s <= hi - INSIDE)
        got = np.asarray(bt.extra["classed_pc_flag"])[inner]
        want = np.array([cls_full[k] for k, i in zip(_key(bt), inner) if i])
        assert inner.sum() > 2000
        assert np.mean(got == want) >= 0.99, f"{100 * np.mean(got == want):.2f} % kept"
    fb = full.blocks.set_index(["length", "block"])
    bb = box.blocks.set_index(["length", "block"])
    same = [i for i in bb.index if i in fb.index
            and fb.loc[i, "n_photons"] == bb.loc[i, "n_photons"]]
    assert len(same) >= 15 and len(same) >= len(bb) - 2, (len(same), len(bb))
    for col in ("top", "ground", "hmax", "h90"):
        np.testing.assert_allclose(bb.loc[same, col].to_numpy(float),
                                   fb.loc[same, col].to_numpy(float), atol=1e-9,
                                   equal_nan=True, err_msg=col)
    assert (bb.loc[same, "flag"] == fb.loc[same, "flag"]).all()


def test_the_margin_comes_from_the_estimators_windows() -> None:
    from canopyblocks.workflows.box_context import REACH_FACTOR, context_margin

    atl08 = preset("atl08").atl08
    assert context_margin(preset("paper")) == 0.0  # per block: no context
    # ... but every block meeting the box is read whole: the longest block beyond it
    assert context_margin(preset("paper"), (10.0, 50.0, 25.0)) == 50.0
    assert context_margin(preset("icesat2"), (25.0,)) == context_margin(preset("icesat2")) + 25
    assert context_margin(None) == context_margin(preset("atl08"))
    assert context_margin(preset("atl08")) == REACH_FACTOR * (
        atl08.sparse_canopy_filter.segment + atl08.sparse_canopy_filter.along)
    d = preset("icesat2").density
    assert context_margin(preset("icesat2")) == REACH_FACTOR * (d.segment + d.along)
