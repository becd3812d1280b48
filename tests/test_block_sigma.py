"""The per-block uncertainty (blocks/uncertainty.py): hmax_sigma, ground_sigma, the
low_confidence flag and use.

Coverage is checked on simulated ICESat-2 tracks whose truth is known (the footprint-
matched reference from the airborne points), over a tile the model was never fitted on
(pyfor_test; fitted on lasR_bcts only) with seeds of its own; the flag/use logic against
hand-made tables; the columns in blocks, segments and the residuals layer.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from canopyblocks.blocks import BlockParams
from canopyblocks.blocks.estimators import estimate_blocks, preset
from canopyblocks.blocks.uncertainty import (
    FEATURES,
    SigmaModel,
    left_out_summary,
    mark_use,
    sigma_model,
)
from canopyblocks.errors import InputError
from canopyblocks.readers import read_atl03
from canopyblocks.readers.las import read_las
from canopyblocks.reference.footprint import FootprintCloud, block_footprint_reference
from canopyblocks.reference.footprint_params import FootprintReferenceParams
from canopyblocks.schema import BLOCK_COLUMNS, FLAG_LOW_CONFIDENCE
from canopyblocks.simulate import SimParams, line_through, simulate_photons
from canopyblocks.simulate.writers import write_simulation_atl03
from canopyblocks.validation.residuals import compute_residuals
from canopyblocks.validation.stats import block_stats

DATA = Path(__file__).resolve().parent / "data"
TILE = DATA / "als" / "pyfor_test.laz"  # never used to fit the model
A03 = DATA / "icesat2" / "vegr_atl03_clip.h5"
A08 = DATA / "icesat2" / "vegr_atl08_clip.h5"


def _model(hmax_max: float = 3.0, ground_max: float = 1.0) -> SigmaModel:
    return SigmaModel((0.0,) * len(FEATURES), (0.0,) * len(FEATURES), hmax_max, ground_max)


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> pd.DataFrame:
    """25 m atl08 blocks of strong and weak beams, night and day, over pyfor_test, joined
    to their footprint-matched reference."""
    tmp = tmp_path_factory.mktemp("sigma")
    pts = read_las([str(TILE)])
    cloud = FootprintCloud(pts, FootprintReferenceParams())
    frames = []
    for i, az in enumerate((15.0, 45.0, 75.0, 105.0, 135.0, 165.0)):
        line = line_through(pts.bounds, az, inset=9.5)
        for beam in ("strong", "weak"):
            for j, mhz in enumerate((0.15, 3.0)):
                sim = simulate_photons(pts, line, SimParams(beam=beam, background_rate_mhz=mhz),
                                       seed=7000 + 100 * i + 10 * j + (beam == "weak"))
                t = read_atl03(write_simulation_atl03(sim, tmp / "t.h5"), "gt1r", crs=pts.crs)
                t.track = f"{az:g}|{beam}|{mhz:g}"
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    b = estimate_blocks(t, BlockParams(lengths=(25.0,), s0=0.0),
                                        preset("atl08"))
                    ref = block_footprint_reference(b, cloud)
                b = pd.DataFrame(b.drop(columns="geometry"))
                b["ref_ground"] = ref["ref_ground"].to_numpy(float)
                b["ref_hmax"] = ref["ref_hmax"].to_numpy(float)
                b["ref_ok"] = (ref["ref_flag"] == "ok").to_numpy()
                b["beam"] = beam
                frames.append(b)
    df = pd.concat(frames, ignore_index=True)
    return df[df["ref_ok"] & np.isfinite(df["hmax"])]


def test_sigma_coverage_on_a_tile_never_fitted(simulated: pd.DataFrame) -> None:
    df = simulated
    assert len(df) > 150, len(df)
    zh = np.abs(df["hmax"] - df["ref_hmax"]) / df["hmax_sigma"]
    zg = np.abs(df["ground"] - df["ref_ground"]) / df["ground_sigma"]
    # a tolerant band around 68 % / 95 % (bench/bench_block_sigma.py measures the shares
    # on three unseen tiles). Measured here (191 blocks, no position offset): Hmax 0.84 /
    # 0.98, ground 0.82 / 0.99; strong 0.80 / 0.98, weak 0.87 / 0.98 (the model before the
    # geolocation term: 0.85 / 0.98, 0.79 / 0.98): on this open tile the model, fitted on
    # the denser calibration forest, is cautious, and the geolocation term widens ground
    assert 0.55 <= np.mean(zh <= 1) <= 0.93
    assert np.mean(zh <= 2) >= 0.88
    assert 0.50 <= np.mean(zg <= 1) <= 0.93
    assert np.mean(zg <= 2) >= 0.85
    for beam in ("strong", "weak"):  # each beam on its own, more tolerant still
        z = zh[df["beam"] == beam]
        assert 0.45 <= np.mean(z <= 1) <= 0.97 and np.mean(z <= 2) >= 0.85, beam
    # the sigma says something: weak beams are less certain than strong ones
    assert df.loc[df["beam"] == "weak", "hmax_sigma"].median() > \
        df.loc[df["beam"] == "strong", "hmax_sigma"].median()


def test_blocks_carry_sigma_flag_and_use(simulated: pd.DataFrame) -> None:
    df = simulated
    assert {"hmax_sigma", "ground_sigma", "use"} <= set(df.columns)
    ok = df["flag"] == "ok"
    assert (df["hmax_sigma"][np.isfinite(df["hmax"])] > 0).all()
    m = sigma_model()
    low = df["flag"] == FLAG_LOW_CONFIDENCE
    assert ((df["hmax_sigma"][low] > m.hmax_max) | (df["ground_sigma"][low] > m.ground_max)).all()
    assert (df["hmax_sigma"][ok] <= m.hmax_max).all() and (df["ground_sigma"][ok] <=
                                                            m.ground_max).all()
    assert (df["use"] == ok).all()


def test_mark_use_flags_only_ok_blocks_over_the_thresholds() -> None:
    t = pd.DataFrame({"flag": ["ok", "ok", "ok", "sparse", "ok", "implausible"],
                      "hmax_sigma": [1.0, 3.5, 1.0, np.nan, np.nan, 9.0],
                      "ground_sigma": [0.2, 0.2, 1.5, np.nan, np.nan, 0.1]})
    mark_use(t, _model(3.0, 1.0))
    assert list(t["flag"]) == ["ok", FLAG_LOW_CONFIDENCE, FLAG_LOW_CONFIDENCE, "sparse", "ok",
                               "implausible"]
    assert list(t["use"]) == [True, False, False, False, True, False]


def test_left_out_summary_counts_why() -> None:
    t = pd.DataFrame({"flag": ["ok", FLAG_LOW_CONFIDENCE, FLAG_LOW_CONFIDENCE, "sparse"],
                      "use": [True, False, False, False]})
    s = left_out_summary(t)
    assert s["n"] == 4 and s["n_used"] == 1 and s["n_left_out"] == 3
    assert s["n_low_confidence"] == 2 and s["by_flag"] == {FLAG_LOW_CONFIDENCE: 2, "sparse": 1}
    assert s["hmax_sigma_max"] == sigma_model().hmax_max


def test_sigma_model_is_checked() -> None:
    with pytest.raises(InputError, match="coefficients"):
        SigmaModel((1.0,), (0.0,) * len(FEATURES), 3.0, 1.0)
    with pytest.raises(InputError, match="hmax_max"):
        SigmaModel((0.0,) * len(FEATURES), (0.0,) * len(FEATURES), -1.0, 1.0)
    m = sigma_model()
    assert SigmaModel.from_json(m.to_json()) == m
    assert "calibration tiles" in m.fitted_on


def test_paper_blocks_have_nan_sigma_and_use_follows_flag() -> None:
    track = read_atl03(str(A03), "gt1r")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = estimate_blocks(track, BlockParams(lengths=(25.0,)), preset("paper"))
    assert list(b.columns[:len(BLOCK_COLUMNS)]) == list(BLOCK_COLUMNS)
    assert b["hmax_sigma"].isna().all() and b["ground_sigma"].isna().all()
    assert (b["use"] == (b["flag"] == "ok")).all()


def test_residuals_carry_sigma_and_leave_out_low_confidence() -> None:
    blocks = pd.DataFrame({"track": "a", "length": 25.0, "block": [0, 1, 2],
                           "ground": [10.0, 10.0, 10.0], "top": [30.0, 31.0, 50.0],
                           "hmax": [20.0, 21.0, 40.0], "h90": [15.0, 15.0, 15.0],
                           "flag": ["ok", "ok", FLAG_LOW_CONFIDENCE],
                           "hmax_sigma": [2.0, 2.5, 9.0], "ground_sigma": [0.3, 0.4, 0.5],
                           "use": [True, True, False]})
    ref = pd.DataFrame({"track": "a", "length": 25.0, "block": [0, 1, 2],
                        "ref_ground": 10.0, "ref_top": 30.0, "ref_top90": 25.0,
                        "ref_hmax": 20.0, "ref_h90": 15.0, "ref_flag": "ok"})
    r = compute_residuals(blocks, ref)
    assert list(r["hmax_sigma"]) == [2.0, 2.5, 9.0] and list(r["ground_sigma"]) == [0.3, 0.4, 0.5]
    assert list(r["use"]) == [True, True, False]
    ref.loc[1, "ref_flag"] = "outside"
    r2 = compute_residuals(blocks, ref)
    assert left_out_summary(r2)["by_flag"] == {"reference outside": 1, FLAG_LOW_CONFIDENCE: 1}
    st = block_stats(r, metrics=("hmax",))
    row = st[st["group"] == "all"].iloc[0]
    assert row["n"] == 2 and row["rmse"] == pytest.approx(np.sqrt(0.5))  # residuals 0 and 1


def test_segments_carry_sigma() -> None:
    from canopyblocks.workflows.segments import segments_from_file

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seg = segments_from_file(str(A03), beams=("gt1r",))
    assert {"hmax_sigma", "ground_sigma", "use"} <= set(seg.columns)
    has = np.isfinite(seg["h_canopy"])
    assert (seg["hmax_sigma"][has] > 0).all() and (seg["ground_sigma"][has] > 0).all()
    # the clip's ATL08 h_canopy differs from ours by 0.05-4.7 m (RMS ~2.2 m): the sigmas
    # of segments holding >100 signal photons are metres, not tens of metres
    full = seg["n_seg_ph"] > 100
    assert seg["hmax_sigma"][full].between(0.5, 8.0).all()


def test_segment_sigma_against_atl08_on_the_real_clip() -> None:
    """ATL08's own h_canopy on the Wyoming clip is an independent measurement of each
    segment's canopy height: our segments' h_canopy differ from it within 2 hmax_sigma on
    most whole segments; ATL08's h_canopy_uncertainty (31-68 m there) is another quantity
    (DESIGN 1.12)."""
    import h5py

    from canopyblocks.blocks.atl08_classify import classify_photons
    from canopyblocks.blocks.atl08_segments import atl08_segments
    from canopyblocks.blocks.uncertainty import add_segment_sigma

    track = read_atl03(str(A03), "gt1r")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        classes = classify_photons(track)
    with h5py.File(A03) as f:
        s0 = float(f["gt1r/geolocation/segment_dist_x"][0])
    with h5py.File(A08) as f:
        g = f["gt1r/land_segments/canopy"]
        theirs = g["h_canopy"][:8].astype(float)
        their_unc = g["h_canopy_uncertainty"][:8].astype(float)
    seg = add_segment_sigma(atl08_segments(track, classes, 100.0, s0), track, classes)
    ours = seg["h_canopy"].to_numpy(float)[:8]
    sig = seg["hmax_sigma"].to_numpy(float)[:8]
    within = np.abs(ours - theirs) <= 2 * sig
    assert within.sum() >= 6, (ours - theirs, sig)
    assert np.all(their_unc > 5 * sig)


def _one_block(slope: float, geo_sigma: float = np.nan) -> dict[str, np.ndarray]:
    """block_features' quantities of one 25 m block of a strong beam at night."""
    v = {"n_ground": 20.0, "n_canopy": 40.0, "n_top": 8.0, "n_noise": 2.0, "n_all": 62.0,
         "n_noise_top": 0.0, "n_noise_ground": 1.0, "background": 0.0014,
         "ground_spread": 0.5, "ground_offset": 0.05, "relief": 0.2, "slope": slope,
         "length": 25.0, "hmax": 15.0, "canopy_gradient": 0.5, "geo_sigma": geo_sigma}
    return {k: np.array([x], float) for k, x in v.items()}


