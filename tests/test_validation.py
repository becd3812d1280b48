"""End-to-end validation: synthetic rasters with known residuals, datums, CLI, plots."""

from __future__ import annotations

from pathlib import Path

import geopandas as gpd
import numpy as np
import pyogrio
import pytest

from canopyblocks.cli import main
from canopyblocks.errors import CanopyBlocksWarning, CoverageError, DatumError
from canopyblocks.outputs.tables import read_layer, write_table
from canopyblocks.outputs.validation_plots import write_validation_plots
from canopyblocks.reference.corridor import block_corridors
from canopyblocks.schema import BLOCK_COLUMNS, RESIDUAL_COLUMNS, STATS_COLUMNS
from canopyblocks.validation import validate_blocks
from test_zonal import RES, X0, Y0, brute_force, make_blocks, write_tif

OFFSETS = {"ground": 0.5, "top": -1.0, "z90": 0.3}  # photon minus truth, by construction


@pytest.fixture()
def scene(tmp_path: Path) -> dict:
    rng = np.random.default_rng(11)
    h, w = 80, 90
    cols = np.arange(w)[None, :] * np.ones((h, 1))
    dtm = 800.0 - 0.2 * cols * RES + rng.normal(0, 0.05, (h, w))  # faces east, 11.3 degrees
    dsm = dtm + 18 + rng.normal(0, 2, (h, w))
    p90 = dtm + 14 + rng.normal(0, 1, (h, w))
    paths = {"dtm": write_tif(tmp_path / "dtm.tif", dtm),
             "dsm_max": write_tif(tmp_path / "dsm.tif", dsm),
             "dsm_p90": write_tif(tmp_path / "p90.tif", p90)}
    arrays = {"dtm": dtm, "dsm_max": dsm, "dsm_p90": p90}
    # 8 blocks of 20 m running north-east; the last one leaves the raster's top edge
    blocks = make_blocks(8, 20.0, 60.0, X0 + 30.0, Y0 - 135.0)
    cor = block_corridors(blocks, width=2.0)
    truth = {k: [] for k in ("ground", "top", "top90")}
    for poly in cor.geometry:
        bf = brute_force(poly, arrays)
        truth["ground"].append(np.nanmean(bf["dtm"]))
        truth["top"].append(np.nanmax(bf["dsm_max"]))
        truth["top90"].append(np.nanmax(bf["dsm_p90"]))
    g = np.array(truth["ground"]) + OFFSETS["ground"]
    t = np.array(truth["top"]) + OFFSETS["top"]
    z90 = np.array(truth["top90"]) + OFFSETS["z90"]
    blocks = blocks.assign(lon=-111.0, lat=41.5, n_photons=50, n_kept=45, n_between=30,
                           top=t, ground=g, hmax=t - g, z90=z90, h90=z90 - g, flag="ok",
                           hmax_sigma=2.0, ground_sigma=0.5)
    blocks.loc[2, "flag"] = "sparse"
    blocks["use"] = blocks["flag"] == "ok"
    blocks = blocks[list(BLOCK_COLUMNS) + ["geometry"]]
    return {"paths": paths, "blocks": blocks, "truth": truth, "tmp": tmp_path}


def test_known_residuals_and_stats(scene: dict) -> None:
    res = validate_blocks(scene["blocks"], **scene["paths"], width=2.0, reference_vertical_crs="EPSG:4979")
    r = res.residuals
    assert list(r.columns[:len(BLOCK_COLUMNS)]) == list(BLOCK_COLUMNS)
    assert set(RESIDUAL_COLUMNS) <= set(r.columns)
    assert len(r) == 8 and r.geometry.geom_type.eq("Polygon").all()
    assert list(r["ref_flag"]) == ["ok"] * 7 + ["outside"]
    assert list(r["use"]) == [True, True, False, True, True, True, True, False]
    ok = r["ref_flag"] == "ok"
    np.testing.assert_allclose(r["res_ground"][ok], 0.5, atol=1e-4)
    np.testing.assert_allclose(r["res_top"][ok], -1.0, atol=1e-4)
    np.testing.assert_allclose(r["res_hmax"][ok], -1.5, atol=1e-4)
    np.testing.assert_allclose(r["res_h90"][ok], 0.3 - 0.5, atol=1e-4)
    np.testing.assert_allclose(r["ref_ground"][ok], np.array(scene["truth"]["ground"])[ok],
                               atol=1e-4)
    assert (r["aspect_class"][ok] == "E").all() and (r["slope_class"][ok] == "10-20").all()
    np.testing.assert_allclose(r["slope"][ok], np.degrees(np.arctan(0.2)), atol=0.5)  # noise
    st = res.stats
    assert list(st.columns) == list(STATS_COLUMNS)
    row = st[(st["metric"] == "hmax") & (st["group"] == "all")].iloc[0]
    assert row["n"] == 6 and row["length"] == 20.0
    assert row["bias"] == pytest.approx(-1.5, abs=1e-4)
    assert row["rmse"] == pytest.approx(1.5, abs=1e-4)
    assert row["mae"] == pytest.approx(1.5, abs=1e-4)
    assert set(st["group"]) == {"all", "aspect:E", "slope:10-20"}
    assert res.datum == "same"


