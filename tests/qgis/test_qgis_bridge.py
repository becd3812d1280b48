"""core_bridge (import errors, logging to the QGIS message log) and layers.py conversions."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

pytestmark = [pytest.mark.qgis]


def test_missing_core_module_names_the_install_command(qgis_session):
    from qgis.core import QgsProcessingException
    from qgis_plugin.core_bridge import import_core
    from qgis_plugin.dependencies import install_hint

    with pytest.raises(QgsProcessingException) as exc:
        import_core("canopyblocks.no_such_module")
    msg = str(exc.value.args[0]) if exc.value.args else str(exc.value)
    assert "install canopyblocks into QGIS's Python" in msg
    assert "/usr/bin/python3 -m pip install" in install_hint()


def test_core_logging_reaches_qgis_message_log(qgis_session, run_alg, atl03_sample, tmp_path):
    from qgis.core import QgsApplication, QgsProcessingFeedback

    got: list[tuple[str, str]] = []

    def on_message(message: str, tag: str, level: object) -> None:
        got.append((tag, message))

    log = QgsApplication.messageLog()
    log.messageReceived.connect(on_message)
    fb_texts: list[str] = []

    class Feedback(QgsProcessingFeedback):
        def pushInfo(self, info: str) -> None:  # noqa: N802
            fb_texts.append(info)
            super().pushInfo(info)

    try:
        run_alg("canopyblocks:blockheights",
                {"INPUT": str(atl03_sample), "TRACK": "gt1r", "LENGTHS": "25",
                 "OUTPUT": str(tmp_path / "b.gpkg")}, feedback=Feedback())
    finally:
        log.messageReceived.disconnect(on_message)
    ours = [m for tag, m in got if tag == "canopyblocks"]
    # the ATL03 reader logs the photon count at INFO (6,809 photons in gt1r)
    assert any("6809 photons" in m for m in ours), ours
    assert any("6809 photons" in t for t in fb_texts)
    assert logging.getLogger("canopyblocks").handlers


def test_frame_round_trip_through_a_memory_layer(qgis_session):
    import geopandas as gpd
    import pandas as pd
    import shapely
    from qgis.core import QgsFeature, QgsGeometry, QgsVectorLayer
    from qgis_plugin.layers import frame_fields, frame_wkb_type, source_to_frame

    df = gpd.GeoDataFrame(
        pd.DataFrame({"i": np.array([1, 2, 3], np.int64), "f": [1.5, np.nan, -2.0],
                      "s": ["ok", "sparse", "ok"], "b": [True, False, True]}),
        geometry=shapely.points([0.0, 10.0, 20.0], [5.0, 5.0, 5.0]), crs="EPSG:32613")
    fields = frame_fields(df)
    assert [f.name() for f in fields] == ["i", "f", "s", "b"]
    assert fields.field("i").isNumeric() and fields.field("f").isNumeric()
    assert not fields.field("s").isNumeric()
    layer = QgsVectorLayer("Point?crs=EPSG:32613", "mem", "memory")
    assert frame_wkb_type(df) == layer.wkbType()
    pr = layer.dataProvider()
    pr.addAttributes(list(fields))
    layer.updateFields()
    feats = []
    for row, geom in zip(df.itertuples(index=False), df.geometry):
        f = QgsFeature(layer.fields())
        f.setAttributes([int(row.i), None if math.isnan(row.f) else float(row.f), row.s,
                         bool(row.b)])
        f.setGeometry(QgsGeometry.fromWkt(geom.wkt))
        feats.append(f)
    pr.addFeatures(feats)
    back = source_to_frame(layer)
    assert back.crs.to_epsg() == 32613
    assert back["i"].tolist() == [1, 2, 3]
    assert back["f"].iloc[0] == 1.5 and np.isnan(back["f"].iloc[1])
    assert back["s"].tolist() == ["ok", "sparse", "ok"]
    assert back.geometry.x.tolist() == [0.0, 10.0, 20.0]
    del layer, pr


def test_referencerasters_says_how_to_get_pdal(qgis_session, monkeypatch, tmp_path):
    from qgis.core import QgsApplication, QgsProcessingContext

    monkeypatch.setenv("CANOPYBLOCKS_PDAL", str(tmp_path / "no-pdal-here"))
    alg = QgsApplication.processingRegistry().algorithmById("canopyblocks:referencerasters")
    ok, msg = alg.canExecute()
    assert not ok
    assert "scripts/install_pdal.sh" in msg and "CANOPYBLOCKS_PDAL" in msg
    ok, msg = alg.checkParameterValues({"INPUT": [], "OUTPUT_DIR": str(tmp_path)},
                                       QgsProcessingContext())
    assert not ok and "install_pdal.sh" in msg


def test_core_messages_speak_qgis_not_command_line(qgis_session) -> None:
    """Issue 12 item 7: a datum refusal named --geoid/--offset; in QGIS it names the
    algorithm's parameters."""
    from qgis_plugin.core_bridge import qgis_words

    from canopyblocks.errors import DatumError
    from canopyblocks.reference.datum import check_vertical_datums

    with pytest.raises(DatumError) as info:
        check_vertical_datums("EPSG:4979", "EPSG:3005+5713")
    raw = str(info.value)
    assert "--geoid" in raw  # the core speaks command line ...
    text = qgis_words(raw)
    assert "--" not in text and "'Geoid undulation raster'" in text  # ... QGIS does not
    assert qgis_words("run `canopyblocks rasters` first (CLI: --crs 3005)") == \
        "run the 'Reference rasters from airborne lidar' algorithm first"


def test_wheel_guard_names_wheels_that_bundle_hdf5_or_proj(qgis_session, tmp_path,
                                                          monkeypatch) -> None:
    """A folder holding h5py with h5py.libs (as a PyPI wheel lays it out) is named before
    anything is imported; a package without its .libs folder (Debian's) is not."""
    from qgis_plugin import wheel_guard

    for name, libs in (("h5py", True), ("pyproj", False)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text("raise SystemExit('imported!')\n")
        if libs:
            (tmp_path / f"{name}.libs").mkdir()
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("h5py", "pyproj"):
        monkeypatch.delitem(__import__("sys").modules, name, raising=False)
    message = wheel_guard.wheel_problem(force=True)
    assert message is not None
    assert f"h5py in {tmp_path} bundles its own HDF5" in message
    assert "pyproj" not in message
    assert wheel_guard.wheel_problem() is None  # this process is Python, not QGIS
