"""Refuse, before importing them, PyPI wheels that crash inside the QGIS application.

A manylinux wheel ships its compiled libraries in a ``<package>.libs`` folder beside the
package.  Inside ``qgis``/``qgis_process`` the libraries QGIS has already loaded win over the
wheel's copies.  Measured with QGIS 3.40 on Debian 12 (one package at a time on the plugin's
``PYTHONPATH``, the rest from ``/opt/canopyblocks-qgis-python``):

- h5py (bundled HDF5): ``ValueError: Not a datatype``, then ``double free or corruption`` at
  exit -- exit status -6, and on a loaded machine a process that never ends;
- pyproj (bundled PROJ): ``double free or corruption`` with no Python error at all;
- rasterio (bundled GDAL) and shapely 2.0 (bundled GEOS): work.

Once such a library is loaded nothing can be undone, so the check looks at the files only
(``importlib.util.find_spec`` of the top-level package does not execute it) and runs before the
core is imported.  Python processes that embed QGIS (the test suite's virtualenv) are not
concerned: the check acts only in the QGIS application itself.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

from .venv_guard import in_qgis_application

__all__ = ["CLASHING_WHEELS", "wheel_problem"]

#: package -> the library its PyPI wheel bundles that clashes with QGIS's own copy.
CLASHING_WHEELS = {"h5py": "HDF5", "pyproj": "PROJ"}


def bundled_wheel(package: str) -> Path | None:
    """The package's folder when it is a wheel with its own ``<package>.libs``, else None."""
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin:
        return None
    folder = Path(spec.origin).parent
    return folder if (folder.parent / f"{package}.libs").is_dir() else None


def wheel_problem(force: bool = False) -> str | None:
    """A message naming the wheels that would crash this QGIS process, else None.

    Parameters
    ----------
    force
        Check even outside the QGIS application (for tests).
    """
    if not (force or in_qgis_application()):
        return None
    found = [(name, lib, folder) for name, lib in CLASHING_WHEELS.items()
             if name not in sys.modules and (folder := bundled_wheel(name)) is not None]
    if not found:
        return None
    names = "; ".join(f"{name} in {folder.parent} bundles its own {lib}"
                      for name, lib, folder in found)
    return (f"canopyblocks: a compiled library would clash with QGIS's own ({names}; inside "
            "QGIS it crashes the process), so nothing was run; the Python packages seen by "
            "QGIS must be built on QGIS's GEOS/PROJ/GDAL/HDF5: take that folder off "
            "PYTHONPATH")
