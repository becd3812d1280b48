"""Show Debian's QGIS bindings, and nothing else of Debian's Python, to the project's venv.

Usage (with Debian's Python, the one QGIS is built for): ``/usr/bin/python3
scripts/qgis_bindings.py .venv``.

The venv is made without ``--system-site-packages``, so the command line never imports a
Debian package (pyOpenSSL, requests, chardet, matplotlib, ... pulled in by QGIS) beside the
locked ones.  The QGIS tests run QGIS in-process, so they need QGIS's own Python packages,
which only Debian has: ``qgis`` and ``PyQt5`` (with its ``sip``), ``osgeo``/``osgeo_utils``
(the GDAL provider of Processing) and ``psycopg2`` (its PostGIS tools).  This script links
exactly those into ``VENV/qgis-bindings/`` and adds that folder to the venv's path with one
``.pth`` file (after the venv's own packages, so a locked package always wins).  Without QGIS
it removes both.  Everything else QGIS imports (numpy, yaml, ...) comes from the lock.
"""

from __future__ import annotations

import sys
from pathlib import Path

DIST = Path("/usr/lib/python3/dist-packages")
NAMES = ("qgis", "PyQt5", "osgeo", "osgeo_utils", "psycopg2")
PTH = "canopyblocks-qgis-bindings.pth"


def _site_packages(venv: Path) -> Path:
    found = sorted((venv / "lib").glob("python3*/site-packages"))
    if not found:
        raise SystemExit(f"qgis_bindings.py: {venv} is not a venv (no lib/python3*/site-packages)")
    return found[0]


def _entries() -> list[Path]:
    """The bindings' folders and their metadata folders, [] when QGIS is not installed."""
    if not (DIST / "qgis" / "core").is_dir():
        return []
    out = []
    for name in NAMES:
        out += [p for p in DIST.glob(f"{name}*")
                if p.name == name or p.name.startswith((f"{name}-", f"{name}_sip-"))]
    return sorted(out)


def main(venv_arg: str) -> int:
    venv = Path(venv_arg).resolve()
    pth = _site_packages(venv) / PTH
    folder = venv / "qgis-bindings"
    entries = _entries()
    if folder.is_dir():
        for old in folder.iterdir():
            old.unlink()
    if not entries:
        pth.unlink(missing_ok=True)
        if folder.is_dir():
            folder.rmdir()
        return 0
    folder.mkdir(exist_ok=True)
    for src in entries:
        (folder / src.name).symlink_to(src)
    pth.write_text(f"{folder}\n")
    print(f"canopyblocks: QGIS bindings visible to {venv} "
          f"({', '.join(n for n in NAMES if (folder / n).exists())})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python3 scripts/qgis_bindings.py VENV")
    raise SystemExit(main(sys.argv[1]))
