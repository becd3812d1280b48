"""A COPC or EPT survey whose hierarchy points at data that is not there, read whole and by
a window (``canopyblocks rasters --bounds``), locally and over HTTP: refused in one line
naming the source (and the node's file) and what to do, with no output left; never read as
fewer points.

Made from the Topography tile (``tests/copc_data.py``: capacity 5,000, sub-hierarchies
from level 1); the damaged node is 2-0-0-1 (523 points), a leaf listed in a sub-hierarchy,
and the window is the middle fifth of its cube (144 points).  Before, a window read of the
EPT with that node's entry left out or counted 0, or of the COPC with its entry zeroed, gave
131 points instead of 144 (and the rasters command exit 0), while a whole read was
refused; a truncated node file, a count
that disagreed with the node's file were refused without saying what to do.  The undamaged
survey's window holds exactly the tile's points in it (plain laspy) and gives the rasters of
the LAZ tile, cell for cell.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canopyblocks.cli import main
from canopyblocks.errors import FileFormatError
from canopyblocks.readers import remote
from canopyblocks.readers.copc import read_copc
from canopyblocks.readers.ept import read_ept
from copc_data import (
    NODE_EDITS,
    build_octree,
    copc_node_damaged,
    ept_node_damaged,
    node_box,
    node_entry,
    tile_points,
    write_copc,
    write_ept,
)
from loopback_servers import RangeHTTPServer

laspy = pytest.importorskip("laspy")
rasterio = pytest.importorskip("rasterio")

TOTAL = 73_403  # the Topography tile's points


@pytest.fixture(scope="module")
def made(tmp_path_factory, sample) -> Any:  # noqa: ANN001
    """The tile, its COPC and EPT, the window, and a server over the folder."""
    root = tmp_path_factory.mktemp("nodes")
    topo = sample("als/lidR_Topography.laz")
    tree = build_octree(tile_points([topo]), capacity=5000)
    write_copc([topo], root / "topo.copc.laz", tree=tree, page_level=1)
    write_ept([topo], root / "ept", tree=tree, split_level=1)
    cube = json.loads((root / "ept" / "ept.json").read_text())["bounds"]
    with RangeHTTPServer(root) as server:
        yield {"root": root, "topo": topo, "box": node_box(cube), "url": server.url,
               "raw": (root / "topo.copc.laz").read_bytes()}


def _damaged(made: Any, kind: str, edit: str) -> Path:
    """A damaged copy under the served folder: its local path (``ept.json`` or ``.copc.laz``)."""
    d = made["root"] / f"{kind}-{edit}"
    if kind == "ept":
        shutil.copytree(made["root"] / "ept", d / "ept", dirs_exist_ok=True)
        ept_node_damaged(d / "ept", edit)
        return d / "ept" / "ept.json"
    d.mkdir(exist_ok=True)
    p = d / f"{edit}.copc.laz"
    p.write_bytes(copc_node_damaged(made["raw"], edit))
    return p


def _source(made: Any, path: Path, where: str) -> str:
    remote.clear_cache()
    return str(path) if where == "local" else \
        f"{made['url']}/{path.relative_to(made['root']).as_posix()}"


def _rasters(src: str, out: Path, box: Any, capsys: Any) -> tuple[int, list[str]]:
    args = ["rasters", src, "-o", str(out), "--backend", "serial"]
    if box is not None:
        args += ["--bounds", *map(str, box)]
    code = main(args)
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    return code, err


def _want(made: Any, kind: str, edit: str) -> str:
    """What the refusal must say (besides the source), for whole and window reads alike."""
    if kind == "copc":
        e = node_entry(made["raw"])
        n = len(made["raw"])
        return {"node-past-end": f"the hierarchy puts node 2-0-0-1 at byte {n + e[4]:,}, "
                                 "where no LAZ chunk begins",
                "node-size-past-end": f"the hierarchy says node 2-0-0-1 holds 523 points in "
                                      f"{n:,} bytes, its LAZ chunk holds 523 points in "
                                      f"{e[5]:,} bytes",
                "node-into-other": "where no LAZ chunk begins",
                "node-zeroed": "its hierarchy's nodes hold 72,880 points, its header says "
                               "73,403",
                "node-cut": "truncated or damaged"}[edit]
    return {"node-missing": "node ept-data/2-0-0-1.laz is missing",
            "node-truncated": "node ept-data/2-0-0-1.laz is not readable LAZ",
            "node-count": "its hierarchy's nodes hold 73,280 points, ept.json says 73,403",
            "node-counts-swapped": "node ept-data/2-0-0-1.laz holds 523 points, its "
                                   "hierarchy says 563",
            "node-left-out": "its hierarchy's nodes hold 72,880 points, ept.json says 73,403",
            "node-zero": "its hierarchy's nodes hold 72,880 points, ept.json says 73,403"}[edit]


CASES = [(k, e) for k, edits in NODE_EDITS.items() for e in edits]


@pytest.mark.parametrize("where", ["local", "http"])
@pytest.mark.parametrize(("kind", "edit"), CASES)
def test_a_node_the_hierarchy_lies_about_is_refused(made, kind, edit, where, tmp_path,  # noqa: ANN001
                                                    capsys) -> None:  # noqa: ANN001
    path = _damaged(made, kind, edit)
    want = _want(made, kind, edit)
    read = read_ept if kind == "ept" else read_copc
    src = _source(made, path, where)
    with pytest.raises(FileFormatError) as exc:  # the whole survey, no area
        read(src)
    msg = str(exc.value)
    if not (kind == "ept" and edit == "node-counts-swapped"):  # whole: 2-0-1-1 read first
        assert want in msg, msg
    assert msg.startswith(f"{src}: ") and "\n" not in msg, msg
    assert "again" in msg, f"does not say what to do: {msg}"
    for name, box in (("window", made["box"]), ("extent", None)):
        out = tmp_path / name
        code, err = _rasters(_source(made, path, where), out, box, capsys)
        assert code == 2, err
        assert len(err) == 1 and err[0].startswith("canopyblocks: error: "), err
        assert src in err[0] and want in err[0] and "again" in err[0], err[0]
        assert "no points" not in err[0]
        assert not out.exists() or not any(out.rglob("*")), list(out.rglob("*"))


@pytest.mark.parametrize("kind", ["ept", "copc"])
def test_the_undamaged_window_holds_the_tiles_points(made, kind, tmp_path, capsys) -> None:  # noqa: ANN001
    from canopyblocks.workflows.rasters import make_survey_rasters

    box = made["box"]
    las = laspy.read(made["topo"])
    x, y = np.asarray(las.x), np.asarray(las.y)
    inside = (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
    assert inside.sum() == 144
    path = made["root"] / ("ept/ept.json" if kind == "ept" else "topo.copc.laz")
    read = read_ept if kind == "ept" else read_copc
    for where in ("local", "http"):
        pts = read(_source(made, path, where), bounds=box)
        got = np.sort(np.column_stack([pts.x, pts.y, pts.z]).view("f8,f8,f8"), axis=0)
        want = np.sort(np.column_stack([x[inside], y[inside], np.asarray(las.z)[inside]]
                                       ).view("f8,f8,f8"), axis=0)
        np.testing.assert_array_equal(got, want)
        assert read(_source(made, path, where)).x.size == TOTAL
    code, err = _rasters(str(path), tmp_path / "cloud", box, capsys)
    assert code == 0, err
    tile = make_survey_rasters([made["topo"]], tmp_path / "tile", bounds=box, backend="serial")
    for name in ("dtm.tif", "dsm_max.tif", "dsm_p90.tif"):
        with rasterio.open(tmp_path / "cloud" / name) as a, rasterio.open(
                getattr(tile, name[:-4])) as b:
            assert a.transform == b.transform and a.shape == b.shape
            np.testing.assert_array_equal(a.read(1), b.read(1), err_msg=name)


def test_a_huge_hierarchy_is_not_read_whole_for_a_window(made, monkeypatch, caplog) -> None:  # noqa: ANN001
    """Beyond a bounded number of hierarchy files, a window read does not read the rest of
    the hierarchy for the total check (a national survey's EPT has thousands of them): the
    window's points are read, the check left out and said in the log; the whole read still
    refuses the node left out."""
    import logging

    from canopyblocks.readers import ept

    path = _damaged(made, "ept", "node-left-out")
    n_files = len(list((path.parent / "ept-hierarchy").glob("*.json")))
    assert n_files > 2
    monkeypatch.setattr(ept, "WHOLE_CHECK_FILES", 0)
    monkeypatch.setattr(ept, "_WHOLE", set())
    src = _source(made, path, "local")
    with caplog.at_level(logging.INFO, logger="canopyblocks.readers.ept"):
        pts = read_ept(src, bounds=(made["box"][0], made["box"][1], made["box"][0] + 1.0,
                                    made["box"][1] + 1.0))
    assert pts.x.size < TOTAL
    assert "hierarchy's total is not checked" in caplog.text, caplog.text
    with pytest.raises(FileFormatError, match="72,880 points, ept.json says 73,403"):
        read_ept(src)
