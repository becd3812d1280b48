"""Keep a shell's activated virtualenv out of QGIS's Python, or say what to do.

Started from a shell where a virtualenv is active (as the README's command-line section has
users do), QGIS makes that virtualenv its embedded Python's prefix (measured: ``sys.prefix``
and ``sys.executable`` point into ``$VIRTUAL_ENV``, its site-packages are on ``sys.path`` and
numpy is imported from it before any plugin loads).  PyPI wheels there (h5py, shapely >=
2.1, rasterio, pyproj) bundle their own HDF5/GEOS/PROJ and crash against the copies QGIS
has loaded ("Not a datatype", then ``double free or corruption``).  That cannot be undone
from a plugin, so every algorithm refuses with one message that says what to do
(:func:`venv_problem`); the virtualenv's folders are also taken off ``sys.path`` at plugin
load (:func:`scrub_venv`) so nothing more is imported from it.  Python processes that embed
QGIS from the virtualenv itself (the test suite) are not affected: the process must be the
QGIS application (``qgis``, ``qgis_process``) for the guard to act.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["in_qgis_application", "scrub_venv", "venv_cause", "venv_problem", "VENV_ADVICE"]

VENV_ADVICE = (
    "run `deactivate` in that shell (QGIS takes the first python3 on PATH and its "
    "virtualenv), then start QGIS again as `PYTHONPATH=/opt/canopyblocks-qgis-python:"
    "<checkout>/core qgis` (the runtime of scripts/install_qgis.sh)")

_removed: list[str] = []


def in_qgis_application() -> bool:
    """The process is the QGIS application or qgis_process (not a Python embedding QGIS)."""
    try:
        exe = Path(os.path.realpath("/proc/self/exe")).name.lower()
    except OSError:
        exe = Path(sys.argv[0] if sys.argv and sys.argv[0] else "").name.lower()
    return exe.startswith("qgis")


def _venv() -> Path | None:
    """The virtualenv QGIS's Python runs in: ``$VIRTUAL_ENV``, or the prefix QGIS took from
    a venv's ``python3`` first on ``PATH`` (measured: that alone is enough)."""
    if not in_qgis_application():
        return None
    v = os.environ.get("VIRTUAL_ENV")
    if v:
        return Path(v).resolve()
    if Path(sys.prefix).resolve() != Path(sys.base_prefix).resolve():
        return Path(sys.prefix).resolve()
    return None


def _inside(path: str, root: Path) -> bool:
    try:
        return Path(path).resolve().is_relative_to(root)
    except (OSError, ValueError):
        return False


def scrub_venv() -> list[str]:
    """Remove the active virtualenv's folders from ``sys.path``; return what was removed."""
    root = _venv()
    if root is None:
        return []
    gone = [p for p in sys.path if p and _inside(p, root)]
    sys.path[:] = [p for p in sys.path if p not in gone]
    # QGIS's own Python keeps its packages in the base interpreter's site folders, which a
    # virtualenv without system packages hides (Processing itself then fails to import yaml)
    import site

    sys.path.extend(p for p in site.getsitepackages([sys.base_prefix])
                    if p not in sys.path and Path(p).is_dir())
    _removed.extend(gone)
    return gone


def venv_cause() -> str | None:
    """When QGIS runs inside a shell's virtualenv, the message naming it (the real cause of
    any package QGIS's Python then cannot import: a virtualenv hides the system's packages);
    None otherwise."""
    root = _venv()
    if root is None:
        return None
    return (f"QGIS was started from a shell with the virtualenv {root} active (or its bin "
            f"first on PATH), so its Python cannot see the packages QGIS's own Python has; "
            f"{VENV_ADVICE}")


def venv_problem() -> str | None:
    """A message when modules were already imported from the active virtualenv, else None."""
    root = _venv()
    if root is None:
        return None
    loaded = sorted({name.split(".")[0] for name, mod in list(sys.modules.items())
                     if getattr(mod, "__file__", None) and _inside(str(mod.__file__), root)})
    if not loaded:
        return None
    return (f"QGIS was started from a shell with the virtualenv {root} active (or its bin "
            f"first on PATH) and has loaded "
            f"its packages ({', '.join(loaded[:8])}), whose compiled libraries clash with "
            f"QGIS's own; {VENV_ADVICE}")
