"""Footprint-matched reference (DESIGN 2.7): brute force on a real tile, synthetic truths."""

from __future__ import annotations

import math

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest

from canopyblocks.errors import InputError
from canopyblocks.readers.las import LasPoints, read_las
from canopyblocks.reference.footprint import (
    FootprintCloud,
    block_footprint_reference,
    footprint_reference,
)
from canopyblocks.reference.footprint_params import FootprintReferenceParams
from canopyblocks.reference.terrain import horn_slope_aspect

LEVELS = (50, 75, 90, 95, 98, 100)


@pytest.fixture(scope="module")
def tile(sample) -> LasPoints:  # noqa: ANN001
    return read_las(sample("als/lasR_bcts_1.laz"))


def brute_force(pts: LasPoints, cx: float, cy: float, diameter: float, cut: float,
                density: bool) -> dict[str, float]:
    """One footprint, written plainly: distances to every point, weights, plane, stats."""
    R = diameter / 2.0
    x, y, z = pts.x, pts.y, pts.z
    w_all = np.ones(x.size)
    if density:
        cells = {}
        cx_i = np.floor(x / 1.5).astype(int)
        cy_i = np.floor(y / 1.5).astype(int)
        for key in zip(cx_i.tolist(), cy_i.tolist()):
            cells[key] = cells.get(key, 0) + 1
        w_all = np.array([1.0 / cells[k] for k in zip(cx_i.tolist(), cy_i.tolist())])
    r = np.sqrt((x - cx) ** 2 + (y - cy) ** 2)
    sel = r <= cut * R
    w = np.exp(-2 * r[sel] ** 2 / R**2) * w_all[sel]
    xs, ys, zs = x[sel] - cx, y[sel] - cy, z[sel]
    ground = pts.classification[sel] == 2
    # weighted least squares plane z = a + b x + c y through the ground points
    sw = np.sqrt(w[ground])
    A = np.column_stack([np.ones(ground.sum()), xs[ground], ys[ground]]) * sw[:, None]
    coef, *_ = np.linalg.lstsq(A, zs[ground] * sw, rcond=None)
    a, b, c = coef
    hag = zs - (a + b * xs + c * ys)
    order = np.argsort(hag, kind="stable")
    h_sorted, w_sorted = hag[order], w[order]
    cum = np.cumsum(w_sorted) / w_sorted.sum()
    out = {"ref_ground": float(np.sum(w[ground] * zs[ground]) / np.sum(w[ground])),
           "ref_top": float(zs.max()), "ref_n_points": int(sel.sum()),
           "ref_n_ground": int(ground.sum()),
           "ref_cover": float(np.sum(w[hag > 2.0]) / np.sum(w)),
           "ref_slope": math.degrees(math.atan(math.hypot(b, c))),
           "ref_aspect": math.degrees(math.atan2(-b, -c)) % 360.0}
    for q in LEVELS:
        i = int(np.argmax(cum >= q / 100.0 - 1e-12))
        out[f"ref_rh{q}"] = float(h_sorted[i])
    can = hag > 0.5
    hc, wc = hag[can], w[can]
    oc = np.argsort(hc, kind="stable")
    cumc = np.cumsum(wc[oc]) / wc.sum()
    for q in LEVELS:  # 0 without canopy points
        out[f"ref_canopy_rh{q}"] = (float(hc[oc][int(np.argmax(cumc >= q / 100.0 - 1e-12))])
                                    if hc.size else 0.0)
    first = pts.return_number[sel] <= 1
    out["ref_cover_first"] = float(np.sum(w[first & (hag > 2.0)]) / np.sum(w[first]))
    return out


@pytest.mark.parametrize("diameter,cut,density", [(13.0, 1.0, False), (22.0, 1.5, True),
                                                  (17.0, 1.0, True)])
def test_matches_brute_force_on_real_tile(tile: LasPoints, diameter: float, cut: float,
                                          density: bool) -> None:
    x0, y0, x1, y1 = tile.bounds
    rng = np.random.default_rng(7)
    m = cut * diameter / 2 + 2
    cx = rng.uniform(x0 + m, x1 - m, 6)
    cy = rng.uniform(y0 + m, y1 - m, 6)
    params = FootprintReferenceParams(diameter=diameter, cut=cut,
                                      weighting="gaussian_density" if density else "gaussian")
    got = footprint_reference(tile, cx, cy, params)
    assert (got["ref_flag"] == "ok").all()
    for i in range(cx.size):
        want = brute_force(tile, cx[i], cy[i], diameter, cut, density)
        for key, value in want.items():
            g = got[key].iloc[i]
            if key == "ref_aspect":
                d = (g - value + 180.0) % 360.0 - 180.0
                assert abs(d) < 1e-6, (i, key, g, value)
            else:
                assert g == pytest.approx(value, abs=1e-7), (i, key, g, value)


