"""Block metrics worked out on paper for a dozen photons, and parameter validation.

Every expected number below is computed by hand in the comments (DESIGN.md 1.3-1.8):
bins are 0.5 m from the lowest kept photon, the first window is 4 bins (2 m).
"""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest

from canopyblocks import PhotonTrack
from canopyblocks.blocks import LABEL_OUTSIDE, BlockParams, compute_blocks, default_cutoffs
from canopyblocks.errors import InputError, NoUsableDataError, SparseBlockWarning
from canopyblocks.schema import (
    BLOCK_COLUMNS,
    LABEL_BETWEEN,
    LABEL_CANOPY,
    LABEL_GROUND,
    LABEL_NOISE,
)

CRS = pyproj.CRS.from_epsg(32612)

# Block 0 (s in [0, 25)): 12 photons, no noise among them.
#   zmin = 100.0, zmax = 106.9, (106.9 - 100)/0.5 = 13.8 -> nb = 14 bins
#   bins floor((z-100)/0.5): 100.0,100.1,100.2,100.4 -> 0; 101.3 -> 2; 102.7 -> 5;
#   104.0 -> 8; 105.2 -> 10; 105.6 -> 11; 106.1, 106.3 -> 12; 106.9 -> 13
#   (sigma filter: mean 103.233, std 2.64, 2.5 std = 6.6 > the largest |z - mean| 3.67: all kept)
Z_A = [100.0, 100.1, 100.2, 100.4, 101.3, 102.7, 104.0, 105.2, 105.6, 106.1, 106.3, 106.9]
# Block 1 (s in [25, 50)): 11 photons and one outlier at 260.
#   sum = 4*200 + 201 + 202 + 203 + 4*204 + 260 = 2482, mean = 206.8333
#   squared deviations: 4*6.8333^2 = 186.778, 5.8333^2 = 34.028, 4.8333^2 = 23.361,
#   3.8333^2 = 14.694, 4*2.8333^2 = 32.111, 53.1667^2 = 2826.694; sum 3117.667
#   std = sqrt(3117.667/11) = 16.835, 2.5*std = 42.09 < 53.17: 260 removed, 11 kept
#   kept: zmin 200, zmax 204, 4/0.5 = 8 bins; 200 -> 0 (x4), 201 -> 2, 202 -> 4, 203 -> 6,
#   204 -> floor(8) = 8 clipped to nb - 1 = 7 (x4)
Z_B = [200.0, 200.0, 200.0, 200.0, 201.0, 202.0, 203.0, 204.0, 204.0, 204.0, 204.0, 260.0]
# Block 2: empty (no row).  Block 3 (s in [75, 100)): 3 photons -> sparse.
Z_C = [300.0, 301.0, 302.0]


def _track(z_blocks: dict[int, list[float]], spacing: float = 2.0) -> PhotonTrack:
    s, z = [], []
    for blk, zs in z_blocks.items():
        # spread the photons over the block, staying inside it
        s += [blk * 25.0 + 0.5 + spacing * i for i in range(len(zs))]
        z += zs
    s_a = np.array(s)
    return PhotonTrack(time=s_a.copy(), lat=np.zeros_like(s_a), lon=np.zeros_like(s_a),
                       h=np.array(z), x=500000.0 + s_a, y=np.full_like(s_a, 4_000_000.0),
                       s=s_a, track="gt2l", crs=CRS)


@pytest.fixture()
def three_blocks():
    tr = _track({0: Z_A, 1: Z_B, 3: Z_C})
    with pytest.warns(SparseBlockWarning, match="1 of 3 25 m blocks"):
        out, labels = compute_blocks(tr, BlockParams(lengths=(25.0,), s0=0.0), labels=True)
    return tr, out, labels


def test_columns_geometry_and_crs(three_blocks):
    tr, out, _ = three_blocks
    assert list(out.columns) == [*BLOCK_COLUMNS, "geometry"]
    assert out.crs == CRS
    assert list(out["block"]) == [0, 1, 3]                       # empty block 2 has no row
    assert list(out["s_start"]) == [0.0, 25.0, 75.0]
    assert list(out["s_end"]) == [25.0, 50.0, 100.0]
    # centre = mean x of the block's photons: s = 0.5 + 2i, i = 0..11 -> mean 11.5
    assert out["x"].iloc[0] == pytest.approx(500011.5)
    assert out["x"].iloc[2] == pytest.approx(500000 + 75 + 0.5 + 2.0)
    assert out.geometry.x.iloc[1] == pytest.approx(out["x"].iloc[1])
    # lon/lat of the centre: UTM 12N at x ~ 500 km is the central meridian, -111 deg
    assert out["lon"].iloc[0] == pytest.approx(-111.0, abs=0.01)
    assert list(out["n_photons"]) == [12, 12, 3]


