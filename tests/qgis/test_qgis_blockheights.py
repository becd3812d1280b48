"""canopyblocks:blockheights through real headless QGIS on the real ATL03 clip."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.qgis]

N_PHOTONS_GT1R = 6809  # data/README.md: photons of beam gt1r in vegr_atl03_clip.h5


@pytest.fixture(scope="module")
def direct_blocks(atl03_sample: Path):
    """The core called directly with the same parameters as the QGIS runs below."""
    from canopyblocks.blocks import BlockParams, compute_blocks
    from canopyblocks.errors import SparseBlockWarning
    from canopyblocks.readers import open_track

    track = open_track(atl03_sample, beam="gt1r")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SparseBlockWarning)
        blocks = compute_blocks(track, BlockParams(lengths=(25.0, 10.0), min_photons=5))
    return track, blocks


def _run_blocks(run_alg, src: Path, out: Path, **extra):
    from qgis_plugin.algorithms.blockheights import preset_options

    # the paper's method, which the core's compute_blocks above computes
    paper = [name for _, name in preset_options()[0]].index("paper")
    params = {"INPUT": str(src), "TRACK": "gt1r", "LENGTHS": "25, 10", "MIN_PHOTONS": 5,
              "PRESET": paper, "OUTPUT": str(out)}
    params.update(extra)
    return run_alg("canopyblocks:blockheights", params)


def test_blockheights_matches_core_and_photon_count(run_alg, open_layer, layer_rows,
                                                    atl03_sample, direct_blocks, tmp_path):
    out = tmp_path / "blocks.gpkg"
    png = tmp_path / "profile.png"
    photons = tmp_path / "photons.gpkg"
    res = _run_blocks(run_alg, atl03_sample, out, PROFILE=str(png), PHOTONS=str(photons))
    assert str(res["OUTPUT"]).startswith(str(out))
    layer = open_layer(out)
    # the track's UTM zone: lon -106.57 -> zone 13 north
    assert layer.crs().authid() == "EPSG:32613"
    names = [f.name() for f in layer.fields()]
    for col in ("track", "length", "block", "s_start", "s_end", "x", "y", "lon", "lat",
                "n_photons", "n_kept", "n_between", "top", "ground", "hmax", "z90", "h90",
                "flag"):
        assert col in names
    rows = layer_rows(layer)
    track, direct = direct_blocks
    assert len(rows) == len(direct)
    # every photon lies in exactly one block of each length (s0 = track start)
    for length in (25.0, 10.0):
        assert sum(r["n_photons"] for r in rows if r["length"] == length) == N_PHOTONS_GT1R
        sub = [r for r in rows if r["length"] == length]
        # blocks are length metres long
        assert all(math.isclose(r["s_end"] - r["s_start"], length, abs_tol=1e-6) for r in sub)
    # values equal the core's, row by row (keyed by length and block index)
    key = {(float(r["length"]), int(r["block"])): r for r in rows}
    for d in direct.itertuples():
        r = key[(float(d.length), int(d.block))]
        assert r["flag"] == d.flag
        assert r["n_kept"] == d.n_kept
        for col in ("top", "ground", "hmax", "h90"):
            v = getattr(d, col)
            if np.isnan(v):
                assert r[col] is None
            else:
                assert r[col] == pytest.approx(v, abs=1e-9)
        assert r["_xy"] == pytest.approx((d.x, d.y), abs=1e-6)
    # hmax = top - ground on the QGIS side too
    ok = [r for r in rows if r["flag"] in ("ok", "implausible")]  # unfiltered daytime clip: tall
    assert ok, "the forest clip must give some ok blocks"
    assert all(r["hmax"] == pytest.approx(r["top"] - r["ground"], abs=1e-9) for r in ok)
    # the profile PNG and the labelled photons
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ph = open_layer(photons)
    assert ph.featureCount() == N_PHOTONS_GT1R
    lab_idx = ph.fields().indexOf("label_25m")
    assert lab_idx >= 0 and ph.fields().indexOf("label_10m") >= 0
    n_noise = sum(1 for f in ph.getFeatures() if f.attributes()[lab_idx] == "noise")
    removed = sum(r["n_photons"] - r["n_kept"] for r in rows if r["length"] == 25.0)
    assert n_noise == removed


def test_blockheights_progress_and_cancel(run_alg, atl03_sample, tmp_path):
    from qgis.core import QgsProcessingException, QgsProcessingFeedback

    seen: list[float] = []
    fb = QgsProcessingFeedback()
    fb.progressChanged.connect(seen.append)
    run_alg("canopyblocks:blockheights",
            {"INPUT": str(atl03_sample), "TRACK": "gt1r", "LENGTHS": "25",
             "OUTPUT": str(tmp_path / "a.gpkg")}, feedback=fb)
    assert seen and max(seen) >= 95.0
    assert all(0.0 <= p <= 100.0 for p in seen)

    cancelled = QgsProcessingFeedback()
    cancelled.cancel()
    out = tmp_path / "b.gpkg"
    with pytest.raises(QgsProcessingException, match="cancel"):
        run_alg("canopyblocks:blockheights",
                {"INPUT": str(atl03_sample), "TRACK": "gt1r", "LENGTHS": "25",
                 "OUTPUT": str(out)}, feedback=cancelled)
    assert not out.exists()


def test_blockheights_core_errors_become_processing_errors(run_alg, atl03_sample, tmp_path):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="gt9x"):
        _run_blocks(run_alg, atl03_sample, tmp_path / "c.gpkg", TRACK="gt9x")
    with pytest.raises(QgsProcessingException, match="block lengths"):
        _run_blocks(run_alg, atl03_sample, tmp_path / "d.gpkg", LENGTHS="25, -3")
    bad = tmp_path / "truncated.h5"
    bad.write_bytes(atl03_sample.read_bytes()[:4096])
    with pytest.raises(QgsProcessingException, match="truncated.h5"):
        _run_blocks(run_alg, bad, tmp_path / "e.gpkg")
    assert not (tmp_path / "e.gpkg").exists()
