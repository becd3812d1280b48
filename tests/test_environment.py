"""The environment the README's commands make is the locked one, and nothing else.

`scripts/setup_env.sh` makes `.venv` from one lock (`scripts/lock/demo.txt` or `test.txt`) and
writes which into `.venv/canopyblocks-lock.txt`; these tests check, in that venv, that every
installed package is at its locked version, that no Debian Python package can be imported
beside them (QGIS's bindings excepted, through `scripts/qgis_bindings.py`), and that the
command line starts without a word on stderr.  In another environment (the minimum- and
newest-versions jobs) the lock checks skip.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STAMP = Path(sys.prefix) / "canopyblocks-lock.txt"
DEBIAN = "/usr/lib/python3/dist-packages"
QGIS_BINDINGS = {"qgis", "PyQt5", "osgeo", "osgeo_utils", "psycopg2"}


def _lock() -> Path:
    if not STAMP.is_file():
        pytest.skip("not the venv scripts/setup_env.sh makes (no lock stamp)")
    return ROOT / STAMP.read_text().split()[1]


def _pins(lock: Path) -> dict[str, str]:
    pins = {}
    for line in lock.read_text().splitlines():
        line = line.split("#")[0].strip()
        if "==" in line:
            name, ver = line.split("==")
            pins[name.split("[")[0].strip().lower().replace("_", "-")] = ver.split(";")[0].strip()
    return pins


def test_every_installed_package_is_at_its_locked_version() -> None:
    pins = _pins(_lock())
    assert len(pins) > 100
    installed = {d.metadata["Name"].lower().replace("_", "-"): d.version
                 for d in importlib.metadata.distributions(path=[p for p in sys.path
                                                                 if "site-packages" in p])}
    installed.pop("canopyblocks", None)
    installed.pop("pip", None)
    wrong = {n: (v, pins.get(n)) for n, v in installed.items() if pins.get(n) != v}
    missing = sorted(set(pins) - set(installed))
    assert not wrong, f"installed, locked: {wrong}"
    assert not missing, f"locked but not installed: {missing}"


def test_no_debian_package_on_the_path() -> None:
    _lock()
    assert DEBIAN not in sys.path
    extra = [p for p in sys.path if p.endswith("qgis-bindings")]
    for folder in extra:  # only QGIS's own bindings, linked one by one
        names = {q.name.split("-")[0].split("_sip")[0] for q in Path(folder).iterdir()}
        assert names <= QGIS_BINDINGS, names


def test_the_package_imports_nothing_from_debian() -> None:
    """Every canopyblocks module and the optional parts it reaches (object storage, plots,
    compiled loops, Dask) load from the venv or the standard library only."""
    _lock()
    import canopyblocks

    for mod in pkgutil.walk_packages(canopyblocks.__path__, "canopyblocks."):
        importlib.import_module(mod.name)
    for name in ("boto3", "botocore.httpsession", "s3fs", "aiohttp", "matplotlib.pyplot",
                 "rasterio", "laspy", "numba", "distributed", "requests"):
        importlib.import_module(name)
    foreign = sorted(n for n, m in sys.modules.items()
                     if (getattr(m, "__file__", None) or "").startswith(DEBIAN))
    assert not foreign, foreign


def test_the_command_line_starts_silently() -> None:
    """No foreign warning (OpenSSL's DSA deprecation, requests' dependency check) on stderr."""
    _lock()
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHONWARNINGS")}
    for args in (["--help"], ["info", "--help"], ["batch", "--help"]):
        res = subprocess.run([sys.executable, "-m", "canopyblocks", *args], env=env,
                             capture_output=True, text=True, timeout=120, check=False)
        assert res.returncode == 0, res.stderr
        assert res.stderr == "", res.stderr