def test_block_a_default_cutoffs(three_blocks):
    # 25 m defaults: top 10 %, ground 20 %.
    # top: first window bins 10..13 holds 1+1+2+1 = 5 photons, 5/12 = 0.417 >= 0.10: stops at
    #      once; top = lower edge of bin 10 = 100 + 10*0.5 = 105.0
    # ground: first window bins 0..3 holds 4+1 = 5, 5/12 >= 0.20: stops; ground = upper edge
    #      of bin 3 = 100 + 4*0.5 = 102.0
    # between [102.0, 105.0]: 102.7, 104.0 -> n = 2, index floor(0.9*1) = 0 -> z90 = 102.7
    _, out, labels = three_blocks
    r = out.iloc[0]
    assert (r["n_kept"], r["n_between"]) == (12, 2)
    assert r["top"] == pytest.approx(105.0)
    assert r["ground"] == pytest.approx(102.0)
    assert r["hmax"] == pytest.approx(3.0)
    assert r["z90"] == pytest.approx(102.7)
    assert r["h90"] == pytest.approx(0.7)
    assert r["flag"] == "ok"
    # labels: ground window bins 0..3, canopy window bins 10..13
    g, c, b = LABEL_GROUND, LABEL_CANOPY, LABEL_BETWEEN
    assert labels[25.0][:12].tolist() == [g, g, g, g, g, b, b, c, c, c, c, c]


def test_block_a_windows_expand():
    # top_cutoff 0.5: bins 10..13 = 5/12 < 0.5; add bin 9 (empty) 5/12 < 0.5; add bin 8:
    #     6/12 = 0.5 >= 0.5 -> stop; top = 100 + 8*0.5 = 104.0
    # ground_cutoff 0.5: bins 0..3 = 5/12; add bin 4 (empty) 5/12; add bin 5: 6/12 -> stop;
    #     ground = 100 + 6*0.5 = 103.0
    # between [103.0, 104.0]: only 104.0 (on the top edge, included) -> z90 = 104.0, h90 = 1.0
    tr = _track({0: Z_A})
    out = compute_blocks(tr, BlockParams(lengths=25.0, top_cutoff=0.5, ground_cutoff=0.5))
    r = out.iloc[0]
    assert r["top"] == pytest.approx(104.0)
    assert r["ground"] == pytest.approx(103.0)
    assert r["n_between"] == 1
    assert r["z90"] == pytest.approx(104.0)
    assert r["h90"] == pytest.approx(1.0)
    assert r["flag"] == "ok"


def test_block_b_outlier_removed_and_inverted(three_blocks):
    # kept 11 (260 removed).  Histogram b0:4, b2:1, b4:1, b6:1, b7:4.
    # top: bins 4..7 = 1+1+4 = 6/11 >= 0.10 -> top = 200 + 4*0.5 = 202.0
    # ground: bins 0..3 = 4+1 = 5/11 >= 0.20 -> ground = 200 + 4*0.5 = 202.0
    # top <= ground -> inverted; between [202, 202] = {202.0}: z90 = 202.0, h90 = 0, hmax = 0
    _, out, labels = three_blocks
    r = out.iloc[1]
    assert (r["n_photons"], r["n_kept"], r["n_between"]) == (12, 11, 1)
    assert r["top"] == pytest.approx(202.0)
    assert r["ground"] == pytest.approx(202.0)
    assert r["hmax"] == pytest.approx(0.0)
    assert r["z90"] == pytest.approx(202.0)
    assert r["flag"] == "inverted"
    lab = labels[25.0][12:24]
    assert lab[-1] == LABEL_NOISE                       # the outlier
    assert lab[:4].tolist() == [LABEL_GROUND] * 4
    assert lab[7:11].tolist() == [LABEL_CANOPY] * 4     # bin 7, only in the top window