def test_order_and_chunking_do_not_change_values(tile: LasPoints) -> None:
    x0, y0, x1, y1 = tile.bounds
    rng = np.random.default_rng(3)
    cx = rng.uniform(x0 + 10, x1 - 10, 300)
    cy = rng.uniform(y0 + 10, y1 - 10, 300)
    cloud = FootprintCloud(tile, FootprintReferenceParams())
    a = footprint_reference(cloud, cx, cy)
    perm = rng.permutation(cx.size)
    b = footprint_reference(cloud, cx[perm], cy[perm])
    pd.testing.assert_frame_equal(a.iloc[perm].reset_index(drop=True), b)


def _scene(slope_deg: float = 0.0, cover_half: bool = True, canopy: float = 20.0,
           spacing: float = 0.2, half: float = 40.0) -> LasPoints:
    """Ground lattice on a plane rising to the north-east; canopy on a checkerboard."""
    g = np.arange(-half, half + 1e-9, spacing)
    xx, yy = np.meshgrid(g, g)
    i, j = np.meshgrid(np.arange(g.size), np.arange(g.size))
    t = math.tan(math.radians(slope_deg))
    zg = 100.0 + t * (xx + yy) / math.sqrt(2.0)
    tree = ((i + j) % 2 == 1) if cover_half else np.zeros(xx.shape, bool)
    z = np.where(tree, zg + canopy, zg)
    cls = np.where(tree, 1, 2)
    return LasPoints.from_arrays(xx.ravel() + 500_000.0, yy.ravel() + 5_000_000.0, z.ravel(),
                                 crs="EPSG:32610", classification=cls.ravel())


def test_flat_ground_with_half_cover() -> None:
    pts = _scene()
    cx = 500_000.0 + np.array([0.0, 3.1, -7.3])
    cy = 5_000_000.0 + np.array([0.0, -2.2, 5.9])
    for weighting in ("gaussian", "gaussian_density"):
        got = footprint_reference(pts, cx, cy,
                                  FootprintReferenceParams(diameter=13.0, weighting=weighting))
        assert (got["ref_flag"] == "ok").all()
        np.testing.assert_allclose(got["ref_ground"], 100.0, atol=1e-9)
        np.testing.assert_allclose(got["ref_rh100"], 20.0, atol=1e-9)
        np.testing.assert_allclose(got["ref_rh98"], 20.0, atol=1e-9)
        np.testing.assert_allclose(got["ref_canopy_rh50"], 20.0, atol=1e-9)
        np.testing.assert_allclose(got["ref_top"], 120.0, atol=1e-9)
        np.testing.assert_allclose(got["ref_cover"], 0.5, atol=0.01)
        np.testing.assert_allclose(got["ref_slope"], 0.0, atol=1e-6)


@pytest.mark.parametrize("slope", [10.0, 25.0])
def test_sloped_plane_slope_aspect_and_heights(slope: float) -> None:
    pts = _scene(slope_deg=slope)
    cx = 500_000.0 + np.array([0.0, 4.0])
    cy = 5_000_000.0 + np.array([0.0, -6.0])
    got = footprint_reference(pts, cx, cy, FootprintReferenceParams(diameter=22.0, cut=1.5))
    np.testing.assert_allclose(got["ref_slope"], slope, atol=1e-6)
    # rising to the north-east: the slope faces (drops towards) the south-west
    np.testing.assert_allclose(got["ref_aspect"], 225.0, atol=1e-6)
    # heights above the plane, not above one mean ground: the canopy is 20 m everywhere
    np.testing.assert_allclose(got["ref_rh100"], 20.0, atol=1e-6)
    np.testing.assert_allclose(got["ref_canopy_rh50"], 20.0, atol=1e-6)
    np.testing.assert_allclose(got["ref_cover"], 0.5, atol=0.01)
    # the Horn (GDAL) convention of reference.terrain gives the same aspect on a grid
    g = np.arange(0, 10) * 2.0
    xx, yy = np.meshgrid(g, g[::-1])  # row 0 = north
    t = math.tan(math.radians(slope))
    s, a = horn_slope_aspect(100 + t * (xx + yy) / math.sqrt(2), 2.0, 2.0)
    assert s[5, 5] == pytest.approx(slope, abs=1e-9)
    assert a[5, 5] == pytest.approx(got["ref_aspect"].iloc[0], abs=1e-6)


