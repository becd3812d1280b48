"""scripts/build_plugin.py writes a zip every user of a shared QGIS can read: the zip and
every file in it 0644, every folder 0755, whatever the umask and the checkout's modes
(no QGIS needed)."""

from __future__ import annotations

import importlib.util
import os
import shutil
import stat
import subprocess
import zipfile
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def build_plugin() -> ModuleType:
    """scripts/build_plugin.py as a module (scripts/ is no package)."""
    spec = importlib.util.spec_from_file_location("build_plugin_script",
                                                  ROOT / "scripts" / "build_plugin.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def private_plugin(tmp_path: Path) -> Path:
    """A copy of the plugin folder whose files are 0600 and folders 0700 (a checkout made
    under umask 077)."""
    plugin = tmp_path / "qgis_plugin"
    shutil.copytree(ROOT / "qgis_plugin", plugin,
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for p in [plugin, *plugin.rglob("*")]:
        p.chmod(0o700 if p.is_dir() else 0o600)
    return plugin


def test_zip_and_its_entries_are_world_readable_under_umask_077(build_plugin, tmp_path,
                                                                private_plugin):
    old = os.umask(0o077)
    try:
        path = build_plugin.build(tmp_path / "dist", plugin_dir=private_plugin)
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
    with zipfile.ZipFile(path) as zf:
        infos = zf.infolist()
    files = [i for i in infos if not i.is_dir()]
    folders = {i.filename for i in infos if i.is_dir()}
    assert len(files) == len(build_plugin.plugin_files(private_plugin)) + 2  # metadata, LICENSE
    for info in files:
        assert info.create_system == 3, info.filename
        assert info.external_attr >> 16 == stat.S_IFREG | 0o644, info.filename
    for info in infos:
        if info.is_dir():
            assert info.external_attr >> 16 == stat.S_IFDIR | 0o755, info.filename
    # every folder a file sits in has its own 0755 entry
    assert {f.filename.rsplit("/", 1)[0] + "/" for f in files} <= folders
    assert {"canopyblocks_qgis/", "canopyblocks_qgis/algorithms/"} <= folders


@pytest.mark.skipif(shutil.which("unzip") is None, reason="needs Info-ZIP's unzip")
def test_unzip_lists_rw_r_r_files_and_extracts_them_readable(build_plugin, tmp_path,
                                                             private_plugin):
    path = build_plugin.build(tmp_path / "dist", plugin_dir=private_plugin)
    listing = subprocess.run(["unzip", "-Z", str(path)], capture_output=True, text=True,
                             check=True).stdout.splitlines()
    entries = [line for line in listing if " canopyblocks_qgis/" in line]
    assert entries
    for line in entries:
        mode = line.split()[0]
        want = "drwxr-xr-x" if line.endswith("/") else "-rw-r--r--"
        assert mode == want, line
    out = tmp_path / "plugins"
    subprocess.run(["unzip", "-q", str(path), "-d", str(out)], check=True)
    extracted = list((out / "canopyblocks_qgis").rglob("*"))
    assert extracted
    for p in extracted:
        want = 0o755 if p.is_dir() else 0o644
        assert stat.S_IMODE(p.stat().st_mode) & want == want, p