def test_block_c_sparse(three_blocks):
    # 3 photons < min_photons 10: metrics NaN, counts still reported
    _, out, labels = three_blocks
    r = out.iloc[2]
    assert (r["n_photons"], r["n_kept"], r["n_between"]) == (3, 3, 0)
    for col in ("top", "ground", "hmax", "z90", "h90"):
        assert math.isnan(r[col]), col
    assert r["flag"] == "sparse"
    assert labels[25.0][24:].tolist() == [LABEL_BETWEEN] * 3


def test_fewer_than_four_bins_uses_whole_histogram():
    # z: 300.0 x3, 300.3, 300.6, 300.7, 301.0, 301.1, 301.2 x2 (10 photons, noise off)
    # zmax - zmin = 1.2, 1.2/0.5 = 2.4 -> nb = 3 < 4: both first windows = all 3 bins
    # top = lower edge of bin 0 = 300.0; ground = upper edge of bin 2 = 301.5 -> inverted
    # between [301.5, 300.0] is empty -> z90 NaN
    z = [300.0] * 3 + [300.3, 300.6, 300.7, 301.0, 301.1, 301.2, 301.2]
    out = compute_blocks(_track({0: z}), BlockParams(noise="none"))
    r = out.iloc[0]
    assert r["top"] == pytest.approx(300.0)
    assert r["ground"] == pytest.approx(301.5)
    assert r["hmax"] == pytest.approx(-1.5)
    assert r["n_between"] == 0 and math.isnan(r["z90"])
    assert r["flag"] == "inverted"


def test_flat_block_keeps_everything():
    # std == 0: all 10 kept; nb = max(1, ceil(0)) = 1; top 150.0, ground 150.5
    out = compute_blocks(_track({0: [150.0] * 10}), BlockParams())
    r = out.iloc[0]
    assert r["n_kept"] == 10
    assert (r["top"], r["ground"]) == (150.0, 150.5)
    assert r["flag"] == "inverted"


def test_s0_blocks_and_outside_photons():
    # s0 = 10: photons at s 0.5..8.5 (block 0 of _track, 5 of them) lie in no block;
    # s = 10.5..22.5 -> block 0 of [10, 35)
    tr = _track({0: Z_A})
    out, labels = compute_blocks(tr, BlockParams(lengths=25.0, s0=10.0, min_photons=1),
                                 labels=True)
    assert list(out["block"]) == [0]
    assert out["n_photons"].iloc[0] == 7
    assert out["s_start"].iloc[0] == 10.0
    assert (labels[25.0][:5] == LABEL_OUTSIDE).all()
    assert (labels[25.0][5:] != LABEL_OUTSIDE).all()


def test_signal_conf_filter_before_sigma():
    tr = _track({0: Z_A})
    with pytest.raises(InputError, match="signal_conf"):
        compute_blocks(tr, BlockParams(min_signal_conf=2))
    # confidence 4 except the three lowest photons (0): those are removed first
    tr.signal_conf = np.array([0, 0, 0] + [4] * 9, np.int8)
    out, lab = compute_blocks(tr, BlockParams(min_signal_conf=3, min_photons=1), labels=True)
    r = out.iloc[0]
    assert (r["n_photons"], r["n_kept"]) == (12, 9)
    # kept from 100.4: zmin 100.4; ground window bins 0..3 = [100.4, 102.4): 100.4, 101.3 = 2/9
    # >= 0.2 -> ground = 100.4 + 4*0.5 = 102.4
    assert r["ground"] == pytest.approx(102.4)
    assert lab[25.0][:3].tolist() == [LABEL_NOISE] * 3


def test_empty_or_all_before_s0_is_no_usable_data():
    tr = _track({0: Z_A})
    with pytest.raises(NoUsableDataError, match="s0=1000"):
        compute_blocks(tr, BlockParams(s0=1000.0))


# ----------------------------------------------------------------------------- params
def test_default_cutoffs_by_length():
    assert default_cutoffs(50) == (0.10, 0.25)
    assert default_cutoffs(25) == (0.10, 0.20)
    assert default_cutoffs(10) == (0.05, 0.075)
    # linear in L: 37.5 m -> ground 0.20 + 0.5*(0.25 - 0.20) = 0.225, top 0.10
    assert default_cutoffs(37.5) == pytest.approx((0.10, 0.225))
    # 17.5 m -> top 0.05 + 0.5*0.05 = 0.075, ground 0.075 + 0.5*0.125 = 0.1375
    assert default_cutoffs(17.5) == pytest.approx((0.075, 0.1375))
    assert default_cutoffs(5) == (0.05, 0.075)        # clamped
    assert default_cutoffs(100) == (0.10, 0.25)


