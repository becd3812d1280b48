"""Gaussian decomposition (seed 003, DESIGN 4.4): known sums of Gaussians are recovered,
and on the real GEDI shots its ground agrees with L2A's (issue 8's bar: median
|difference| <= 0.2 m, >= 95 % within 1 m; measured 0.11 m and 98 %)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canopyblocks.errors import InputError
from canopyblocks.readers.gedi import read_gedi_l1b
from canopyblocks.readers.gedi_l2 import read_gedi_l2a
from canopyblocks.waveforms.batch import WaveformBatch
from canopyblocks.waveforms.decompose import decompose_waveforms, fit_gaussians

BEAMS = ("BEAM0001", "BEAM0010", "BEAM0011", "BEAM0101", "BEAM0110", "BEAM1000", "BEAM1011")


def _gauss(x: np.ndarray, a: float, c: float, s: float) -> np.ndarray:
    return a * np.exp(-0.5 * ((x - c) / s) ** 2)


def test_known_gaussians_are_recovered() -> None:
    rng = np.random.default_rng(5)
    x = np.arange(600.0)
    truth = np.array([[40.0, 180.0, 9.0], [25.0, 240.0, 12.0], [80.0, 400.0, 6.5]])
    y = sum(_gauss(x, *g) for g in truth) + rng.normal(0, 1.0, x.size)
    g = fit_gaussians(y, threshold=4.0)
    assert len(g) == 3
    np.testing.assert_allclose(g[:, 1], truth[:, 1], atol=0.5)
    np.testing.assert_allclose(g[:, 2], truth[:, 2], rtol=0.1)
    np.testing.assert_allclose(g[:, 0], truth[:, 0], rtol=0.1)
    assert fit_gaussians(rng.normal(0, 1.0, 300), threshold=6.0).shape == (0, 3)


def test_ground_of_a_synthetic_batch() -> None:
    """Two-layer canopy over ground: ground = the lowest peak, in metres."""
    rng = np.random.default_rng(2)
    n, m = 20, 500
    x = np.arange(m, dtype=float)
    g_idx = rng.uniform(330, 380, n)
    wf = np.array([230 + _gauss(x, 30, gi - 120, 10) + _gauss(x, 15, gi - 60, 8)
                   + _gauss(x, 60, gi, 6.5) + rng.normal(0, 1.5, m) for gi in g_idx])
    top = np.full(n, 1000.0)
    batch = WaveformBatch(
        beam="SIM", shot_number=np.arange(n, dtype=np.uint64), time=np.arange(n, dtype=float),
        waveforms=wf.astype(np.float32), n_samples=np.full(n, m, np.int64),
        elev_bin0=top, elev_lastbin=top - 0.15 * (m - 1), lat_bin0=np.zeros(n),
        lat_lastbin=np.zeros(n), lon_bin0=np.zeros(n), lon_lastbin=np.zeros(n),
        noise_mean=np.full(n, 230.0), noise_sd=np.full(n, 1.5),
        stale=np.zeros(n, bool), degraded=np.zeros(n, bool))
    res = decompose_waveforms(batch)
    np.testing.assert_allclose(res["ground_gauss"], 1000.0 - 0.15 * g_idx, atol=0.1)
    assert (res["n_gaussians"] == 3).all()
    with pytest.raises(InputError, match="max_gaussians"):
        decompose_waveforms(batch, max_gaussians=0)


def test_ground_agrees_with_l2a(gedi_l1b: Path, gedi_l2a: Path) -> None:
    ref = read_gedi_l2a(gedi_l2a).drop_duplicates("shot_number").set_index("shot_number")
    diffs = []
    for beam in BEAMS:
        b = read_gedi_l1b(gedi_l1b, beam)
        d = decompose_waveforms(b)
        r = ref.reindex(d["shot_number"])
        valid = ((r["quality_flag"] == 1) & (r["algrunflag"] == 1)).to_numpy() \
            & ~b.stale & ~b.degraded
        diffs.append((d["ground_gauss"].to_numpy() - r["ground"].to_numpy())[valid])
    dd = np.concatenate(diffs)
    assert np.isfinite(dd).mean() >= 0.98
    dd = np.abs(dd[np.isfinite(dd)])
    assert dd.size >= 250
    assert np.median(dd) <= 0.2
    assert np.mean(dd <= 1.0) >= 0.95


def test_process_waveforms_decompose_option(gedi_l1b: Path) -> None:
    from canopyblocks.waveforms.process import process_waveforms
    from canopyblocks.waveforms.settings import WaveformParams

    b = read_gedi_l1b(gedi_l1b, "BEAM1011")
    res = process_waveforms(b, WaveformParams(decompose=True))
    assert "ground_gauss" in res.columns
    ok = res["flag"] == "ok"
    assert np.median(np.abs(res.loc[ok, "ground_gauss"] - res.loc[ok, "ground"])) < 0.3
