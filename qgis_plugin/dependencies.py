"""What each algorithm needs in QGIS's Python, checked when it starts (and when its dialog
opens), and the PDAL path from the provider's settings page.

A missing package is named with the command that installs it into the Python QGIS runs
(not a shell's other Python), so a user never meets a raw ``ModuleNotFoundError``.
Nothing here imports the packages: ``importlib.util.find_spec`` only looks for them.
"""

from __future__ import annotations

import importlib.util
import os
import sys

__all__ = ["NEEDS", "missing_packages", "dependency_problem", "install_command",
           "PDAL_SETTING", "pdal_setting", "apply_pdal_setting"]

_BASE = ("numpy", "pandas", "pyproj", "shapely", "geopandas", "canopyblocks")
_HDF5 = ("h5py",)
_RASTER = ("rasterio", "scipy")
_LAS = ("laspy", "lazrs")

#: The Python modules each algorithm imports when it runs (its optional outputs aside).
NEEDS: dict[str, tuple[str, ...]] = {
    "blockheights": _BASE + _HDF5 + ("scipy",),
    "corridor": _BASE,
    "referencerasters": _BASE + _RASTER + _LAS,
    "validate": _BASE + _RASTER,
    "aspecterrors": _BASE,
    "calibrate": _BASE + _HDF5 + _RASTER,
    "coregister": _BASE + _HDF5 + _RASTER,
    "simulate": _BASE + _HDF5 + _LAS + ("scipy",),
    "simulatewaveforms": _BASE + _HDF5 + _LAS + ("scipy",),
    "gedifootprints": _BASE + _HDF5 + ("scipy",),
    "flashdualfootprints": _BASE + _HDF5 + ("scipy",),
    "footprintvalidation": _BASE + _LAS + ("scipy",),
    "waveformplot": _BASE + _HDF5 + ("scipy", "matplotlib"),
}

#: module -> (Debian package, pip requirement); pip for what Debian lacks or has too old
_PACKAGES: dict[str, tuple[str | None, str]] = {
    "numpy": ("python3-numpy", "numpy<2"),
    "pandas": ("python3-pandas", "pandas"),
    "pyproj": ("python3-pyproj", "pyproj"),
    "scipy": ("python3-scipy", "scipy"),
    "h5py": ("python3-h5py", "h5py"),
    "rasterio": ("python3-rasterio", "rasterio"),
    "matplotlib": ("python3-matplotlib", "matplotlib"),
    "shapely": (None, "shapely>=2.0,<2.1"),
    "geopandas": (None, "geopandas>=1.0,<1.1"),
    "laspy": (None, "laspy"),
    "lazrs": (None, "lazrs"),
    "canopyblocks": (None, "canopyblocks"),
}


def _importable(module: str) -> bool:
    if module in sys.modules:
        return sys.modules[module] is not None
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def missing_packages(alg_id: str) -> list[str]:
    """The modules algorithm ``alg_id`` needs that QGIS's Python cannot import."""
    return [m for m in NEEDS.get(alg_id, _BASE) if not _importable(m)]


def install_command(modules: list[str], platform: str | None = None) -> str:
    """The command that installs ``modules`` into the Python QGIS runs, on this platform."""
    plat = platform or sys.platform
    reqs = [_PACKAGES.get(m, (None, m))[1] for m in modules]
    quoted = " ".join(f"'{r}'" if any(c in r for c in "<>=,") else r for r in reqs)
    if plat.startswith("linux"):
        debs = [d for d, _ in (_PACKAGES.get(m, (None, m)) for m in modules) if d]
        pips = [f"'{p}'" if any(c in p for c in "<>=,") else p
                for d, p in (_PACKAGES.get(m, (None, m)) for m in modules) if not d]
        parts = []
        if debs:
            parts.append("sudo apt install " + " ".join(debs))
        if pips:
            parts.append("/usr/bin/python3 -m pip install --user --break-system-packages "
                         + " ".join(pips))
        return " and ".join(parts)
    if plat == "darwin":
        return f"/Applications/QGIS.app/Contents/MacOS/bin/python3 -m pip install {quoted}"
    return f"in the OSGeo4W Shell (Start menu): python -m pip install {quoted}"


def dependency_problem(alg_id: str, display_name: str) -> str | None:
    """None when everything ``alg_id`` needs is importable; else one message naming the
    missing packages and how to install them in QGIS's Python."""
    missing = missing_packages(alg_id)
    if not missing:
        return None
    from .venv_guard import venv_cause

    cause = venv_cause()
    if cause is not None:  # not a package to install: the shell's virtualenv hides them
        return f"{display_name}: {cause}"
    env_note = ("(A package installed elsewhere can be made visible with Settings > Options > "
                "System > Environment: PYTHONPATH, 'Append', its folder.)")
    if "canopyblocks" in missing:  # the core itself: its own, fuller instructions

        return (f"{display_name} needs the canopyblocks library, which the Python that runs "
                f"QGIS cannot import; {install_hint()}. {env_note}")
    what = ", ".join(missing)
    s = "s" if len(missing) > 1 else ""
    return (f"{display_name} needs the Python package{s} {what}, which the Python that runs "
            f"QGIS cannot import. Install {'them' if s else 'it'}: {install_command(missing)}; "
            "then restart QGIS. " + env_note)


#: The Processing setting (Settings > Options > Processing > Providers > canopyblocks).
PDAL_SETTING = "CANOPYBLOCKS_PDAL_PATH"


def pdal_setting() -> str:
    """The pdal executable set on the provider's settings page ("" when not set)."""
    try:
        from processing.core.ProcessingConfig import ProcessingConfig
    except ImportError:  # pragma: no cover - Processing is part of every QGIS
        return ""
    value = ProcessingConfig.getSetting(PDAL_SETTING)
    return str(value).strip() if value else ""


def apply_pdal_setting() -> None:
    """Let the core find the pdal executable the user set (the core reads
    ``CANOPYBLOCKS_PDAL``); an unset setting leaves the environment alone."""
    value = pdal_setting()
    if value:
        os.environ["CANOPYBLOCKS_PDAL"] = value


def install_hint() -> str:
    """How to install the core into the Python that runs QGIS (platform-specific)."""
    if sys.platform.startswith("linux"):
        cmd = (
            "/usr/bin/python3 -m pip install --user --break-system-packages --no-deps "
            "canopyblocks (or a source checkout), with Debian's python3-h5py python3-pyproj "
            "python3-rasterio python3-scipy python3-pandas python3-matplotlib and pip's "
            "'shapely>=2.0,<2.1' 'geopandas>=1.0,<1.1' (scripts/install_qgis.sh sets this up in "
            "/opt/canopyblocks-qgis-python: start QGIS with PYTHONPATH=/opt/canopyblocks-qgis-"
            "python:<checkout>/core)"
        )
    elif sys.platform == "darwin":
        cmd = "the QGIS app's python3 -m pip install 'canopyblocks[all]'"
    else:
        cmd = "python3 -m pip install canopyblocks[all]  (in the OSGeo4W shell)"
    return "install canopyblocks into QGIS's Python: " + cmd + ", then restart QGIS"