def test_datum_refusal_and_offset(scene: dict) -> None:
    with pytest.raises(DatumError, match="NAVD88"):
        validate_blocks(scene["blocks"], **scene["paths"], width=2.0,
                        reference_vertical_crs="EPSG:32612+5703")
    res = validate_blocks(scene["blocks"], **scene["paths"], width=2.0,
                          reference_vertical_crs="EPSG:32612+5703", offset=-17.0)
    ok = res.residuals["ref_flag"] == "ok"
    np.testing.assert_allclose(res.residuals["res_ground"][ok], 17.5, atol=1e-4)
    np.testing.assert_allclose(res.residuals["res_hmax"][ok], -1.5, atol=1e-4)
    assert res.datum == "differ"
    with pytest.warns(CanopyBlocksWarning, match="vertical datum unknown"):
        validate_blocks(scene["blocks"], **scene["paths"], width=2.0)  # horizontal-only GeoTIFF CRS


def test_compound_crs_rasters_refused_without_conversion(scene: dict, tmp_path: Path) -> None:
    """GeoTIFFs in WGS 84 / UTM 12N + NAVD88 height: their vertical datum is read and used."""
    import pyproj
    import rasterio

    paths = {}
    for k, p in scene["paths"].items():
        with rasterio.open(p) as src:
            arr = src.read(1)
        crs = rasterio.crs.CRS.from_wkt(pyproj.CRS("EPSG:32612+5703").to_wkt())
        paths[k] = write_tif(tmp_path / f"c_{k}.tif", arr, crs=crs)
    with pytest.raises(DatumError, match="NAVD88"):
        validate_blocks(scene["blocks"], **paths, width=2.0)
    res = validate_blocks(scene["blocks"], **paths, offset=0.0, width=2.0)
    ok = res.residuals["ref_flag"] == "ok"
    np.testing.assert_allclose(res.residuals["res_ground"][ok], 0.5, atol=1e-4)


def test_not_covering(scene: dict) -> None:
    far = scene["blocks"].copy()
    far["x"] += 5000.0
    far = far.set_geometry(gpd.points_from_xy(far["x"], far["y"]), crs=far.crs)
    with pytest.raises(CoverageError):
        validate_blocks(far, **scene["paths"], width=2.0, reference_vertical_crs="EPSG:4979")


def _cli_args(scene: dict, out: Path) -> list[str]:
    bp = scene["tmp"] / "blocks.gpkg"
    if not bp.exists():
        write_table(scene["blocks"], bp, layer="blocks")
    p = scene["paths"]
    return ["-q", "validate", str(bp), "--dtm", str(p["dtm"]), "--dsm-max", str(p["dsm_max"]),
            "--dsm-p90", str(p["dsm_p90"]), "-o", str(out), "--reference-vcrs", "EPSG:4979",
            "--width", "2"]


def test_cli(scene: dict, capsys: pytest.CaptureFixture[str]) -> None:
    out = scene["tmp"] / "val.gpkg"
    plots = scene["tmp"] / "plots"
    assert main(_cli_args(scene, out) + ["--plots", str(plots)]) == 0
    names = [n for n, _ in pyogrio.list_layers(out)]
    assert set(names) == {"residuals", "stats"}
    r = read_layer(out, "residuals")
    np.testing.assert_allclose(r["res_top"][r["ref_flag"] == "ok"], -1.0, atol=1e-4)
    st = read_layer(out, "stats")
    assert st[(st["metric"] == "top") & (st["group"] == "all")]["n"].iloc[0] == 6
    pngs = sorted(p.name for p in plots.iterdir())
    assert pngs == ["aspect_rmse_20m.png", "validation_20m.png"]
    assert (plots / "validation_20m.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("extra, message", [
    (["--reference-vcrs", "EPSG:32612+5703"], "NAVD88"),
    (["--offset", "1", "--geoid", "g.tif"], "not both"),
    (["--width", "-2"], "width"),
])
def test_cli_bad_input_leaves_nothing(scene: dict, capsys: pytest.CaptureFixture[str],
                                      extra: list[str], message: str) -> None:
    out = scene["tmp"] / "bad.gpkg"
    assert main(_cli_args(scene, out) + extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0]
    assert not out.exists()
    assert not [p for p in scene["tmp"].iterdir() if ".part" in p.name]


def test_cli_not_covering(scene: dict, capsys: pytest.CaptureFixture[str]) -> None:
    far = scene["blocks"].copy()
    far["x"] += 5000.0
    far = far.set_geometry(gpd.points_from_xy(far["x"], far["y"]), crs=far.crs)
    bp = scene["tmp"] / "far.gpkg"
    write_table(far, bp)
    out = scene["tmp"] / "far_val.gpkg"
    args = _cli_args(scene, out)
    args[2] = str(bp)
    assert main(args) == 2
    assert "do not cover the track" in capsys.readouterr().err
    assert not out.exists()


def test_plots_written(scene: dict) -> None:
    res = validate_blocks(scene["blocks"], **scene["paths"], width=2.0, reference_vertical_crs="EPSG:4979")
    paths = write_validation_plots(res.residuals, res.stats, scene["tmp"] / "figs")
    assert len(paths) == 2 and all(p.stat().st_size > 10_000 for p in paths)
