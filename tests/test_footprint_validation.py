"""Footprint validation (DESIGN 4.10) on a real tile with footprints made from the ALS."""

from __future__ import annotations

import math
import warnings

import click
import geopandas as gpd
import numpy as np
import pandas as pd
import pyproj
import pytest

from canopyblocks.errors import DatumError, InputError, NoUsableDataError
from canopyblocks.readers.las import LasPoints, read_las
from canopyblocks.reference.footprint_params import FootprintReferenceParams
from canopyblocks.validation.footprints import (
    FootprintOutsideWarning,
    validate_blocks_footprint,
    validate_footprints,
)
from canopyblocks.workflows.validate import validate_footprints_file

N_GEOID = 17.25  # a constant "geoid height": ellipsoidal = orthometric + N
OFFSETS = {"ground": 0.3, "rh98": 1.0, "rh50": -0.5, "cover": 0.05}
PARAMS = FootprintReferenceParams(diameter=22.0, cut=1.5, weighting="gaussian")


@pytest.fixture(scope="module")
def tile_path(sample):  # noqa: ANN001, ANN201
    return sample("als/lasR_bcts_1.laz")


@pytest.fixture(scope="module")
def tile(tile_path) -> LasPoints:  # noqa: ANN001
    return read_las(tile_path)


def brute(pts: LasPoints, cx: float, cy: float) -> dict[str, float]:
    """Ground, RH98, RH50, cover of one footprint, plainly (22 m, points within 16.5 m)."""
    R = 11.0
    r2 = (pts.x - cx) ** 2 + (pts.y - cy) ** 2
    sel = r2 <= (1.5 * R) ** 2
    w = np.exp(-2 * r2[sel] / R**2)
    dx, dy, z = pts.x[sel] - cx, pts.y[sel] - cy, pts.z[sel]
    g = pts.classification[sel] == 2
    sw = np.sqrt(w[g])
    A = np.column_stack([np.ones(g.sum()), dx[g], dy[g]]) * sw[:, None]
    (a, b, c), *_ = np.linalg.lstsq(A, z[g] * sw, rcond=None)
    h = z - (a + b * dx + c * dy)
    o = np.argsort(h)
    cum = np.cumsum(w[o]) / w.sum()
    return {"ground": float(np.sum(w[g] * z[g]) / w[g].sum()),
            "rh98": float(h[o][np.argmax(cum >= 0.98 - 1e-12)]),
            "rh50": float(h[o][np.argmax(cum >= 0.50 - 1e-12)]),
            "cover": float(w[h > 2.0].sum() / w.sum())}


@pytest.fixture(scope="module")
def footprints(tile: LasPoints) -> pd.DataFrame:
    """12 footprints along a diagonal of the tile (values = brute force + offsets), plus 2
    beyond the tile's edge; lon/lat in WGS84, elevations ellipsoidal (+ N)."""
    x0, y0, x1, y1 = tile.bounds
    t = np.linspace(0.0, 1.0, 12)
    cx = np.concatenate([x0 + 25 + t * (x1 - x0 - 50), [x1 + 40.0, x1 + 80.0]])
    cy = np.concatenate([y0 + 25 + t * (y1 - y0 - 50), [y1 + 40.0, y1 + 80.0]])
    rows = []
    for i, (x, y) in enumerate(zip(cx, cy)):
        v = brute(tile, x, y) if i < 12 else {k: 10.0 for k in OFFSETS}
        rows.append({k: v[k] + OFFSETS[k] for k in OFFSETS})
    df = pd.DataFrame(rows)
    df["ground"] += N_GEOID
    tr = pyproj.Transformer.from_crs(tile.crs, "EPSG:4326", always_xy=True)
    lon, lat = tr.transform(cx, cy)
    df.insert(0, "beam", np.where(np.arange(cx.size) % 2 == 0, "BEAM0101", "BEAM1000"))
    df.insert(1, "shot_number", np.int64(196400200300400000) + np.arange(cx.size))
    df["lon"], df["lat"] = lon, lat
    df["top"] = df["ground"] + df["rh98"]
    df["flag"] = "ok"
    df.loc[3, "flag"] = "degraded"
    return df


