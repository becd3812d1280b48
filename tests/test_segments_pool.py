"""``segments`` classifies the beams of a granule in the worker pool ``blocks`` reads with,
and the table is the one a single process makes, value for value."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from canopyblocks.outputs.h5_layouts import Atl03BeamData, write_atl03
from canopyblocks.progress import Progress
from canopyblocks.workflows.segments import segments_from_file


@pytest.fixture(scope="module")
def granule(tmp_path_factory):
    """Three beams of a forest track with night background, as an ATL03 file."""
    rng = np.random.default_rng(4)
    beams = {}
    for i, b in enumerate(("gt1l", "gt2l", "gt3l")):
        n = 30_000 + 5_000 * i
        s = np.sort(rng.random(n)) * (n / 15.0)
        u = rng.random(n)
        h = 300.0 + 0.05 * s + np.where(u < 0.45, rng.normal(0, 0.3, n),
                                       np.where(u < 0.85, rng.random(n) * 20.0,
                                                rng.uniform(-60, 90, n)))
        beams[b] = Atl03BeamData(delta_time=s / 7000.0, lat=41.5 + s * 9.0e-6,
                                 lon=-106.57 + i * 1e-3 + s * 1e-7, h=h, s=s)
    path = tmp_path_factory.mktemp("pool") / "ATL03_pool.h5"
    write_atl03(path, beams)
    return path


@pytest.mark.filterwarnings("ignore:.*no usable bckgrd_atlas:canopyblocks.errors.CanopyBlocksWarning")
def test_segments_in_workers_equal_one_process(granule):
    one = segments_from_file(granule, length=100.0, workers=1)
    said: list[str] = []
    pool = segments_from_file(granule, length=100.0, workers=2,
                              progress=Progress(lambda f, m: said.append(m)))
    assert any(m.endswith(": classified") for m in said)  # the pool ran
    assert set(one["track"]) == {"gt1l", "gt2l", "gt3l"} and len(one) > 60
    pd.testing.assert_frame_equal(pd.DataFrame(pool), pd.DataFrame(one), check_exact=True)
    assert pool.crs == one.crs
