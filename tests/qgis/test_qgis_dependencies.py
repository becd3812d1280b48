"""A missing package is named with how to install it in QGIS's Python, before anything
runs; the pdal executable can be set on the provider's settings page."""

from __future__ import annotations

import sys

import pytest

pytestmark = pytest.mark.qgis


def _alg(alg_id: str):  # noqa: ANN202
    from qgis.core import QgsApplication

    alg = QgsApplication.processingRegistry().algorithmById(f"canopyblocks:{alg_id}")
    assert alg is not None
    return alg


@pytest.mark.parametrize("alg_id,module", [("blockheights", "geopandas"),
                                           ("gedifootprints", "h5py"),
                                           ("referencerasters", "laspy")])
def test_a_missing_package_is_named_with_its_install_command(qgis_session, monkeypatch,
                                                             alg_id, module) -> None:
    import processing
    from qgis.core import QgsProcessingContext, QgsProcessingException, QgsProcessingFeedback

    monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
    ok, msg = _alg(alg_id).canExecute()
    assert not ok
    assert module in msg and "install" in msg and "restart QGIS" in msg, msg
    assert "Settings > Options > System > Environment" in msg
    assert "matching canopyblocks version" not in msg
    with pytest.raises(QgsProcessingException) as err:
        processing.run(f"canopyblocks:{alg_id}", {"INPUT": "/nonexistent.h5"},
                       context=QgsProcessingContext(), feedback=QgsProcessingFeedback())
    assert "ModuleNotFoundError" not in str(err.value)


def test_install_commands_per_platform() -> None:
    from qgis_plugin.dependencies import install_command

    linux = install_command(["h5py", "geopandas"], "linux")
    assert "sudo apt install python3-h5py" in linux
    assert "/usr/bin/python3 -m pip install --user --break-system-packages " \
           "'geopandas>=1.0,<1.1'" in linux
    assert install_command(["laspy"], "win32").startswith("in the OSGeo4W Shell")
    assert "QGIS.app" in install_command(["laspy"], "darwin")


def test_pdal_path_on_the_provider_settings_page(qgis_session, pdal_bin, monkeypatch,
                                                 tmp_path) -> None:
    from processing.core.ProcessingConfig import ProcessingConfig
    from qgis_plugin.dependencies import PDAL_SETTING

    assert PDAL_SETTING in ProcessingConfig.settings  # the page lists it
    monkeypatch.delenv("CANOPYBLOCKS_PDAL", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))  # no pdal on PATH
    monkeypatch.setattr("canopyblocks.reference.pdal.DEFAULT_PDAL", tmp_path / "none")
    try:
        ProcessingConfig.setSettingValue(PDAL_SETTING, str(tmp_path))  # not an executable
        ok, msg = _alg("referencerasters").canExecute()
        assert not ok and "Settings > Options > Processing > Providers" in msg, msg
        ProcessingConfig.setSettingValue(PDAL_SETTING, pdal_bin)
        ok, msg = _alg("referencerasters").canExecute()
        assert ok, msg
    finally:
        ProcessingConfig.setSettingValue(PDAL_SETTING, "")
