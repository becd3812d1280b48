"""Corridor polygons: widths, areas, block edges, ids, curved tracks."""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely
from shapely.geometry import LineString

from canopyblocks.errors import CRSError, InputError
from canopyblocks.reference.corridor import block_corridors


def line_blocks(n: int, length: float, angle_deg: float, *, x0: float = 500_000.0,
                y0: float = 4_600_000.0, track: str = "gt1r", crs: object = 32612,
                first: int = 0) -> gpd.GeoDataFrame:
    """Blocks along a straight line at ``angle_deg`` (counter-clockwise from east)."""
    th = np.radians(angle_deg)
    s0 = (first + np.arange(n)) * length
    sm = s0 + length / 2
    d = pd.DataFrame({"track": track, "length": float(length), "block": first + np.arange(n),
                      "s_start": s0, "s_end": s0 + length,
                      "x": x0 + sm * np.cos(th), "y": y0 + sm * np.sin(th)})
    return gpd.GeoDataFrame(d, geometry=gpd.points_from_xy(d.x, d.y), crs=crs)


@pytest.mark.parametrize("angle", [0.0, 30.0, 90.0, 161.3])
@pytest.mark.parametrize("width", [2.0, 13.0])
def test_straight_track_rectangles(angle: float, width: float) -> None:
    L = 25.0
    blocks = line_blocks(8, L, angle)
    cor = block_corridors(blocks, width=width)
    assert cor.crs == blocks.crs
    np.testing.assert_allclose(cor.area.to_numpy(), width * L, rtol=1e-9)  # float round-off at UTM coords
    th = np.radians(angle)
    u = np.array([np.cos(th), np.sin(th)])  # along track
    v = np.array([-np.sin(th), np.cos(th)])  # left of track
    for i, poly in enumerate(cor.geometry):
        # hand-computed corners of the block's rectangle
        p0 = np.array([500_000.0, 4_600_000.0]) + u * i * L
        p1 = p0 + u * L
        h = v * width / 2
        corners = [p0 + h, p0 - h, p1 - h, p1 + h]
        expected = shapely.Polygon(corners)
        assert poly.symmetric_difference(expected).area < 1e-6
        # 4 corners: the vertices where the outline turns (the one at the block centre is
        # collinear; shapely 2.0.0's simplify keeps it, so it is not used here)
        ring = np.asarray(poly.exterior.coords)[:-1]
        d_in, d_out = ring - np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0) - ring
        turn = np.abs(d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0])
        assert int((turn > 1e-6).sum()) == 4


def test_ids_and_order_kept() -> None:
    blocks = line_blocks(5, 10.0, 45.0, first=7).iloc[::-1]  # reversed row order
    blocks.index = [10, 11, 12, 13, 14]
    cor = block_corridors(blocks)
    assert list(cor.index) == [10, 11, 12, 13, 14]
    for c in ("track", "length", "block", "s_start", "s_end"):
        assert list(cor[c]) == list(blocks[c])
    np.testing.assert_allclose(cor.geometry.centroid.x, blocks["x"], atol=1e-9)
    np.testing.assert_allclose(cor.geometry.centroid.y, blocks["y"], atol=1e-9)


def test_adjacent_blocks_share_edges_without_overlap() -> None:
    blocks = line_blocks(6, 25.0, 17.0)
    cor = block_corridors(blocks, width=2.0).geometry.to_numpy()
    for a, b in zip(cor[:-1], cor[1:]):
        assert a.intersection(b).area < 1e-9
        shared = a.buffer(1e-6).intersection(b.boundary)  # the common end edge
        assert shared.length == pytest.approx(2.0, abs=1e-5)
    assert shapely.union_all(cor).area == pytest.approx(6 * 25.0 * 2.0, rel=1e-9)


def test_curved_track() -> None:
    """Centres on a circle (R = 150 m, 10 m blocks): edges shared, no gaps or overlaps."""
    R, L, n, w = 150.0, 10.0, 30, 2.0
    sm = (np.arange(n) + 0.5) * L
    ang = sm / R
    d = pd.DataFrame({"track": "c", "length": L, "block": np.arange(n),
                      "s_start": sm - L / 2, "s_end": sm + L / 2,
                      "x": 1000 + R * np.sin(ang), "y": 2000 + R * (1 - np.cos(ang))})
    blocks = gpd.GeoDataFrame(d, geometry=gpd.points_from_xy(d.x, d.y), crs=32633)
    cor = block_corridors(blocks, width=w).geometry.to_numpy()
    # the polyline is parametrised by its own arc length (chords between centres), so the
    # blocks' pieces add up to n * L of it (the end halves extrapolate the end chords);
    # a mitred strip of constant width along a polyline has area width * length
    assert sum(p.area for p in cor) == pytest.approx(w * n * L, rel=1e-9)
    union = shapely.union_all(cor)
    assert union.area == pytest.approx(sum(p.area for p in cor), rel=1e-9)  # no overlaps
    assert isinstance(union, shapely.Polygon) and len(union.interiors) == 0  # no gaps
    for a, b in zip(cor[:-1], cor[1:]):
        assert a.buffer(1e-6).intersection(b.boundary).length == pytest.approx(w, abs=1e-5)
    # each block polygon stays within w/2 of the circle, up to the chords' sagitta
    # (L**2 / 8R = 0.08 m) and the straight extrapolation at the two ends (0.25 m)
    centre = shapely.Point(1000, 2000 + R)
    for p in cor:
        dists = [centre.distance(shapely.Point(c)) for c in p.exterior.coords]
        assert min(dists) > R - w / 2 - 0.1 and max(dists) < R + w / 2 + 0.3