def test_a_20_degree_slope_adds_the_geolocation_term_to_ground_sigma() -> None:
    """A horizontal error of G m (1 sigma) on ground sloping at 20 degrees is G tan(20 deg)
    m of height: added in quadrature to the same block's measurement part. G is ICESat-2's
    published 4.4 m (worst beam, Luthcke et al. 2021) when the file states none, else the
    file's sqrt(sigma_along^2 + sigma_across^2)."""
    from dataclasses import replace

    from canopyblocks.blocks.uncertainty import FEATURES, predict_sigma

    m = sigma_model()
    ground = list(m.ground)
    ground[FEATURES.index("log_slope")] = 0.0  # the measurement part: the same block
    same = replace(m, ground=tuple(ground))
    tan20 = np.tan(np.radians(20.0))
    for geo_sigma, g in ((np.nan, 4.4), (5.0, 5.0), (np.hypot(3.0, 4.0), 5.0)):
        _, flat = predict_sigma(_one_block(0.0, geo_sigma), same)
        _, steep = predict_sigma(_one_block(tan20, geo_sigma), same)
        assert flat[0] > same.floor  # (not floored)
        assert np.sqrt(steep[0] ** 2 - flat[0] ** 2) == pytest.approx(g * tan20, rel=1e-9)
    # the package's own model: at least the geolocation term, and more than flat
    _, flat = predict_sigma(_one_block(0.0), m)
    _, steep = predict_sigma(_one_block(tan20), m)
    assert steep[0] > flat[0] and steep[0] >= 4.4 * tan20 - 1e-12


