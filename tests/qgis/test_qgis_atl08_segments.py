"""canopyblocks:blockheights' atl08 estimators and ATL08-style segments through real headless
QGIS on the real ATL03 clip, against the core called directly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.qgis]


def test_blockheights_atl08_segments_match_core(run_alg, open_layer, layer_rows,
                                                atl03_sample: Path, tmp_path):
    from qgis_plugin.algorithms.blockheights import preset_options

    from canopyblocks.blocks.atl08_classify import classify_photons
    from canopyblocks.blocks.atl08_segments import atl08_segments
    from canopyblocks.readers import open_track

    track = open_track(atl03_sample, beam="gt1r")
    direct = atl08_segments(track, classify_photons(track), 50.0)
    atl08_index = [name for _, name in preset_options()[0]].index("atl08")
    seg_out = tmp_path / "segments.gpkg"
    photons = tmp_path / "photons.gpkg"
    run_alg("canopyblocks:blockheights", {
        "INPUT": str(atl03_sample), "TRACK": "gt1r", "LENGTHS": "25", "PRESET": atl08_index,
        "OUTPUT": str(tmp_path / "blocks.gpkg"), "PHOTONS": str(photons),
        "SEGMENTS": str(seg_out), "SEGMENT_LENGTH": 50.0})
    rows = layer_rows(open_layer(seg_out))
    assert len(rows) == len(direct)
    for r, d in zip(sorted(rows, key=lambda r: r["segment"]), direct.itertuples()):
        assert r["segment"] == d.segment
        assert r["n_te_photons"] == d.n_te_photons
        for col in ("h_te_best_fit", "h_canopy", "canopy_h_metrics_50", "canopy_openness"):
            v = getattr(d, col)
            assert (r[col] is None) if np.isnan(v) else r[col] == pytest.approx(v, abs=1e-9)
    flags = {r["classed_pc_flag"] for r in layer_rows(open_layer(photons))}
    assert flags <= {0, 1, 2, 3} and {1, 2}.issubset(flags)
