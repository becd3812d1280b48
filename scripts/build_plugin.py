#!/usr/bin/env python3
"""Build the QGIS plugin zip: dist/canopyblocks_qgis-<version>.zip.

The zip holds one folder, ``canopyblocks_qgis/``, with the plugin (``qgis_plugin/``) and the
top-level ``metadata.txt``.  The plugin version in metadata.txt must equal the core's
``__version__`` (core/canopyblocks/__init__.py); the build stops otherwise.  The zip is written
under a temporary name and renamed when complete; it and every file in it are mode 0644
(folders 0755), whatever the umask and the checkout's modes.

Usage: python scripts/build_plugin.py [--out DIR]
"""

from __future__ import annotations

import argparse
import configparser
import os
import re
import stat
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLUGIN_DIR = ROOT / "qgis_plugin"
METADATA = ROOT / "metadata.txt"
CORE_INIT = ROOT / "core" / "canopyblocks" / "__init__.py"
FOLDER = "canopyblocks_qgis"
SKIP_DIRS = {"__pycache__", ".mypy_cache", ".pytest_cache"}
SKIP_SUFFIXES = {".pyc", ".pyo", ".orig", ".rej", ".swp"}


class BuildError(Exception):
    """The plugin cannot be built as it stands (message says why)."""


def core_version(init: Path = CORE_INIT) -> str:
    """``__version__`` of the core, read from the source without importing it."""
    m = re.search(r'^__version__\s*=\s*["\']([^"\']+)["\']', init.read_text(), re.MULTILINE)
    if not m:
        raise BuildError(f"no __version__ = '...' line in {init}")
    return m.group(1)


def metadata_version(path: Path = METADATA) -> str:
    """``version`` of the [general] section of the plugin's metadata.txt."""
    cp = configparser.ConfigParser(interpolation=None)
    cp.read_string(path.read_text(encoding="utf-8"))
    try:
        return cp["general"]["version"].strip()
    except KeyError:
        raise BuildError(f"{path} has no [general] version=") from None


def check_metadata(path: Path = METADATA) -> None:
    """The keys the QGIS plugin repository requires are present and non-empty."""
    cp = configparser.ConfigParser(interpolation=None)
    cp.read_string(path.read_text(encoding="utf-8"))
    required = ("name", "qgisMinimumVersion", "description", "about", "version", "author",
                "email", "repository", "tracker", "homepage", "license", "tags")
    g = cp["general"] if cp.has_section("general") else {}
    missing = [k for k in required if not str(g.get(k, "")).strip()]
    if missing:
        raise BuildError(f"{path} lacks required key(s): {', '.join(missing)}")


def plugin_files(plugin_dir: Path = PLUGIN_DIR) -> list[Path]:
    """Files of the plugin folder to ship, sorted (no caches or editor leftovers)."""
    out = []
    for p in sorted(plugin_dir.rglob("*")):
        rel = p.relative_to(plugin_dir)
        if p.is_dir() or any(part in SKIP_DIRS for part in rel.parts):
            continue
        if p.suffix in SKIP_SUFFIXES or p.name.startswith("."):
            continue
        out.append(p)
    return out


def _entry(name: str, mode: int, source: Path | None) -> zipfile.ZipInfo:
    """A zip entry of fixed Unix mode (whatever the umask or the checkout's modes),
    dated as its source file (folders: the zip's epoch, 1980-01-01)."""
    if source is None:
        info = zipfile.ZipInfo(name)
    else:
        info = zipfile.ZipInfo.from_file(source, name)
    info.create_system = 3  # Unix: unzip and QGIS's installer read the mode below
    info.external_attr = mode << 16
    if source is None:
        info.external_attr |= 0x10  # MS-DOS directory bit
    else:
        info.compress_type = zipfile.ZIP_DEFLATED
    return info


def write_zip(path: Path, entries: list[tuple[Path, str]]) -> None:
    """Write ``entries`` (source file, name in the zip) to ``path``: every file
    ``-rw-r--r--`` (0644), every folder ``drwxr-xr-x`` (0755), so every user of a shared
    QGIS can read the installed plugin."""
    folders = sorted({"/".join(name.split("/")[:i]) + "/" for _, name in entries
                      for i in range(1, name.count("/") + 1)})
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for folder in folders:
            zf.writestr(_entry(folder, stat.S_IFDIR | 0o755, None), b"")
        for source, name in entries:
            zf.writestr(_entry(name, stat.S_IFREG | 0o644, source), source.read_bytes())


def build(out_dir: Path = ROOT / "dist", *, metadata: Path = METADATA,
          plugin_dir: Path = PLUGIN_DIR, core_init: Path = CORE_INIT,
          licence: Path = ROOT / "LICENSE") -> Path:
    """Write the zip and return its path (raises BuildError, leaving nothing behind)."""
    check_metadata(metadata)
    v_meta, v_core = metadata_version(metadata), core_version(core_init)
    if v_meta != v_core:
        raise BuildError(
            f"metadata.txt version {v_meta} differs from canopyblocks.__version__ {v_core} "
            f"({core_init}); make them equal"
        )
    if not (plugin_dir / "__init__.py").exists():
        raise BuildError(f"{plugin_dir}/__init__.py is missing")
    if not licence.is_file():
        raise BuildError(f"{licence} is missing; the QGIS plugin repository rejects a zip "
                         "without its licence")
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"{FOLDER}-{v_meta}.zip"
    fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=".part.zip", dir=out_dir)
    os.close(fd)
    try:
        entries = [(p, f"{FOLDER}/{p.relative_to(plugin_dir).as_posix()}")
                   for p in plugin_files(plugin_dir)]
        entries += [(metadata, f"{FOLDER}/metadata.txt"), (licence, f"{FOLDER}/LICENSE")]
        write_zip(Path(tmp), entries)
        os.chmod(tmp, 0o644)  # mkstemp made it 0600: readable by every user of the QGIS
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "dist", help="output folder (dist/)")
    args = ap.parse_args(argv)
    try:
        path = build(args.out)
    except BuildError as exc:
        print(f"build_plugin: error: {exc}", file=sys.stderr)
        return 2
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
