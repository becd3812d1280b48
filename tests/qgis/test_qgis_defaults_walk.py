"""The QGIS algorithms share the CLI's defaults: the recommended estimators (atl08) and the
corridor width of the photons' sensor; GEDI footprints carry time_utc; GeoPackages written
by the command line open in QGIS's GDAL without a version warning."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.qgis]

ROOT = Path(__file__).resolve().parents[2]
ATL08_LABEL = "noise=atl08,ground=atl08,top=atl08"


def _algorithms(qgis_session):  # noqa: ANN001, ANN202
    from qgis.core import QgsApplication

    return [a for a in QgsApplication.processingRegistry().algorithms()
            if a.provider() is not None and a.provider().id() == "canopyblocks"]


def test_every_estimator_parameter_defaults_to_atl08(qgis_session) -> None:
    from qgis.core import QgsProcessingParameterDefinition, QgsProcessingParameterEnum

    from canopyblocks.cli.common import PRESET_CHOICES

    seen, widths = set(), set()
    for alg in _algorithms(qgis_session):
        for p in alg.parameterDefinitions():
            if isinstance(p, QgsProcessingParameterEnum) and \
                    any(o.startswith("paper") for o in p.options()):
                seen.add(alg.name())
                assert p.options()[int(p.defaultValue())].startswith("atl08"), alg.name()
                names = [o.split(":")[0].split(" ")[0] for o in p.options()]
                assert names == list(PRESET_CHOICES), (alg.name(), names)
                assert any("the paper's method" in o for o in p.options())
            if p.name() == "WIDTH":
                widths.add(alg.name())
                assert p.defaultValue() is None, (alg.name(), p.defaultValue())
                assert p.flags() & QgsProcessingParameterDefinition.FlagOptional
    assert {"blockheights", "calibrate"} <= seen, seen
    assert {"validate", "calibrate", "corridor"} <= widths, widths


def test_block_heights_with_its_defaults_are_atl08(run_alg, open_layer, layer_rows,
                                                   atl03_sample, tmp_path) -> None:
    out = tmp_path / "blocks.gpkg"
    res = run_alg("canopyblocks:blockheights", {"INPUT": str(atl03_sample), "TRACK": "gt1r",
                                                "LENGTHS": "25", "OUTPUT": str(out)})
    rows = layer_rows(open_layer(res["OUTPUT"]))
    assert rows and {r["estimators"] for r in rows} == {ATL08_LABEL}
    # the corridor of an ICESat-2 beam without a width: the 13 m footprint
    cor = run_alg("canopyblocks:corridor", {"INPUT": res["OUTPUT"],
                                            "OUTPUT": str(tmp_path / "c.gpkg")})
    areas = sorted(r["_area"] for r in layer_rows(open_layer(cor["OUTPUT"])))
    assert areas[len(areas) // 2] == pytest.approx(13.0 * 25.0, rel=0.02)


def test_simulated_gedi_footprints_carry_time_utc(run_alg, open_layer, sample,
                                                  tmp_path) -> None:
    """time_utc is a field of the layer for simulated files too (empty: their clock
    starts at the first shot), as in the command line's layer."""
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import line_through
    from canopyblocks.simulate.sensor_files import simulate_gedi_to_file
    from canopyblocks.workflows.waveforms import footprints_from_l1b

    pts = read_las([sample("als/lasR_bcts_1.laz")])
    sim = tmp_path / "sim.h5"
    simulate_gedi_to_file(pts, line_through(pts.bounds, 10.0, inset=17), sim, seed=1)
    fp = run_alg("canopyblocks:gedifootprints", {"INPUT": str(sim),
                                                  "OUTPUT": str(tmp_path / "fp.gpkg")})
    layer = open_layer(fp["OUTPUT"])
    names = [f.name() for f in layer.fields()]
    cli_names = list(footprints_from_l1b(sim)[0].columns)
    assert "time_utc" in names and "time_utc" in cli_names


def test_cli_geopackage_opens_in_qgis_gdal_without_a_warning(qgis_session, open_layer,
                                                            atl03_sample, tmp_path) -> None:
    from osgeo import gdal

    out = tmp_path / "blocks.gpkg"
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "-q", "blocks",
                        str(atl03_sample), "--length", "25", "--photon-layer", "-o", str(out)],
                       capture_output=True, text=True, timeout=300,
                       env={"PYTHONPATH": str(ROOT / "core"), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    messages: list[str] = []

    def handler(cls: int, num: int, msg: str) -> None:
        messages.append(msg)

    gdal.PushErrorHandler(handler)
    try:
        ds = gdal.OpenEx(str(out), gdal.OF_VECTOR)
        assert ds is not None and ds.GetLayerCount() == 2
        ds = None
    finally:
        gdal.PopErrorHandler()
    assert not [m for m in messages if "partially supported" in m], messages
    layer = open_layer(out)
    assert layer.isValid() and layer.featureCount() > 0