def test_user_cutoffs():
    p = BlockParams(lengths=(10, 25), top_cutoff=0.3, ground_cutoff={10: 0.1, 25.0: 0.4})
    assert p.lengths == (10.0, 25.0)
    assert p.cutoffs_for(10) == (0.3, 0.1)
    assert p.cutoffs_for(25) == (0.3, 0.4)
    hash(p)  # frozen and hashable even with a mapping


@pytest.mark.parametrize("kw, match", [
    ({"lengths": ()}, "lengths is empty"),
    ({"lengths": (25, -1)}, r"positive finite .* got -1"),
    ({"lengths": (25, 25.0)}, "twice"),
    ({"lengths": "abc"}, "positive"),
    ({"s0": float("nan")}, "s0"),
    ({"k_sigma": 0}, "k_sigma"),
    ({"bin_size": -0.5}, "bin_size"),
    ({"window": 1.2}, "whole number"),
    ({"top_cutoff": 1.5}, r"\(0, 1\).*1.5"),
    ({"ground_cutoff": 0}, "ground_cutoff"),
    ({"ground_cutoff": {10: 0.1}}, "no value for block length 25"),
    ({"top_cutoff": "x"}, "top_cutoff"),
    ({"min_photons": 0}, "min_photons"),
    ({"min_photons": 2.5}, "min_photons"),
    ({"noise": "dragann"}, "noise"),
    ({"min_signal_conf": 5}, r"-2 to 4.*5"),
    ({"min_signal_conf": True}, "min_signal_conf"),
])
def test_bad_params(kw, match):
    with pytest.raises(InputError, match=match):
        BlockParams(**kw)


def test_fraction_exactly_at_cutoff_stops():
    # 100 photons: 93 evenly in [10, 15] and 7 at 20.0, 20.1, ..., 20.6; noise off; top 0.07
    # zmin 10, (20.6 - 10)/0.5 = 21.2 -> 22 bins; first top window = bins 18..21 = [19, 21)
    # holds the 7 top photons: 7/100 = 0.07 >= 0.07 -> stops at once: top = 10 + 18*0.5 = 19.0
    # (0.07*100 is 7.000000000000001 in float64, so a count test "count >= ceil(0.07*100) = 8"
    # would go on down to the 8th highest photon, 15.0, and give top = 15.0)
    z = list(np.linspace(10.0, 15.0, 93)) + [20.0 + 0.1 * i for i in range(7)]
    out = compute_blocks(_track({0: z}, spacing=0.2),
                         BlockParams(noise="none", top_cutoff=0.07))
    assert out["n_photons"].iloc[0] == 100
    assert out["top"].iloc[0] == pytest.approx(19.0)


def test_empty_track_and_all_nan():
    e = np.empty(0)
    empty = PhotonTrack(time=e, lat=e, lon=e, h=e, x=e, y=e, s=e, track="gt1r", crs=CRS)
    with pytest.raises(NoUsableDataError, match="no photons"):
        compute_blocks(empty)
    tr = _track({0: Z_A})
    tr.h = np.full(tr.h.size, np.nan)
    with pytest.raises(NoUsableDataError, match="finite"):
        compute_blocks(tr)


def test_progress_and_cancel():
    from canopyblocks import Progress
    from canopyblocks.errors import CancelledError

    tr = _track({0: Z_A, 1: Z_B})
    seen: list[float] = []
    compute_blocks(tr, BlockParams(lengths=(10, 25), min_photons=1),
                   progress=Progress(lambda f, m: seen.append(f)))
    assert seen[0] == 0.0 and seen[-1] == 1.0 and 0.5 in seen      # once per length
    with pytest.raises(CancelledError):
        compute_blocks(tr, progress=Progress(cancelled=lambda: True))


def test_geographic_crs_is_refused():
    tr = _track({0: Z_A})
    tr.crs = pyproj.CRS.from_epsg(4326)
    from canopyblocks.errors import CRSError

    with pytest.raises(CRSError, match="not projected"):
        compute_blocks(tr)