def test_hmax_sigma_grows_with_canopy_relief_by_the_geolocation_term() -> None:
    from dataclasses import replace

    from canopyblocks.blocks.uncertainty import predict_sigma

    m = replace(sigma_model(), hmax_geo=0.5)
    flat = _one_block(0.0)
    rough = dict(flat, canopy_gradient=np.array([2.0]))
    h0, _ = predict_sigma(dict(flat, canopy_gradient=np.array([0.0])), m)
    h2, _ = predict_sigma(rough, m)
    assert np.sqrt(h2[0] ** 2 - h0[0] ** 2) == pytest.approx(0.5 * 4.4 * 2.0, rel=1e-9)


def test_the_file_s_geolocation_uncertainty_is_read(tmp_path: Path) -> None:
    """ATL03's geolocation/sigma_along and sigma_across (per segment) reach each photon
    as sqrt(along^2 + across^2); fill values are not stated values; a file without them
    gets none (the model then uses the published figure)."""
    import h5py

    from canopyblocks.blocks.atl08_classify import classify_photons
    from canopyblocks.blocks.uncertainty import block_features
    from canopyblocks.readers.atl03_geolocation import GEOLOCATION_SIGMA_COLUMN

    pts = read_las([str(TILE)])
    sim = simulate_photons(pts, line_through(pts.bounds, 30.0, inset=9.5), SimParams(), seed=3)
    path = write_simulation_atl03(sim, tmp_path / "t.h5")
    assert GEOLOCATION_SIGMA_COLUMN not in read_atl03(path, "gt1r", crs=pts.crs).extra
    with h5py.File(path, "r+") as f:
        g = f["gt1r/geolocation"]
        n = g["segment_id"].shape[0]
        along = np.full(n, 3.0, np.float32)
        along[:2] = np.float32(3.4028235e38)  # the product's fill value
        g["sigma_along"], g["sigma_across"] = along, np.full(n, 4.0, np.float32)
        first = int(g["ph_index_beg"][2]) - 1  # photons of segments 0-1 come before
    t = read_atl03(path, "gt1r", crs=pts.crs)
    geo = t.extra[GEOLOCATION_SIGMA_COLUMN]
    fin = np.isfinite(geo)
    assert np.allclose(geo[fin], 5.0) and (~fin).sum() == first
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        classes = classify_photons(t)
    s = np.array([t.s.min() + 100.0]), np.array([t.s.min() + 125.0])
    f = block_features(t, classes, *s, np.array([10.0]))
    assert f["geo_sigma"][0] == pytest.approx(5.0)
    # negative or absurd values are not stated values; a damaged shape states nothing
    with h5py.File(path, "r+") as f:
        g = f["gt1r/geolocation"]
        g["sigma_along"][:] = np.where(np.arange(n) % 2, -1.0, 500.0)
    assert not np.isfinite(read_atl03(path, "gt1r", crs=pts.crs)
                           .extra.get(GEOLOCATION_SIGMA_COLUMN, [np.nan])).any()
    with h5py.File(path, "r+") as f:
        del f["gt1r/geolocation/sigma_along"]
        f["gt1r/geolocation/sigma_along"] = np.full(n + 3, 3.0, np.float32)
    assert GEOLOCATION_SIGMA_COLUMN not in read_atl03(path, "gt1r", crs=pts.crs).extra
    # and the real clip states 5 m along and across
    real = read_atl03(str(A03), "gt1r").extra[GEOLOCATION_SIGMA_COLUMN]
    assert np.allclose(real, np.hypot(5.0, 5.0))
