"""The accuracy benchmark's yardstick (bench/icesat2_scoring.py) against brute force and
against blocks whose errors are known."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from canopyblocks.readers.las import LasPoints

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
scoring = pytest.importorskip("icesat2_scoring")


def test_corridor_reference_equals_brute_force():
    rng = np.random.default_rng(4)
    n = 4000
    x, y = rng.random(n) * 120, rng.random(n) * 60
    cls = np.where(rng.random(n) < 0.4, 2, 1).astype(np.uint8)
    z = np.where(cls == 2, 0.05 * x, 0.05 * x + rng.random(n) * 30)
    pts = LasPoints.from_arrays(500_000 + x, 5_000_000 + y, z, crs=32610, classification=cls)
    # a line along +x through y = 30: blocks of 25 m, corridor +-6.5 m
    ref = scoring._corridor_reference(pts, 500_000.0, 5_000_030.0, 1.0, 0.0, 4)
    for k in range(4):
        inside = (x >= 25 * k) & (x < 25 * (k + 1)) & (np.abs(y - 30) <= 6.5)
        zs = np.sort(z[inside])
        g = z[inside & (cls == 2)].mean()
        assert ref["cor_ground"][k] == pytest.approx(g)
        assert ref["cor_hmax"][k] == pytest.approx(zs.max() - g)
        assert ref["cor_h90"][k] == pytest.approx(zs[int(np.floor(0.9 * (zs.size - 1)))] - g)


def _blocks(rng, n, bias, noise, site):
    """Blocks of each strength x light with Hmax = reference + bias + noise."""
    rows = []
    for beam in scoring.BEAMS:
        for light in scoring.LIGHTS:
            ref = rng.uniform(5, 30, n)
            ground = rng.uniform(100, 110, n)
            err = bias + noise * rng.standard_normal(n)
            rows.append(pd.DataFrame({
                "track": f"{site}|{beam}|{light}", "block": np.arange(n), "beam": beam,
                "light": light, "key": f"{beam}|{light}", "length": 25.0,
                "estimators": "x", "hmax": ref + err, "h90": ref + err - 1.0,
                "ground": ground + 0.5, "ref_ground": ground, "ref_hmax": ref,
                "ref_h90": ref - 1.0, "cor_ground": ground, "cor_hmax": ref + 3.0,
                "cor_h90": ref + 2.0, "floor_top": ground + ref + 1.0}))
    return pd.concat(rows, ignore_index=True)


def test_scores_of_blocks_with_known_errors():
    rng = np.random.default_rng(0)
    cal = _blocks(rng, 40, bias=-4.0, noise=0.0, site="cal")
    test = _blocks(rng, 40, bias=-4.0, noise=1.0, site="test")
    test.loc[test.index[:5], "hmax"] = np.nan  # five strong-night blocks not estimated
    t = scoring.score_blocks(cal, test).set_index(["beam", "light"])
    # the additive calibration removes the -4 m bias: what remains is the 1 m noise
    assert t["hmax_rmse_fp"].between(0.7, 1.3).all()
    assert t["hmax_rmse_corridor"].between(0.7, 1.3).all()
    assert np.allclose(t["ground_rmse"], 0.5)
    assert np.allclose(t["floor_fp"], 0.0, atol=1e-9)  # a constant offset, calibrated away
    assert t.loc[("strong", "night"), "estimated"] == pytest.approx(35 / 40)
    assert t.loc[("weak", "night"), "estimated"] == 1.0
    assert t.loc[("all", "all"), "n_blocks"] == 40 * 6
