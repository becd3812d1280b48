"""scripts/install_pdal.sh and finding the pdal executable."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from canopyblocks.errors import DependencyError
from canopyblocks.reference import pdal as pdal_mod
from canopyblocks.reference.pdal import DEFAULT_PDAL, find_pdal, pdal_version

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "install_pdal.sh"


def test_install_script_is_valid_bash() -> None:
    r = subprocess.run(["bash", "-n", str(SCRIPT)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    text = SCRIPT.read_text()
    # the recipe: private apt state, an empty dpkg status, bullseye only, no system install
    for needle in ("Dir::State::status", "Dir::Etc::SourceParts=/dev/null", "bullseye-security",
                   "apt-get", "download", "dpkg-deb -x", "--no-install-recommends"):
        assert needle in text
    # it only simulates an install (-s) against the private state, never installs system-wide
    assert "apt-get \"${APT_OPTS[@]}\" -s --no-install-recommends install" in text


def test_install_script_is_idempotent(pdal_bin: str) -> None:
    if not (DEFAULT_PDAL.exists() and Path(pdal_bin).resolve() == DEFAULT_PDAL.resolve()):
        pytest.skip("pdal was not installed by scripts/install_pdal.sh in the default prefix")
    r = subprocess.run(["bash", str(SCRIPT)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == str(DEFAULT_PDAL)
    assert "already installed" in r.stderr


def test_wrapper_keeps_pdal_env_out_of_python(pdal_bin: str) -> None:
    """The wrapper sets PDAL's library paths for pdal only; this process never sees them."""
    assert pdal_version(pdal_bin).startswith("2.")
    for var in ("PDAL_DRIVER_PATH",):
        assert "canopyblocks-pdal" not in os.environ.get(var, "")
    assert "canopyblocks-pdal" not in os.environ.get("LD_LIBRARY_PATH", "")


def test_find_pdal_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake = tmp_path / "mypdal"
    fake.write_text("#!/bin/sh\necho 'pdal 9.9.9 (fake)'\n")
    fake.chmod(0o755)
    other = tmp_path / "envpdal"
    shutil.copy(fake, other)
    monkeypatch.setenv("CANOPYBLOCKS_PDAL", str(other))
    assert find_pdal(fake) == fake  # an explicit setting wins
    assert find_pdal() == other  # then the environment variable
    assert pdal_version(fake) == "9.9.9"
    monkeypatch.setenv("CANOPYBLOCKS_PDAL", str(tmp_path / "nothing"))
    with pytest.raises(DependencyError, match="CANOPYBLOCKS_PDAL.*install_pdal.sh"):
        find_pdal()
    with pytest.raises(DependencyError, match="pdal setting.*install_pdal.sh"):
        find_pdal(tmp_path / "nothing")
    # nothing anywhere: the message says how to install
    monkeypatch.delenv("CANOPYBLOCKS_PDAL")
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.setattr(pdal_mod, "DEFAULT_PDAL", tmp_path / "none" / "pdal")
    with pytest.raises(DependencyError, match="install_pdal.sh"):
        find_pdal()
    # on PATH, after the env variable
    (tmp_path / "bin").mkdir()
    shutil.copy(fake, tmp_path / "bin" / "pdal")
    monkeypatch.setenv("PATH", str(tmp_path / "bin"))
    assert find_pdal() == tmp_path / "bin" / "pdal"