def test_residuals_equal_the_known_offsets(tile: LasPoints, footprints: pd.DataFrame) -> None:
    with pytest.warns(FootprintOutsideWarning, match="2 of 14 footprints"):
        res = validate_footprints(footprints, tile, params=PARAMS, offset=N_GEOID)
    r = res.residuals
    assert r.crs.equals(tile.crs)
    assert r["shot_number"].tolist() == footprints["shot_number"].tolist()
    assert r["flag"].tolist()[-2:] == ["outside", "outside"]
    assert r["flag"].iloc[3] == "degraded"
    use = r["use"].to_numpy(bool)
    assert use.sum() == 11
    for m, off in OFFSETS.items():
        np.testing.assert_allclose(r.loc[use, f"res_{m}"], off, atol=1e-6)
    # circles of radius R = 11 m around the centres
    np.testing.assert_allclose(r.geometry.area.iloc[:3], math.pi * 121, rtol=0.02)
    st = res.stats
    allg = st[st["group"] == "all"].set_index("metric")
    for m, off in OFFSETS.items():
        assert allg.loc[m, "n"] == 11
        assert allg.loc[m, "bias"] == pytest.approx(off, abs=1e-6)
        assert allg.loc[m, "rmse"] == pytest.approx(abs(off), abs=1e-6)
    assert {"beam:BEAM0101", "beam:BEAM1000"} <= set(st["group"])
    assert any(g.startswith("cover:") for g in st["group"])
    assert any(g.startswith("slope:") for g in st["group"])
    assert (st["length"] == 22.0).all()
    n_beam = st[(st["metric"] == "ground") & st["group"].str.startswith("beam:")]["n"].sum()
    assert n_beam == 11


def test_datum_rule_and_no_usable(tile: LasPoints, tile_path, footprints) -> None:  # noqa: ANN001
    # the tile states CGVD28 heights (EPSG:5713); GEDI elevations are ellipsoidal
    with pytest.raises(DatumError, match="geoid"):
        validate_footprints(footprints, [tile_path], params=PARAMS)
    far = footprints.iloc[-2:]
    with pytest.raises(NoUsableDataError, match="footprints"):
        validate_footprints(far, [tile_path], params=PARAMS, offset=N_GEOID)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FootprintOutsideWarning)
        with pytest.raises(NoUsableDataError, match="none of the 2 footprints is usable"):
            validate_footprints(far, tile, params=PARAMS, offset=N_GEOID)
    with pytest.raises(InputError, match="rh98"):
        validate_footprints(footprints.drop(columns="rh98"), tile, offset=N_GEOID)


