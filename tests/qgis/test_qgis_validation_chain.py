"""simulate -> blockheights -> referencerasters (PDAL) -> validate -> aspecterrors in QGIS.

Real airborne lidar (lasR_bcts_1.laz, BC Albers) and the project's simulator make the
photon/reference pair (no real pair exists; data/README.md).
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import pytest

pytestmark = [pytest.mark.qgis, pytest.mark.pdal, pytest.mark.slow]

CROP = (885040.0, 629180.0, 885200.0, 629380.0)  # inside the tile, BC Albers metres


@pytest.fixture(scope="module")
def chain(qgis_session, sample, pdal_bin, tmp_path_factory) -> dict[str, Any]:
    import processing
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback

    def run(alg: str, params: dict[str, Any]) -> dict[str, Any]:
        return processing.run(alg, params, context=QgsProcessingContext(),
                              feedback=QgsProcessingFeedback())

    tmp = tmp_path_factory.mktemp("chain")
    laz = sample("als/lasR_bcts_1.laz")
    out: dict[str, Any] = {"laz": laz, "tmp": tmp}
    out["sim"] = run("canopyblocks:simulate", {
        "INPUT": [str(laz)], "AZIMUTH": 0.0, "DIAMETER": 13.0, "PHOTON_RATE": 1, "SEED": 7,
        "OUTPUT": str(tmp / "sim.h5")})
    out["blocks"] = run("canopyblocks:blockheights", {
        "INPUT": str(tmp / "sim.h5"), "TRACK": "gt1r", "LENGTHS": "25",
        "OUTPUT": str(tmp / "blocks.gpkg")})
    out["rasters"] = run("canopyblocks:referencerasters", {
        "INPUT": [str(laz)], "RESOLUTION": 2.0,
        "EXTENT": f"{CROP[0]},{CROP[2]},{CROP[1]},{CROP[3]} [EPSG:3005]",
        "OUTPUT_DIR": str(tmp / "rasters")})
    r = out["rasters"]
    out["validate"] = run("canopyblocks:validate", {
        "INPUT": str(tmp / "blocks.gpkg"), "DTM": r["DTM"], "DSM_MAX": r["DSM_MAX"],
        "DSM_P90": r["DSM_P90"], "WIDTH": 13.0, "OFFSET": 0.0,
        "OUTPUT": str(tmp / "residuals.gpkg"), "STATS": str(tmp / "stats.csv")})
    out["calibrate"] = run("canopyblocks:calibrate", {
        "INPUT": str(tmp / "sim.h5"), "TRACK": "gt1r", "LENGTHS": "25", "DTM": r["DTM"],
        "DSM_MAX": r["DSM_MAX"], "DSM_P90": r["DSM_P90"], "WIDTH": 13.0, "OFFSET": 0.0,
        "OUTPUT": str(tmp / "calibration.csv")})
    out["aspect"] = run("canopyblocks:aspecterrors", {
        "INPUT": str(tmp / "residuals.gpkg"), "GROUP_BY": 0,
        "OUTPUT": str(tmp / "aspect_stats.csv"), "MAP": str(tmp / "aspect_map.gpkg")})
    return out


def _finite(v: Any) -> bool:
    return v is not None and isinstance(v, (int, float)) and math.isfinite(v)


def test_simulated_file_matches_core(chain):
    from canopyblocks.readers import open_track
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons

    tr = open_track(chain["tmp"] / "sim.h5", beam="gt1r")
    pts = read_las([chain["laz"]])
    sim = simulate_photons(pts, line_through(pts.bounds, 0.0, inset=6.5),
                           SimParams(diameter=13.0, photon_rate="temperate", beam="strong"), seed=7)
    direct = sim.photon_track()
    assert len(tr) == len(direct) > 100
    np.testing.assert_allclose(np.sort(tr.h), np.sort(direct.h), atol=1e-3)


def test_reference_rasters_grid(chain, open_layer):
    r = chain["rasters"]
    for key in ("DTM", "DSM_MAX", "DSM_P90"):
        layer = open_layer(r[key], "raster")
        # the tiles' CRS: BC Albers (+ CGVD28 heights, a compound CRS without one code)
        import pyproj

        crs = pyproj.CRS.from_wkt(layer.crs().toWkt())
        horiz = crs.sub_crs_list[0] if crs.is_compound else crs
        assert horiz.to_epsg() == 3005
        assert layer.rasterUnitsPerPixelX() == pytest.approx(2.0)
        ext = layer.extent()
        # the grid covers the requested crop, snapped outward to 2 m
        assert ext.xMinimum() <= CROP[0] and ext.xMaximum() >= CROP[2]
        assert ext.yMinimum() <= CROP[1] and ext.yMaximum() >= CROP[3]
        assert ext.width() <= CROP[2] - CROP[0] + 4.0
    import rasterio

    with rasterio.open(r["DTM"]) as d, rasterio.open(r["DSM_MAX"]) as m:
        dtm = d.read(1, masked=True)
        dsm = m.read(1, masked=True)
    both = ~(dtm.mask | dsm.mask)
    assert both.sum() > 0.9 * both.size
    # heights of the survey (data/README.md: 325-362 m), canopy above the ground
    assert 320 < float(dtm[both].min()) and float(dsm[both].max()) < 365
    assert np.all(dsm[both] >= dtm[both] - 0.5)


def test_validate_matches_core_and_own_arithmetic(chain, open_layer, layer_rows):
    from canopyblocks import read_blocks
    from canopyblocks.validation.block_validation import validate_blocks

    res = open_layer(chain["validate"]["OUTPUT"])
    rows = layer_rows(res)
    blocks = read_blocks(chain["tmp"] / "blocks.gpkg")
    r = chain["rasters"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        direct = validate_blocks(blocks, dtm=r["DTM"], dsm_max=r["DSM_MAX"],
                                 dsm_p90=r["DSM_P90"], width=13.0, offset=0.0)
    assert len(rows) == len(direct.residuals) == len(blocks)
    key = {int(x["block"]): x for x in rows}
    for d in direct.residuals.itertuples():
        q = key[int(d.block)]
        for col in ("ref_ground", "ref_top", "res_hmax", "res_ground"):
            v = getattr(d, col)
            assert (q[col] is None) if not np.isfinite(v) else q[col] == pytest.approx(v)
    # residual = photon - reference, row by row, on the QGIS layer itself
    usable = [x for x in rows if _finite(x["res_hmax"])]
    assert len(usable) >= 3
    for x in usable:
        assert x["res_hmax"] == pytest.approx(x["hmax"] - x["ref_hmax"], abs=1e-9)
        assert x["res_ground"] == pytest.approx(x["ground"] - x["ref_ground"], abs=1e-9)
    # the 'all' statistics of hmax from numpy over the used rows of the layer
    stats = open_layer(chain["validate"]["STATS"])
    srows = layer_rows(stats)
    st = next(s for s in srows if s["metric"] == "hmax" and s["group"] == "all")
    used = np.array([x["res_hmax"] for x in rows if x.get("use") and _finite(x["res_hmax"])])
    assert int(st["n"]) == used.size
    assert float(st["bias"]) == pytest.approx(float(used.mean()), abs=1e-6)
    assert float(st["rmse"]) == pytest.approx(float(np.sqrt(np.mean(used ** 2))), abs=1e-6)


def test_aspect_errors_partition_the_blocks(chain, open_layer, layer_rows):
    srows = layer_rows(open_layer(chain["aspect"]["OUTPUT"]))
    res = layer_rows(open_layer(chain["validate"]["OUTPUT"]))
    used = [x for x in res if x.get("use")]
    hm = [s for s in srows if s["metric"] == "hmax"]
    all_n = int(next(s for s in hm if s["group"] == "all")["n"])
    classes = [s for s in hm if str(s["group"]).startswith("aspect:")]
    assert classes and all(not str(s["group"]).startswith("slope:") for s in hm
                           if s["group"] != "all")
    assert sum(int(s["n"]) for s in classes) == all_n
    for s in classes:
        cls = s["group"].split(":", 1)[1]
        vals = np.array([x["res_hmax"] for x in used if x["aspect_class"] == cls
                         and _finite(x["res_hmax"])])
        assert int(s["n"]) == vals.size
        if vals.size:
            assert float(s["bias"]) == pytest.approx(float(vals.mean()), abs=1e-6)


def test_residual_and_aspect_styles(chain, open_layer):
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback
    from qgis_plugin import styles

    layer = open_layer(chain["validate"]["OUTPUT"])
    r = styles.residual_renderer(layer, "res_hmax")
    ranges = r.ranges()
    assert len(ranges) == 7
    assert ranges[0].lowerValue() == pytest.approx(-ranges[-1].upperValue())
    mid = ranges[3]
    assert mid.lowerValue() < 0 < mid.upperValue()
    assert mid.lowerValue() == pytest.approx(-mid.upperValue())
    # red for photon-below-reference, blue above (RdBu)
    assert ranges[0].symbol().color().red() > ranges[0].symbol().color().blue()
    assert ranges[-1].symbol().color().blue() > ranges[-1].symbol().color().red()
    pp = styles._StylePostProcessor.create("aspect", "aspect_class")
    pp.postProcessLayer(layer, QgsProcessingContext(), QgsProcessingFeedback())
    cats = layer.renderer().categories()
    assert {c.value() for c in cats} == set(styles.ASPECT_COLOURS)
    assert layer.renderer().classAttribute() == "aspect_class"


def test_calibrate_matches_core(chain):
    import pandas as pd

    from canopyblocks import BlockParams
    from canopyblocks.workflows.calibrate import calibrate_reference_rasters

    r = chain["rasters"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        core = calibrate_reference_rasters(
            str(chain["tmp"] / "sim.h5"), BlockParams(lengths=(25.0,)), dtm=r["DTM"],
            dsm_max=r["DSM_MAX"], dsm_p90=r["DSM_P90"], width=13.0, beam="gt1r", offset=0.0)
    got = pd.read_csv(chain["calibrate"]["OUTPUT"])
    assert len(got) == 1
    for col in ("top_cutoff", "ground_cutoff", "rmse_hmax_default", "rmse_hmax_calibrated"):
        assert got[col].iloc[0] == pytest.approx(core.table[col].iloc[0], rel=1e-9)
    # held out: default vs calibrated scored on the same blocks
    assert got["n_holdout"].iloc[0] > 0


def test_aspect_map_holds_the_usable_blocks_with_their_class(chain, open_layer, layer_rows):
    """Issue 12 item 5: aspect errors on a map, not only a table."""
    from qgis.core import QgsWkbTypes

    layer = open_layer(chain["aspect"]["MAP"])
    assert QgsWkbTypes.geometryType(layer.wkbType()) == QgsWkbTypes.PolygonGeometry
    rows = layer_rows(layer)
    used = [x for x in layer_rows(open_layer(chain["validate"]["OUTPUT"])) if x.get("use")]
    assert sorted((int(r["block"]), r["aspect_class"]) for r in rows) == \
        sorted((int(x["block"]), x["aspect_class"]) for x in used)
    by_block = {int(x["block"]): x for x in used}
    for r in rows:
        if _finite(r["res_hmax"]):
            assert r["res_hmax"] == pytest.approx(by_block[int(r["block"])]["res_hmax"])


def test_blocks_stand_in_the_elevation_profile_and_sparse_ones_show(chain, open_layer):
    """Issue 12 items 4 and 6: blocks as bars from ground to top; no near-white class; an
    else rule draws blocks without a height."""
    from qgis.core import (
        Qgis,
        QgsCategorizedSymbolRenderer,
        QgsExpression,
        QgsExpressionContext,
        QgsExpressionContextUtils,
        QgsMapLayerElevationProperties,
    )
    from qgis_plugin import styles

    layer = open_layer(chain["blocks"]["OUTPUT"])
    assert styles.set_elevation(layer)
    props = layer.elevationProperties()
    dd = props.dataDefinedProperties()
    P = QgsMapLayerElevationProperties.Property
    assert props.clamping() == Qgis.AltitudeClamping.Absolute and props.extrusionEnabled()
    assert dd.property(P.ZOffset).field() == "ground"
    assert dd.property(P.ExtrusionHeight).field() == "hmax"
    r = styles.height_renderer(layer, "hmax")
    assert isinstance(r, QgsCategorizedSymbolRenderer)
    cats = r.categories()
    assert cats[-1].value() is None or cats[-1].value() == ""  # catch-all: no height
    first = cats[0].symbol().color()
    assert first.lightnessF() < 0.85, first.name()
    # every block with a height falls in one of the classes, and in the class its value says
    keys = {c.value(): c.label() for c in cats[:-1]}
    ctx = QgsExpressionContext(QgsExpressionContextUtils.globalProjectLayerScopes(layer))
    expr = QgsExpression(r.classAttribute())
    for f in layer.getFeatures():
        ctx.setFeature(f)
        key = expr.evaluate(ctx)
        if f["hmax"] is None or (hasattr(f["hmax"], "isNull") and f["hmax"].isNull()):
            assert key is None or (hasattr(key, "isNull") and key.isNull())
            continue
        label = keys[key]
        lo, hi = (float(v) for v in label.split(": ")[-1].replace(" m", "").split(" to "))
        # negative heights (inverted blocks) go to the lowest class
        assert (lo - 0.05 <= f["hmax"] or key.endswith("0")) and f["hmax"] <= hi + 0.05, \
            (f["hmax"], label)


def test_dtm_loads_with_elevation_and_a_ramp_over_its_values(chain, open_layer):
    import rasterio
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback
    from qgis_plugin import styles

    layer = open_layer(chain["rasters"]["DTM"], kind="raster")
    pp = styles._RasterPostProcessor.create("raster_dtm")
    pp.postProcessLayer(layer, QgsProcessingContext(), QgsProcessingFeedback())
    assert layer.elevationProperties().isEnabled()
    shader = layer.renderer().shader().rasterShaderFunction()
    with rasterio.open(chain["rasters"]["DTM"]) as src:
        v = src.read(1, masked=True)
    assert shader.minimumValue() == pytest.approx(float(v.min()), abs=1e-3)
    assert shader.maximumValue() == pytest.approx(float(v.max()), abs=1e-3)

