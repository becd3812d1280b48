"""Corpus cases of cloud-optimised surveys: COPC files and EPT datasets made from the
Topography tile (``tests/copc_data.py``), damaged: truncated COPC files, a plain LAZ given
as COPC, a broken ``ept.json``, a missing node file, an unsupported EPT data type, a server
that ignores byte ranges; hierarchies that lie (a node's count halved or zeroed, a node at
another node's chunk, a moved octree centre or header, an EPT without its root or a node).  The undamaged ones must be read, and give the tile's own points
(read here with plain laspy).

Registered in :func:`badinputs.make_corpus.all_cases`; the runner ``copc`` is added to the
corpus test's runners through :data:`RUNNERS`.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["copc_cases", "RUNNERS"]

LIES = ("half", "none", "other", "sibling", "centre", "header")
"""COPC edits of :func:`copc_data.copc_damaged`: a node's count halved or zeroed, a node at
another node's chunk (its parent's, its sibling's), the octree centre or the header extent
moved 5 km."""

BROKEN = ("truncat", "not a copc", "corrupt", "damaged", "missing", "not supported",
          "not valid json", "byte-range")


def _made(base: Any) -> tuple[Path, Path]:
    """The COPC file and EPT folder of the Topography tile (made once per session)."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from copc_data import build_octree, tile_points, write_copc, write_ept

    root = base.folder / "copc"
    copc, ept = root / "topo.copc.laz", root / "ept"
    if not (ept / "ept.json").exists():
        root.mkdir(exist_ok=True)
        tree = build_octree(tile_points([base.topo]), capacity=5000)
        write_copc([base.topo], copc, tree=tree, page_level=1)
        write_ept([base.topo], ept, tree=tree, split_level=1)
    return copc, ept


def _copc(edit: str, frac: float = 0.0) -> Callable[[Path, Any], dict[str, Any]]:
    def make(folder: Path, base: Any) -> dict[str, Any]:
        copc, _ = _made(base)
        if edit == "laz":
            p = folder / "topo.laz"
            shutil.copy(base.topo, p)
            return {"path": p, "kind": "copc", "truth": base.topo}
        p = folder / ("norange" if edit == "norange" else "") / f"{edit}.copc.laz"
        p.parent.mkdir(exist_ok=True)
        raw = copc.read_bytes()
        if edit in LIES:  # a hierarchy, octree centre or header that lies
            from copc_data import copc_damaged

            raw = copc_damaged(raw, edit)
        p.write_bytes(raw[:int(len(raw) * frac)] if edit == "truncated" else raw)
        return {"path": p, "kind": "copc", "truth": base.topo,
                "serve": edit == "norange"}
    return make


def _ept(edit: str) -> Callable[[Path, Any], dict[str, Any]]:
    def make(folder: Path, base: Any) -> dict[str, Any]:
        _, src = _made(base)
        ept = folder / "ept"
        shutil.copytree(src, ept)
        meta = (ept / "ept.json").read_text()
        if edit == "broken-json":
            (ept / "ept.json").write_text(meta[: len(meta) // 3])
        elif edit == "binary":
            (ept / "ept.json").write_text(meta.replace('"laszip"', '"binary"'))
        elif edit == "zstandard":
            (ept / "ept.json").write_text(meta.replace('"laszip"', '"zstandard"'))
        elif edit == "missing-node":
            sorted((ept / "ept-data").glob("2-*.laz"))[0].unlink()
        elif edit == "missing-hierarchy":
            sorted((ept / "ept-hierarchy").glob("1-*.json"))[0].unlink()
        elif edit in ("no-root", "no-entry"):  # a node left out of the hierarchy
            h = (ept / "ept-hierarchy" / "0-0-0-0.json" if edit == "no-root"
                 else sorted((ept / "ept-hierarchy").glob("1-*.json"))[0])
            j = json.loads(h.read_text())
            del j["0-0-0-0" if edit == "no-root" else
                  next(k for k, v in j.items() if k.startswith("2-") and v > 0)]
            h.write_text(json.dumps(j))
        return {"path": ept / "ept.json", "kind": "ept", "truth": base.topo}
    return make


def run_copc(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks.readers.copc import read_copc
    from canopyblocks.readers.ept import read_ept

    read = read_copc if i["kind"] == "copc" else read_ept
    if i.get("serve"):
        from canopyblocks.readers import remote
        from loopback_servers import RangeHTTPServer

        p = Path(i["path"])
        remote.clear_cache()
        with RangeHTTPServer(p.parent.parent) as server:
            return read(f"{server.url}/{p.parent.name}/{p.name}")
    return read(i["path"])


def check_copc(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    """An accepted dataset holds exactly the tile's points (plain laspy)."""
    import laspy

    las = laspy.read(i["truth"])
    want = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    got = np.column_stack([result.x, result.y, result.z])
    assert got.shape == want.shape, f"{len(got)} points, the tile has {len(want)}"
    np.testing.assert_array_equal(got[np.lexsort(got.T[::-1])], want[np.lexsort(want.T[::-1])])


RUNNERS: dict[str, tuple[Callable[..., Any], Callable[..., None]]] = {
    "copc": (run_copc, check_copc)}


def copc_cases() -> list[Any]:
    from .make_corpus import Case

    cases = [Case("copc-baseline", "copc", _copc("whole"), must_accept=True),
             Case("ept-baseline", "copc", _ept("none"), must_accept=True),
             Case("copc-laz-not-copc", "copc", _copc("laz"), needles=("not a COPC",),
                  must_refuse=True),
             Case("copc-norange-server", "copc", _copc("norange"), needles=("byte-range",),
                  must_refuse=True)]
    cases += [Case(f"copc-truncated-{f:g}", "copc", _copc("truncated", f), needles=BROKEN,
                   must_refuse=True) for f in (0.0, 0.001, 0.05, 0.3, 0.6, 0.9, 0.999)]
    cases += [Case(f"ept-{e}", "copc", _ept(e), needles=BROKEN, must_refuse=True)
              for e in ("broken-json", "binary", "zstandard", "missing-node",
                        "missing-hierarchy")]
    cases += [Case(f"copc-hierarchy-{e}", "copc", _copc(e), needles=("hierarchy", "octree"),
                   forbidden=("no points",), must_refuse=True) for e in LIES]
    cases += [Case(f"ept-hierarchy-{e}", "copc", _ept(e), needles=("hierarchy",),
                   forbidden=("no points",), must_refuse=True) for e in ("no-root", "no-entry")]
    return cases
