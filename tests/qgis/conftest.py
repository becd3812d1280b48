"""Headless QGIS for the plugin tests (no pytest-qgis needed).

QGIS is started once per session, only when a test asks for it: on a machine without
QGIS these tests skip (and FAIL under CI=true, through tests/conftest.py's ``require``);
the rest of the suite never imports ``qgis``.  Every layer a test opens goes through the
``open_layer`` fixture so it is deleted before ``exitQgis()`` (QGIS segfaults at exit
otherwise).
"""

from __future__ import annotations

import gc
import importlib.util
import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
QGIS_PLUGINS = "/usr/share/qgis/python/plugins"  # Debian's home of the `processing` package
INSTALL_HOW = "run: bash scripts/install_qgis.sh"


def _root_conftest() -> Any:
    """tests/conftest.py as a module (its ``require`` and ``data_file``)."""
    name = "_canopyblocks_tests_root_conftest"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, ROOT / "tests" / "conftest.py")
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


require: Callable[[bool, str, str], None] = _root_conftest().require


def qgis_importable() -> bool:
    """True when ``import qgis.core`` works in this Python."""
    if importlib.util.find_spec("qgis") is None:
        return False
    try:
        import qgis.core  # noqa: F401
    except ImportError:
        return False
    return True


def qgis_process_exe() -> str | None:
    """The ``qgis_process`` command (Debian package ``qgis``), or None."""
    return shutil.which("qgis_process")


@pytest.fixture(scope="session")
def qgis_session() -> Iterator[Any]:
    """A headless QgsApplication with Processing initialised and the plugin's provider added.

    Reuses an application someone else (e.g. pytest-qgis) started, and then leaves its
    shutdown to them.
    """
    require(qgis_importable(), "QGIS Python bindings (qgis.core)", INSTALL_HOW)
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from qgis.core import QgsApplication

    own = QgsApplication.instance() is None
    app = QgsApplication([], False) if own else QgsApplication.instance()
    if own:
        app.initQgis()
    if QGIS_PLUGINS not in sys.path:
        sys.path.append(QGIS_PLUGINS)
    from processing.core.Processing import Processing

    Processing.initialize()
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from qgis_plugin.plugin import CanopyBlocksPlugin

    plugin = CanopyBlocksPlugin(None)
    plugin.initProcessing()
    yield app
    plugin.unload()
    gc.collect()
    if own:
        app.exitQgis()


@pytest.fixture
def open_layer(qgis_session: Any) -> Iterator[Callable[..., Any]]:
    """``open_layer(path_or_uri, kind="vector"|"raster") -> layer``; layers deleted after."""
    from qgis.core import QgsRasterLayer, QgsVectorLayer

    opened: list[Any] = []

    def _open(uri: str | os.PathLike[str], kind: str = "vector") -> Any:
        layer = (QgsVectorLayer(str(uri), "t", "ogr") if kind == "vector"
                 else QgsRasterLayer(str(uri), "t"))
        assert layer.isValid(), f"QGIS cannot open {uri}"
        opened.append(layer)
        return layer

    yield _open
    opened.clear()
    gc.collect()


@pytest.fixture
def run_alg(qgis_session: Any) -> Callable[..., dict[str, Any]]:
    """``run_alg("canopyblocks:corridor", {...}, feedback=None) -> results`` (processing.run)."""
    import processing
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback

    def _run(alg_id: str, params: dict[str, Any], feedback: Any = None) -> dict[str, Any]:
        context = QgsProcessingContext()
        return processing.run(alg_id, params, context=context,
                              feedback=feedback or QgsProcessingFeedback())

    return _run


@pytest.fixture(scope="session")
def atl03_sample() -> Path:
    """The real ATL03 clip (beam gt1r, 6,809 photons, Wyoming conifer forest)."""
    return _root_conftest().data_file("icesat2/vegr_atl03_clip.h5")


def _layer_rows(layer: Any) -> list[dict[str, Any]]:
    from qgis.core import QgsWkbTypes

    rows = []
    names = [f.name() for f in layer.fields()]
    for feat in layer.getFeatures():
        vals = [None if (v is None or (hasattr(v, "isNull") and v.isNull())) else v
                for v in feat.attributes()]
        row = dict(zip(names, vals))
        g = feat.geometry()
        row["_wkt"] = g.asWkt()
        row["_area"] = g.area()
        if not g.isNull() and g.type() == QgsWkbTypes.PointGeometry:
            p = g.asPoint()
            row["_xy"] = (p.x(), p.y())
        rows.append(row)
    return rows


@pytest.fixture
def layer_rows(qgis_session: Any) -> Callable[[Any], list[dict[str, Any]]]:
    """``layer_rows(layer)``: attributes per feature as dicts (NULL -> None), plus
    ``_wkt``, ``_area`` and, for points, ``_xy``."""
    return _layer_rows


# ---- the real qgis_process with the README's runtime ----------------------------------------

RUNTIME = Path(os.environ.get("CANOPYBLOCKS_QGIS_RUNTIME", "/opt/canopyblocks-qgis-python"))


def _env(profile: Path, core_on_path: bool = True,
         runtime: Path | None = None) -> dict[str, str]:
    """qgis_process embeds Debian's Python: the plugin runtime (scripts/install_qgis.sh) and
    the core source go on its PYTHONPATH (never the venv's wheels: see install_qgis.sh)."""
    env = dict(os.environ)
    env["QT_QPA_PLATFORM"] = "offscreen"
    env["QGIS_CUSTOM_CONFIG_PATH"] = str(profile)
    paths = [str(runtime or RUNTIME)] + ([str(ROOT / "core")] if core_on_path else [])
    env["PYTHONPATH"] = os.pathsep.join(paths)
    env.pop("PYTHONHOME", None)
    for var in ("LD_LIBRARY_PATH", "GDAL_DATA", "PROJ_LIB", "PDAL_DRIVER_PATH"):
        env.pop(var, None)
    return env


@pytest.fixture(scope="session")
def built_zip(tmp_path_factory) -> Path:
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import build_plugin
    finally:
        sys.path.remove(str(ROOT / "scripts"))
    return build_plugin.build(tmp_path_factory.mktemp("dist"))


@pytest.fixture(scope="session")
def qgis_profile(built_zip, tmp_path_factory) -> Path:
    """A clean QGIS profile folder with the BUILT zip unpacked and the plugin enabled."""
    import zipfile

    require(qgis_process_exe() is not None, "the qgis_process command line",
            "run: bash scripts/install_qgis.sh (package 'qgis')")
    require((RUNTIME / "geopandas").is_dir() and (RUNTIME / "laspy").is_dir(),
            f"the QGIS-side runtime in {RUNTIME}", "run: bash scripts/install_qgis.sh")
    profile = tmp_path_factory.mktemp("qgisprofile")
    plugins = profile / "profiles" / "default" / "python" / "plugins"
    plugins.mkdir(parents=True)
    with zipfile.ZipFile(built_zip) as zf:
        zf.extractall(plugins)
    r = subprocess.run(["qgis_process", "plugins", "enable", "canopyblocks_qgis"],
                       env=_env(profile), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    return profile


@pytest.fixture(scope="session")
def qgis_process_env() -> Callable[..., dict[str, str]]:
    """``env(profile, core_on_path=True)``: the environment the README documents for
    ``qgis_process`` (the plugin runtime and the checkout's core on PYTHONPATH, no venv)."""
    return _env