def test_outside_and_no_ground_flags() -> None:
    pts = _scene()
    cx = 500_000.0 + np.array([0.0, 38.0, 200.0, np.nan])
    cy = 5_000_000.0 + np.array([0.0, 0.0, 0.0, 0.0])
    got = footprint_reference(pts, cx, cy, FootprintReferenceParams(diameter=13.0))
    assert got["ref_flag"].tolist() == ["ok", "outside", "outside", "outside"]
    assert got["ref_n_points"].iloc[2] == 0
    assert 0.3 < got["ref_coverage"].iloc[1] < 0.9
    no_ground = _scene(cover_half=False)
    no_ground.classification[:] = 1
    res = footprint_reference(no_ground, cx[:1], cy[:1], FootprintReferenceParams())
    assert res["ref_flag"].iloc[0] == "no_ground"
    assert np.isnan(res["ref_ground"].iloc[0]) and np.isnan(res["ref_rh98"].iloc[0])


def test_params_are_validated() -> None:
    with pytest.raises(InputError, match="diameter"):
        FootprintReferenceParams(diameter=0)
    with pytest.raises(InputError, match="weighting"):
        FootprintReferenceParams(weighting="box")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="min_ground_points"):
        FootprintReferenceParams(min_ground_points=2)
    p = FootprintReferenceParams.gedi()
    assert (p.radius, p.cut_radius, p.weighting) == (11.0, 16.5, "gaussian_density")


def _blocks_along(x0: float, y0: float, angle: float, length: float, n: int,
                  crs: object) -> gpd.GeoDataFrame:
    ux, uy = math.cos(angle), math.sin(angle)
    s_start = np.arange(n) * length
    mid = s_start + length / 2
    df = pd.DataFrame({"track": "gt1r", "length": length, "block": np.arange(n),
                       "s_start": s_start, "s_end": s_start + length,
                       "x": x0 + mid * ux, "y": y0 + mid * uy})
    return gpd.GeoDataFrame(df, geometry=gpd.points_from_xy(df.x, df.y), crs=crs)


