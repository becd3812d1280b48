"""Corpus cases of cloud-optimised surveys: COPC files and EPT datasets made from the
Topography tile (``tests/copc_data.py``), damaged: truncated COPC files, a plain LAZ given
as COPC, a broken ``ept.json``, a missing node file, an unsupported EPT data type, a server
that ignores byte ranges; hierarchies that lie (a node's count halved or zeroed, a node at
another node's chunk, a moved octree centre or header, an EPT without its root or a node);
a node whose data is not what the hierarchy says (an EPT node's file missing, cut in half,
counted otherwise, left out or counted 0; a COPC node's offset or size past the file's end,
inside another node's chunk, zeroed, the file cut inside it), read whole and by a window
over the node, some over HTTP.  The undamaged ones must be read, and give the tile's own
points (read here with plain laspy), those of the window for a window read.

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
        if edit in (*LIES, "garbled"):  # a hierarchy, centre or header that lies, or a
            # node's compressed bytes garbled
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
        elif edit == "bounds-moved":  # ept.json's cube moved 20 m east
            j = json.loads(meta)
            j["bounds"][0] += 20.0
            j["bounds"][3] += 20.0
            (ept / "ept.json").write_text(json.dumps(j))
        return {"path": ept / "ept.json", "kind": "ept", "truth": base.topo}
    return make


NODE_NEEDLES = {"node-missing": ("is missing",), "node-truncated": ("truncated",),
                "node-count": ("hierarchy",), "node-counts-swapped": ("its hierarchy says",),
                "node-left-out": ("hierarchy's nodes hold",),
                "node-zero": ("hierarchy's nodes hold",),
                "node-past-end": ("no LAZ chunk begins",),
                "node-size-past-end": ("its LAZ chunk holds",),
                "node-into-other": ("no LAZ chunk begins",),
                "node-zeroed": ("hierarchy's nodes hold",), "node-cut": ("truncated",)}
"""What the refusal of each node edit (``copc_data.NODE_EDITS``) must say."""


def _node(kind: str, edit: str, window: bool, serve: bool = False
          ) -> Callable[[Path, Any], dict[str, Any]]:
    """A COPC or EPT whose node 2-0-0-1 is damaged by ``edit`` (none: undamaged), read
    whole or by the middle fifth of the node's cube, locally or over HTTP."""
    def make(folder: Path, base: Any) -> dict[str, Any]:
        from copc_data import copc_node_damaged, ept_node_damaged, node_box

        copc, ept = _made(base)
        d = folder / "served"
        d.mkdir()
        if kind == "ept":
            shutil.copytree(ept, d / "ept")
            if edit != "none":
                ept_node_damaged(d / "ept", edit)
            p = d / "ept" / "ept.json"
        else:
            p = d / f"{edit}.copc.laz"
            raw = copc.read_bytes()
            p.write_bytes(raw if edit == "none" else copc_node_damaged(raw, edit))
        cube = json.loads((ept / "ept.json").read_text())["bounds"]
        return {"path": p, "kind": kind, "truth": base.topo, "serve": serve,
                "bounds": node_box(cube) if window else None}
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
            return read(f"{server.url}/{p.parent.name}/{p.name}", bounds=i.get("bounds"))
    return read(i["path"], bounds=i.get("bounds"))


def check_copc(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    """An accepted dataset holds exactly the tile's points (plain laspy)."""
    import laspy

    las = laspy.read(i["truth"])
    want = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    b = i.get("bounds")
    if b is not None:  # a window read: the tile's points inside it, edges included
        want = want[(want[:, 0] >= b[0]) & (want[:, 0] <= b[2]) & (want[:, 1] >= b[1])
                    & (want[:, 1] <= b[3])]
        assert len(want) == 144, f"the window holds {len(want)} of the tile's points"
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
    cases.append(Case("ept-bounds-moved", "copc", _ept("bounds-moved"),
                      needles=("ept.json's bounds",), must_refuse=True,
                      forbidden=("another node's points",)))
    cases.append(Case("copc-node-garbled", "copc", _copc("garbled"),
                      needles=("cannot be decompressed",), must_refuse=True,
                      forbidden=("ioerror", "fill whole buffer", "0-0-0-0")))
    cases += [Case(f"ept-hierarchy-{e}", "copc", _ept(e), needles=("hierarchy",),
                   forbidden=("no points",), must_refuse=True) for e in ("no-root", "no-entry")]
    return cases + _node_cases()


def _node_cases() -> list[Any]:
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from copc_data import NODE_EDITS

    from .make_corpus import Case

    cases = [Case(f"{k}-window-baseline", "copc", _node(k, "none", True), must_accept=True)
             for k in ("copc", "ept")]
    for kind, edits in NODE_EDITS.items():
        for e in edits:
            for read in ("whole", "window"):
                cases.append(Case(f"{kind}-{e}-{read}", "copc", _node(kind, e, read == "window"),
                                  needles=NODE_NEEDLES[e], forbidden=("no points",),
                                  must_refuse=True))
    cases += [Case(f"{k}-{e}-window-http", "copc", _node(k, e, True, serve=True),
                   needles=NODE_NEEDLES[e], forbidden=("no points",), must_refuse=True)
              for k, e in (("ept", "node-missing"), ("ept", "node-truncated"),
                           ("ept", "node-left-out"), ("copc", "node-past-end"),
                           ("copc", "node-zeroed"))]
    return cases
