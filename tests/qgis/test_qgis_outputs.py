"""Outputs: GEDI zips read as the HDF5 they hold; waveform plots of the footprints selected
on the map, each PNG declared as an output."""

from __future__ import annotations

import gc
from pathlib import Path

import pytest

pytestmark = pytest.mark.qgis

ROOT = Path(__file__).resolve().parents[2]
L1B_ZIP = ROOT / "tests" / "data" / "gedi" / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.zip"


def test_waveforms_of_the_selected_footprints_from_a_gedi_zip(run_alg, gedi_l1b,
                                                              tmp_path) -> None:
    import h5py
    from qgis.core import QgsProcessingFeatureSourceDefinition, QgsProject, QgsVectorLayer

    fp = run_alg("canopyblocks:gedifootprints", {"INPUT": str(L1B_ZIP), "BEAMS": "BEAM0101",
                                                 "OUTPUT": str(tmp_path / "fp.gpkg")})
    with h5py.File(gedi_l1b) as f:  # the same file, unzipped by the test fixture
        truth = sorted(int(s) for s in f["BEAM0101"]["shot_number"][:])
    layer = QgsVectorLayer(fp["OUTPUT"], "footprints", "ogr")
    assert layer.isValid()
    try:
        shots = sorted(int(f["shot_number"]) for f in layer.getFeatures())
        assert shots == truth  # the zip was read as the HDF5 it holds
        QgsProject.instance().addMapLayer(layer, False)
        chosen = [f for f in layer.getFeatures()][3:5]
        layer.selectByIds([f.id() for f in chosen])
        want = sorted(int(f["shot_number"]) for f in chosen)
        import processing
        from qgis.core import QgsProcessingContext, QgsProcessingFeedback

        context = QgsProcessingContext()
        context.setProject(QgsProject.instance())  # the map's layers, as in the dialog
        out = processing.run("canopyblocks:waveformplot", {
            "INPUT": str(L1B_ZIP), "SETTING": 0, "OUTPUT": str(tmp_path / "view.html"),
            "FOOTPRINTS": QgsProcessingFeatureSourceDefinition(layer.id(), True)},
            context=context, feedback=QgsProcessingFeedback())
        pngs = sorted(out["PLOTS"])
        assert pngs == sorted(str(tmp_path / f"view_{s}.png") for s in want)
        assert all(Path(p).stat().st_size > 10_000 for p in pngs)
        assert sorted(p.name for p in tmp_path.glob("view_*.png")) == \
            sorted(Path(p).name for p in pngs)  # every file written is declared
    finally:
        QgsProject.instance().removeMapLayer(layer.id())
        gc.collect()


def test_nothing_chosen_says_what_to_do(run_alg, tmp_path) -> None:
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="select them on the map"):
        run_alg("canopyblocks:waveformplot", {"INPUT": str(L1B_ZIP), "SETTING": 0,
                                              "OUTPUT": str(tmp_path / "v.html")})