def test_block_reference_is_the_mean_of_its_footprints(tile: LasPoints) -> None:
    x0, y0, x1, y1 = tile.bounds
    angle = math.atan2(y1 - y0 - 40, x1 - x0 - 40)
    blocks = _blocks_along(x0 + 20, y0 + 20, angle, 25.0, 8, tile.crs)
    params = FootprintReferenceParams(diameter=13.0)
    got = block_footprint_reference(blocks, tile, params, spacing=0.7,
                                    statistic="footprint-mean")
    # independent: footprints at s = (k + 0.5) * 0.7 on the straight line, block by s
    s = (np.arange(400) + 0.5) * 0.7
    s = s[s < 8 * 25.0]
    fx = x0 + 20 + s * math.cos(angle)
    fy = y0 + 20 + s * math.sin(angle)
    fp = footprint_reference(tile, fx, fy, params)
    owner = (s // 25.0).astype(int)
    assert (got["ref_flag"] == "ok").all()
    for b in range(8):
        sub = fp[(owner == b) & (fp["ref_flag"] == "ok").to_numpy()]
        assert got["n_footprints"].iloc[b] == int((owner == b).sum())
        assert got["ref_ground"].iloc[b] == pytest.approx(sub["ref_ground"].mean(), abs=1e-9)
        assert got["ref_top"].iloc[b] == pytest.approx(
            (sub["ref_ground"] + sub["ref_rh98"]).mean(), abs=1e-9)
        assert got["ref_hmax"].iloc[b] == pytest.approx(sub["ref_rh98"].mean(), abs=1e-9)
        assert got["ref_h90"].iloc[b] == pytest.approx(sub["ref_rh90"].mean(), abs=1e-9)
        assert got["ref_cover"].iloc[b] == pytest.approx(sub["ref_cover"].mean(), abs=1e-9)
    mx = block_footprint_reference(blocks, tile, params, spacing=0.7, statistic="footprint-max")
    sub = fp[owner == 3]
    assert mx["ref_top"].iloc[3] == pytest.approx(
        (sub["ref_ground"] + sub["ref_rh98"]).max(), abs=1e-9)
    assert mx["ref_ground"].iloc[3] == pytest.approx(sub["ref_ground"].mean(), abs=1e-9)


def test_block_reference_synthetic_and_outside() -> None:
    pts = _scene(slope_deg=10.0)
    blocks = _blocks_along(500_000.0 - 30.0, 5_000_000.0 - 10.0, 0.3, 10.0, 9,
                           "EPSG:32610")
    got = block_footprint_reference(blocks, pts, FootprintReferenceParams(diameter=13.0))
    inside = got["ref_flag"] == "ok"
    assert inside.iloc[:4].all() and got["ref_flag"].iloc[-1] == "outside"
    np.testing.assert_allclose(got.loc[inside, "ref_hmax"], 20.0, atol=1e-6)
    np.testing.assert_allclose(got.loc[inside, "slope"], 10.0, atol=1e-6)
    assert set(got.loc[inside, "aspect_class"]) == {"SW"}
    with pytest.raises(InputError, match="statistic"):
        block_footprint_reference(blocks, pts, statistic="median")  # type: ignore[arg-type]


def test_density_weights_remove_survey_density() -> None:
    """Ground-only west half, canopy-only east half sampled 4x as densely: the Gaussian
    cover counts the extra points (~0.8), the density-weighted cover does not (0.5)."""
    gw = np.arange(-30.0, 0.0, 0.2)
    ge = np.arange(0.05, 30.0, 0.1)
    yy = np.arange(-30.0, 30.0, 0.2)
    xw, yw = np.meshgrid(gw, yy)
    xe, ye = np.meshgrid(ge, np.arange(-30.0, 30.0, 0.1))
    x = np.concatenate([xw.ravel(), xe.ravel()]) + 600_000.0
    y = np.concatenate([yw.ravel(), ye.ravel()]) + 5_000_000.0
    z = np.concatenate([np.full(xw.size, 50.0), np.full(xe.size, 65.0)])
    cls = np.concatenate([np.full(xw.size, 2), np.full(xe.size, 5)])
    pts = LasPoints.from_arrays(x, y, z, crs="EPSG:32610", classification=cls)
    cx, cy = np.array([600_000.0]), np.array([5_000_000.0])
    plain = footprint_reference(pts, cx, cy, FootprintReferenceParams(diameter=13.0))
    dens = footprint_reference(pts, cx, cy, FootprintReferenceParams(
        diameter=13.0, weighting="gaussian_density"))
    assert plain["ref_cover"].iloc[0] == pytest.approx(0.8, abs=0.01)
    assert dens["ref_cover"].iloc[0] == pytest.approx(0.5, abs=0.01)
    assert dens["ref_ground"].iloc[0] == pytest.approx(50.0, abs=1e-9)


def test_same_points_as_the_photon_simulator(tile: LasPoints) -> None:
    """ICESat-2 defaults weigh exactly the simulator's point set (DESIGN 3.1): per shot
    the same number of points and the same highest point as its truth."""
    from canopyblocks.simulate.engine import simulate_photons
    from canopyblocks.simulate.params import SimParams
    from canopyblocks.simulate.tracks import SimTrack

    x0, y0, x1, y1 = tile.bounds
    sp = SimParams()
    sim = simulate_photons(tile, SimTrack(vertices=((x0 + 20, y0 + 20), (x1 - 20, y0 + 90))),
                           sp)
    ref = footprint_reference(tile, sim.shot_x, sim.shot_y,
                              FootprintReferenceParams(diameter=2 * sp.radius))
    np.testing.assert_array_equal(ref["ref_n_points"].to_numpy(), sim.truth["n_points"])
    np.testing.assert_array_equal(ref["ref_top"].to_numpy(), sim.truth["top"])


def test_a_footprint_does_not_depend_on_what_else_was_read(sample) -> None:  # noqa: ANN001
    """Blocks along the west edge of one tile (some footprints over the edge, so their
    coverage is < 1): their reference and their footprints' coverage are the same whether
    the neighbouring tile, 53-60 m from the track, is read or not, and whether the points
    farther than 30 m from the track are read or not (another block length reads another
    buffer)."""
    one = read_las(sample("als/lasR_bcts_1.laz"))
    both = read_las([sample("als/lasR_bcts_1.laz"), sample("als/lasR_bcts_2.laz")])
    x0 = 885029.0
    blocks = _blocks_along(x0, 629160.0, math.pi / 2, 25.0, 7, one.crs)
    assert blocks["y"].max() + 12.5 + 6.5 <= 629400.0 - 53.0  # the tile 2 edge
    near = one.subset(np.abs(one.x - x0) <= 30.0)
    params = FootprintReferenceParams(diameter=13.0)
    refs = [block_footprint_reference(blocks, pts, params) for pts in (one, both, near)]
    fy = 629160.0 + (np.arange(250) + 0.5) * 0.7
    fps = [footprint_reference(pts, np.full(fy.size, x0), fy, params)
           for pts in (one, both, near)]
    cov = fps[0]["ref_coverage"].to_numpy()
    assert cov.min() < 0.9 <= cov.max()  # some footprints flagged over the edge, some not
    assert (refs[0]["ref_flag"] == "ok").sum() >= 3
    for ref, fp in zip(refs[1:], fps[1:]):
        for col in ("ref_ground", "ref_top", "ref_cover", "n_footprints"):
            np.testing.assert_array_equal(ref[col].to_numpy(), refs[0][col].to_numpy(),
                                          err_msg=col)
        assert (ref["ref_flag"] == refs[0]["ref_flag"]).all()
        for col in ("ref_coverage", "ref_ground"):
            np.testing.assert_array_equal(fp[col].to_numpy(), fps[0][col].to_numpy(),
                                          err_msg=col)