def _dtm(tile: LasPoints, path):  # noqa: ANN001, ANN202
    """A 2 m GeoTIFF of the tile's mean ground per cell (for the maps' hillshade)."""
    import rasterio
    from affine import Affine

    x0, y0, x1, y1 = tile.bounds
    nx, ny = int((x1 - x0) // 2) + 1, int((y1 - y0) // 2) + 1
    g = tile.classification == 2
    col = ((tile.x[g] - x0) // 2).astype(int)
    row = ((y1 - tile.y[g]) // 2).astype(int)
    s = np.bincount(row * nx + col, tile.z[g], minlength=nx * ny)
    c = np.bincount(row * nx + col, minlength=nx * ny)
    z = np.where(c > 0, s / np.maximum(c, 1), -9999.0).reshape(ny, nx)
    with rasterio.open(path, "w", driver="GTiff", width=nx, height=ny, count=1,
                       dtype="float64", crs=tile.crs.to_wkt(), nodata=-9999.0,
                       transform=Affine(2.0, 0.0, x0, 0.0, -2.0, y1)) as dst:
        dst.write(z, 1)
    return path


def test_file_round_trip_and_cli(tile: LasPoints, tile_path, footprints, tmp_path) -> None:  # noqa: ANN001
    from canopyblocks.cli.common import run_main
    from canopyblocks.cli.footprint_validation import register
    from canopyblocks.outputs.tables import read_layer, write_table

    gdf = gpd.GeoDataFrame(footprints, geometry=gpd.points_from_xy(
        footprints["lon"], footprints["lat"]), crs="EPSG:4326").to_crs(tile.crs)
    src = tmp_path / "fp.gpkg"
    write_table(gdf, src, layer="footprints")
    out = tmp_path / "val.gpkg"
    with pytest.raises(InputError, match="new file"):
        validate_footprints_file(src, [tile_path], src, params=PARAMS, offset=N_GEOID)
    dtm = _dtm(tile, tmp_path / "dtm.tif")
    with pytest.warns(FootprintOutsideWarning):
        validate_footprints_file(src, [tile_path], out, params=PARAMS, offset=N_GEOID,
                                 plots=tmp_path / "plots", dtm=dtm)
    back = read_layer(out, "residuals_footprints")
    assert int(back["use"].sum()) == 11
    np.testing.assert_allclose(back.loc[back["use"], "res_rh98"], 1.0, atol=1e-6)
    assert len(read_layer(out, "stats_footprints")) > 0
    pngs = sorted(p.name for p in (tmp_path / "plots").glob("*.png"))
    assert pngs == ["footprints_res_ground.png", "footprints_res_rh98.png",
                    "footprints_rh98.png", "footprints_scatter.png"]

    @click.group()
    def cli() -> None:
        pass

    register(cli)
    out2 = tmp_path / "val2.gpkg"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FootprintOutsideWarning)
        code = run_main(cli, ["validate-footprints", str(src), "--points", str(tile_path),
                              "--weighting", "gaussian", "--offset", str(N_GEOID),
                              "-o", str(out2)])
    assert code == 0 and out2.exists()
    code = run_main(cli, ["validate-footprints", str(src), "--points", str(tile_path),
                          "-o", str(tmp_path / "val3.gpkg")])
    assert code == 2 and not (tmp_path / "val3.gpkg").exists()


def test_blocks_against_footprint_reference(tile: LasPoints) -> None:
    from canopyblocks.reference.footprint import block_footprint_reference

    x0, y0, x1, y1 = tile.bounds
    ang = math.atan2(y1 - y0, x1 - x0)
    n = 6
    s0 = np.arange(n) * 25.0
    mid = s0 + 12.5
    blocks = gpd.GeoDataFrame(
        {"track": "gt2l", "length": 25.0, "block": np.arange(n), "s_start": s0,
         "s_end": s0 + 25.0, "x": x0 + 20 + mid * math.cos(ang),
         "y": y0 + 20 + mid * math.sin(ang), "flag": "ok"},
        geometry=gpd.points_from_xy(x0 + 20 + mid * math.cos(ang),
                                    y0 + 20 + mid * math.sin(ang)), crs=tile.crs)
    ref = block_footprint_reference(blocks, tile)
    blocks["ground"] = ref["ref_ground"].to_numpy() + 1.5 + N_GEOID
    blocks["top"] = ref["ref_top"].to_numpy() - 2.0 + N_GEOID
    blocks["z90"] = ref["ref_top90"].to_numpy() + N_GEOID
    blocks["hmax"] = blocks["top"] - blocks["ground"]
    blocks["h90"] = blocks["z90"] - blocks["ground"]
    res = validate_blocks_footprint(blocks, tile, offset=N_GEOID)
    r = res.residuals
    assert r["use"].all()
    np.testing.assert_allclose(r["res_ground"], 1.5, atol=1e-9)
    np.testing.assert_allclose(r["res_top"], -2.0, atol=1e-9)
    np.testing.assert_allclose(r["res_hmax"], -3.5, atol=1e-9)
    np.testing.assert_allclose(r.geometry.area, 25.0 * 13.0, rtol=1e-6)
    assert set(res.stats["metric"]) == {"ground", "top", "hmax", "h90"}


def test_blocks_against_footprint_reference_on_tiles_without_crs(tile: LasPoints, tile_path,  # noqa: ANN001
                                                                 tmp_path) -> None:
    """``points_crs`` (``validate --points-crs``) is the CRS of tiles whose files state none."""
    import laspy

    from canopyblocks.errors import CanopyBlocksError

    las = laspy.read(tile_path)
    las.header.vlrs = [v for v in las.header.vlrs  # GeoTIFF keys and WKT records
                       if v.user_id != "LASF_Projection" and v.record_id != 2112]
    bare = tmp_path / "no_crs.laz"
    las.write(bare)
    x0, y0, x1, y1 = tile.bounds
    mid = np.arange(4) * 25.0 + 12.5
    bx, by = x0 + 30 + mid * 0.7, y0 + 30 + mid * 0.7
    blocks = gpd.GeoDataFrame(
        {"track": "gt2l", "length": 25.0, "block": np.arange(4), "s_start": mid - 12.5,
         "s_end": mid + 12.5, "x": bx, "y": by, "flag": "ok", "ground": 300.0, "top": 320.0,
         "z90": 318.0, "hmax": 20.0, "h90": 18.0},
        geometry=gpd.points_from_xy(bx, by), crs=tile.crs)
    want = validate_blocks_footprint(blocks, [tile_path], offset=0.0).residuals
    with pytest.raises(CanopyBlocksError):
        validate_blocks_footprint(blocks, [bare], offset=0.0)
    got = validate_blocks_footprint(blocks, [bare], offset=0.0, points_crs=tile.crs).residuals
    np.testing.assert_allclose(got["ref_ground"], want["ref_ground"], atol=1e-9)
    np.testing.assert_allclose(got["ref_rh98"], want["ref_rh98"], atol=1e-9)


def test_validate_footprints_is_validate(tile, tile_path, footprints, tmp_path) -> None:
    """`validate FOOTPRINTS --points` gives what the deprecated `validate-footprints`
    gave, defaults and --diameter alike (a --diameter used to drop GEDI's 3-sigma cut and
    density weights)."""
    from canopyblocks.outputs.tables import read_layer, write_table
    from test_cli import run_cli

    gdf = gpd.GeoDataFrame(footprints, geometry=gpd.points_from_xy(
        footprints["lon"], footprints["lat"]), crs="EPSG:4326").to_crs(tile.crs)
    src = tmp_path / "fp.gpkg"
    write_table(gdf, src, layer="footprints")
    common = [str(src), "--points", str(tile_path), "--offset", str(N_GEOID)]
    got = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FootprintOutsideWarning)
        for name, args in {"old": ["validate-footprints", *common],
                           "new": ["validate", *common],
                           "points": ["validate", *common, "--footprint-definition",
                                      "points", "--weighting", "gaussian"]}.items():
            out = tmp_path / f"{name}.gpkg"
            r = run_cli(*args, "-o", str(out))
            assert r.returncode == 0, r.stderr
            assert ("deprecated" in r.stderr) == (name == "old"), r.stderr
            got[name] = read_layer(out, "residuals_footprints")
    # the weighted-points definition, one option away, is the brute force's
    assert set(got["points"]["reference"]) == {"points"}
    use = got["points"]["use"].to_numpy(bool)
    assert use.sum() == 11
    for m, off in OFFSETS.items():
        np.testing.assert_allclose(got["points"].loc[use, f"res_{m}"], off, atol=1e-6)
    assert set(got["new"]["reference"]) == {"waveform"}
    # --diameter is refused for GEDI footprints (the instrument's footprint is fixed)
    r = run_cli("validate", *common, "--diameter", "22", "-o", str(tmp_path / "d.gpkg"))
    assert r.returncode == 2 and "applies to photon blocks only" in r.stderr, r.stderr
    assert not (tmp_path / "d.gpkg").exists()
    for name in ("new",):
        for col in ("ref_ground", "ref_rh98", "res_rh98"):
            np.testing.assert_allclose(got[name][col], got["old"][col], equal_nan=True,
                                       err_msg=f"{name} {col}")


def test_a_tile_without_ground_is_named_not_the_coverage(tile_path, sample, tmp_path) -> None:  # noqa: ANN001
    """`validate --points` with a tile whose ground points were reclassified: a warning
    names it (as `run`'s does) and its blocks have no ground reference; that tile alone is
    refused for its missing ground, not sent to check the track's coverage."""
    import laspy

    las = laspy.read(sample("als/lasR_bcts_2.laz"))
    c = np.asarray(las.classification)
    c[c == 2] = 1
    las.classification = c
    bare = tmp_path / "noground.laz"
    las.write(str(bare))
    by = np.arange(629180.0, 629680.0, 25.0)  # north through lasR_bcts_1 into the bare tile
    bx = np.full(by.size, 885120.0)
    blocks = gpd.GeoDataFrame(
        {"track": "gt2l", "length": 25.0, "block": np.arange(by.size), "s_start": by - 12.5,
         "s_end": by + 12.5, "x": bx, "y": by, "flag": "ok", "ground": 340.0, "top": 360.0,
         "z90": 358.0, "hmax": 20.0, "h90": 18.0},
        geometry=gpd.points_from_xy(bx, by), crs="EPSG:3005")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = validate_blocks_footprint(blocks, [tile_path, bare], offset=0.0).residuals
    named = [str(w.message) for w in caught if str(bare) in str(w.message)]
    assert len(named) == 1 and "no ground point (ASPRS class 2)" in named[0], named
    assert "no ground reference" in named[0] and "filters.smrf" in named[0]
    over_bare = by > 629400.0 + 20.0   # more than the footprint's reach inside the bare tile
    over_ground = by < 629400.0 - 20.0
    assert r["ref_ground"].to_numpy(float)[over_bare].size == over_bare.sum() > 0
    assert np.isnan(r["ref_ground"].to_numpy(float)[over_bare]).all()
    assert np.isfinite(r["ref_ground"].to_numpy(float)[over_ground]).all()
    with pytest.raises(NoUsableDataError) as exc:
        validate_blocks_footprint(blocks, [bare], offset=0.0)
    msg = str(exc.value)
    assert str(bare) in msg and "classed ground" in msg and "covers" not in msg