def test_track_line_given() -> None:
    blocks = line_blocks(4, 25.0, 0.0)
    line = LineString([(499_990.0, 4_600_000.0), (500_200.0, 4_600_000.0)])
    cor = block_corridors(blocks, width=4.0, track_line=line, line_s0=-10.0)
    ref = block_corridors(blocks, width=4.0)
    for a, b in zip(cor.geometry, ref.geometry):
        assert a.symmetric_difference(b).area < 1e-6
    with pytest.raises(InputError, match="does not reach"):
        block_corridors(blocks, track_line=line, line_s0=500.0)


def test_groups_per_track_and_length() -> None:
    a = line_blocks(4, 25.0, 0.0, track="gt1r")
    b = line_blocks(10, 10.0, 90.0, track="gt1r", x0=600_000.0)
    blocks = pd.concat([a, b], ignore_index=True)
    cor = block_corridors(blocks, width=2.0)
    np.testing.assert_allclose(cor.area, 2.0 * blocks["length"], rtol=1e-9)
    # without a width: the footprint of the ICESat-2 beam gt1r, 13 m
    np.testing.assert_allclose(block_corridors(blocks).area, 13.0 * blocks["length"],
                               rtol=1e-9)
    # the 10 m blocks run north: their bounds are 2 m wide in x
    w = cor.bounds["maxx"] - cor.bounds["minx"]
    np.testing.assert_allclose(w[blocks["length"] == 10.0], 2.0, atol=1e-9)


def test_bad_input() -> None:
    blocks = line_blocks(3, 25.0, 0.0)
    with pytest.raises(InputError, match="width"):
        block_corridors(blocks, width=0)
    with pytest.raises(InputError, match="at least 2"):
        block_corridors(blocks.iloc[:1])
    with pytest.raises(InputError, match="s_end"):
        bad = blocks.copy()
        bad.loc[0, "s_end"] = bad.loc[0, "s_start"]
        block_corridors(bad)
    with pytest.raises(InputError, match="s_start"):
        block_corridors(blocks.drop(columns="s_start"))
    with pytest.raises(CRSError, match="not projected"):
        block_corridors(blocks.set_crs(4326, allow_override=True))


def test_bunched_photons_do_not_move_the_corridor() -> None:
    """A block whose photons bunch at its start has its centre 4 m back along the track:
    its corridor (and its neighbours') must still span its own s range, 10 m long."""
    n, L = 20, 10.0
    blocks = line_blocks(n, L, 30.0)
    th = np.radians(30.0)
    bunched = blocks.copy()
    bunched.loc[5, "x"] -= 4.0 * np.cos(th)
    bunched.loc[5, "y"] -= 4.0 * np.sin(th)
    cor = block_corridors(bunched, width=2.0)
    ref = block_corridors(blocks, width=2.0)
    u = np.array([np.cos(th), np.sin(th)])
    for k in range(n):
        a, b = cor.geometry.iloc[k], ref.geometry.iloc[k]
        # the whole track's parameter shifts by the mean of one 4 m displacement: 0.2 m
        assert a.area == pytest.approx(2.0 * L, rel=1e-9)
        ca = np.array(a.centroid.coords[0])
        cb = np.array(b.centroid.coords[0])
        assert abs(np.dot(ca - cb, u)) <= 4.0 / n + 1e-6
        along = np.array(a.exterior.coords) @ u
        assert along.max() - along.min() == pytest.approx(L, abs=1e-6)


@pytest.mark.parametrize("L", [10.0, 25.0])
def test_corridors_are_as_long_as_their_blocks_with_scattered_centres(L: float) -> None:
    """Centres at random positions within their blocks (sparse photons): lengths stay L."""
    rng = np.random.default_rng(5)
    n = 60
    blocks = line_blocks(n, L, 75.0)
    th = np.radians(75.0)
    jitter = rng.uniform(-0.45 * L, 0.45 * L, n)
    blocks["x"] += jitter * np.cos(th)
    blocks["y"] += jitter * np.sin(th)
    cor = block_corridors(blocks, width=13.0)
    u = np.array([np.cos(th), np.sin(th)])
    lengths = [np.ptp(np.array(p.exterior.coords) @ u) for p in cor.geometry]
    np.testing.assert_allclose(lengths, L, atol=1e-6)
    # and they sit where their blocks are, up to the mean jitter (a metre or two at most)
    true_mid = (np.array(blocks["s_start"]) + L / 2)
    got_mid = np.array([np.array(p.centroid.coords[0]) @ u for p in cor.geometry])
    offset = got_mid - true_mid - (np.array([500_000.0, 4_600_000.0]) @ u)
    assert np.ptp(offset) < 1e-6
    assert abs(offset.mean()) <= 3 * 0.45 * L / np.sqrt(3 * n)
