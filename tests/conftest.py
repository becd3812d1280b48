"""Shared fixtures: real sample data, and dependency gates that fail under CI=true."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEST_DATA = ROOT / "tests" / "data"
SHARED_DATA = ROOT.parent / "shared" / "data"
IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


def _qgis_importable() -> bool:
    try:
        import qgis.core  # noqa: F401
        import qgis.gui  # noqa: F401
    except Exception:  # noqa: BLE001 - any failure (missing, broken libs) means "no QGIS"
        return False
    return True


HAVE_QGIS = _qgis_importable()
# pytest-qgis imports QGIS at load time, so it is disabled in pyproject (-p no:pytest_qgis)
# and loaded here only where QGIS works; tests/qgis/ gates on HAVE_QGIS (fails under CI=true).
pytest_plugins = ["pytest_qgis.plugin"] if HAVE_QGIS else []


def pytest_addoption(parser: pytest.Parser) -> None:
    if not HAVE_QGIS:  # pytest-qgis not loaded: keep its ini key known
        parser.addini("qgis_gui_enabled", "pytest-qgis setting (not loaded: no QGIS)",
                      type="bool", default=False)


def require(available: bool, what: str, how: str) -> None:
    """Skip when ``what`` is missing on a user's machine; fail under ``CI=true``."""
    if available:
        return
    msg = f"{what} is not available ({how})"
    if IN_CI:
        pytest.fail(f"CI=true: {msg}; a missing dependency is a failure in CI", pytrace=False)
    pytest.skip(msg)


def data_file(relpath: str) -> Path:
    """A sample file: ``tests/data/<relpath>`` if bundled, else ``../shared/data/<relpath>``.

    Bundled copies keep their provenance in ``tests/data/PROVENANCE.md``.
    """
    for base in (TEST_DATA, SHARED_DATA):
        p = base / relpath
        if p.exists():
            return p
    require(False, f"sample file {relpath}", "not in tests/data nor ../shared/data")
    raise AssertionError("unreachable")


@pytest.fixture(scope="session")
def sample() -> object:
    """``sample("icesat2/vegr_atl03_clip.h5") -> Path``."""
    return data_file


def pdal_executable() -> str | None:
    """The pdal wrapper the project installs, or one on PATH."""
    env = os.environ.get("CANOPYBLOCKS_PDAL")
    if env and Path(env).exists():
        return env
    try:
        from canopyblocks.reference.pdal import find_pdal  # type: ignore[attr-defined]
    except ImportError:
        find_pdal = None
    if find_pdal is not None:
        try:
            return str(find_pdal())
        except Exception:  # noqa: BLE001 - any failure means "not available"
            return None
    return shutil.which("pdal")


@pytest.fixture(scope="session")
def pdal_bin() -> str:
    """Path of a working ``pdal``; skips (fails under CI) when missing."""
    exe = pdal_executable()
    require(exe is not None, "the pdal command line", "run: bash scripts/install_pdal.sh")
    return str(exe)


def _unzipped(relpath: str, dest: Path) -> Path:
    """Extract the one HDF5 file of the zip ``relpath`` (see :func:`data_file`) into ``dest``."""
    import zipfile

    with zipfile.ZipFile(data_file(relpath)) as zf:
        names = [n for n in zf.namelist() if n.endswith(".h5")]
        assert len(names) == 1, f"{relpath}: expected one .h5 inside, got {names}"
        return Path(zf.extract(names[0], dest))


@pytest.fixture(scope="session")
def gedi_l1b(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The real GEDI L1B subset (7 beams, ~300 shots; tests/data/gedi, unzipped once)."""
    return _unzipped("gedi/GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.zip",
                     tmp_path_factory.mktemp("gedi_l1b"))


@pytest.fixture(scope="session")
def gedi_l2a(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The real GEDI L2A subset of the same shots as :func:`gedi_l1b` (unzipped once)."""
    return _unzipped("gedi/GEDI02_A_2019108080338_O01964_T05337_02_001_01_sub.zip",
                     tmp_path_factory.mktemp("gedi_l2a"))
