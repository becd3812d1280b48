"""scripts/build_plugin.py: the zip layout and the version check (no QGIS needed)."""

from __future__ import annotations

import configparser
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def build_plugin():
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import build_plugin as mod
    finally:
        sys.path.remove(str(ROOT / "scripts"))
    return mod


def test_zip_holds_plugin_folder_and_metadata(build_plugin, tmp_path):
    import canopyblocks

    path = build_plugin.build(tmp_path)
    assert path.name == f"canopyblocks_qgis-{canopyblocks.__version__}.zip"
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        meta = zf.read("canopyblocks_qgis/metadata.txt").decode()
        licence = zf.read("canopyblocks_qgis/LICENSE").decode()
    # the plugin repository rejects a zip without its licence: the GPL the metadata names
    assert licence == (ROOT / "LICENSE").read_text()
    assert licence.lstrip().startswith("GNU GENERAL PUBLIC LICENSE") and "Version 3" in licence
    assert {n.split("/")[0] for n in names} == {"canopyblocks_qgis"}
    for f in ("__init__.py", "plugin.py", "provider.py", "core_bridge.py", "layers.py",
              "styles.py", "icons/canopyblocks.svg", "algorithms/blockheights.py",
              "algorithms/corridor.py", "algorithms/referencerasters.py",
              "algorithms/validate.py", "algorithms/aspecterrors.py",
              "algorithms/simulate.py", "algorithms/calibrate.py"):
        assert f"canopyblocks_qgis/{f}" in names
    assert not any("__pycache__" in n or n.endswith(".pyc") for n in names)
    cp = configparser.ConfigParser(interpolation=None)
    cp.read_string(meta)
    g = cp["general"]
    assert g["name"] == "canopyblocks"
    assert g["version"] == canopyblocks.__version__
    assert g["qgisMinimumVersion"] == "3.36"
    assert g["license"] == "GPL-3.0-or-later"
    assert g["hasProcessingProvider"] == "yes"
    for key in ("tracker", "repository", "homepage", "email", "about"):
        assert g[key].strip(), key
    tags = {t.strip() for t in g["tags"].split(",")}
    assert {"icesat-2", "atl03", "mabel", "gedi", "las", "laz"} <= tags
    assert (tmp_path / path.name).exists() and len(list(tmp_path.iterdir())) == 1


def test_version_mismatch_stops_the_build(build_plugin, tmp_path):
    text = (ROOT / "metadata.txt").read_text()
    fake = tmp_path / "metadata.txt"
    fake.write_text("\n".join("version=9.9.9" if line.startswith("version=") else line
                              for line in text.splitlines()))
    with pytest.raises(build_plugin.BuildError, match="9.9.9"):
        build_plugin.build(tmp_path / "dist", metadata=fake)
    assert not any((tmp_path / "dist").glob("*"))
    missing = tmp_path / "nometa.txt"
    missing.write_text("[general]\nname=canopyblocks\nversion=0.1.0\n")
    with pytest.raises(build_plugin.BuildError, match="qgisMinimumVersion"):
        build_plugin.build(tmp_path / "dist", metadata=missing)
