"""Corpus cases of options that did not act, inputs read past their context, and messages
that named another cause: the estimator options the estimators ignore, an old and a new
spelling together, ``validate --diameter`` on GEDI footprints, invalid and foreign
``--polygon`` inputs, a ``--bbox`` that cut the classifier's context or the paper's
blocks (moved off the full run's grid, cut at the box's edge), a noise-free
dual-wavelength file, and network reads (real loopback servers) that failed in the middle.

Registered in :func:`badinputs.make_corpus.all_cases`; the runners ``options`` (the
command line, in-process, one refusal line turned into the project's error) and
``box-context`` / ``box-grid`` / ``dual-free`` (numbers against an independent truth) join
the corpus
test's runners through :data:`RUNNERS`.
"""

from __future__ import annotations

import contextlib
import io
import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from canopyblocks.errors import CanopyBlocksError

__all__ = ["options_cases", "RUNNERS"]

BOX = (-106.58, 41.5338, -106.56, 41.5378)  # the middle half of the vegr clip's track
GEDI_ZIP = "gedi/GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.zip"


class CliRefused(CanopyBlocksError):
    """The command's one error line (exit 2), for the corpus's refusal checks."""


def _cli(args: list[str]) -> None:
    from canopyblocks.cli import cli
    from canopyblocks.cli.common import run_main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = run_main(cli, ["-q", *args])
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    assert "Traceback" not in err.getvalue(), err.getvalue()
    if code == 2:
        errors = [ln for ln in lines if ln.startswith("canopyblocks: error: ")]
        assert len(errors) == 1 and lines[-1] == errors[0], lines
        raise CliRefused(errors[0][len("canopyblocks: error: "):])
    assert code == 0, (code, lines)


def _served(folder: Path, base: Any) -> Path:
    root = folder / "served"
    (root / "norange").mkdir(parents=True, exist_ok=True)
    shutil.copy(base.vegr, root / "atl03.h5")
    shutil.copy(base.vegr, root / "norange" / "atl03.h5")
    shutil.copy(base.topo, root / "tile.laz")
    return root


def run_options(i: dict[str, Any], folder: Path) -> Any:
    args = i["args"]
    if "served" not in i:
        return _cli(args(folder))
    from canopyblocks.readers import remote
    from loopback_servers import RangeHTTPServer

    remote.clear_cache()
    saved = remote.RETRIES
    remote.RETRIES = 0
    try:
        with RangeHTTPServer(i["served"], fail_after=i.get("fail_after", float("inf"))) as s:
            i["name"] = i["name"].format(url=s.url)
            return _cli(args(folder, s.url))
    finally:
        remote.RETRIES = saved


def check_options(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    raise AssertionError(f"accepted: {i.get('name')} should have been refused")


def _gedi(folder: Path, base: Any) -> Path:
    with zipfile.ZipFile(base.data_file(GEDI_ZIP)) as z:
        name = z.namelist()[0]
        z.extract(name, folder)
    return folder / name


def _footprints(folder: Path, base: Any) -> Path:
    fp = folder / "fp.gpkg"
    _cli(["waveforms", str(_gedi(folder, base)), "-o", str(fp)])
    return fp


def run_box(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks import BlockParams, blocks_from_file
    from canopyblocks.readers import read_atl03

    s0 = float(np.min(read_atl03(i["path"], "gt1r").s))
    p = BlockParams(lengths=(25.0,), s0=s0)
    full = blocks_from_file(i["path"], p, beams=("gt1r",), with_photons=True, workers=1)
    box = blocks_from_file(i["path"], p, beams=("gt1r",), with_photons=True, bbox=BOX,
                           workers=1)
    return full, box


def check_box(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    full, box = result
    ft, bt = full.tracks[0], box.tracks[0]

    def key(t: Any) -> list[tuple[float, float]]:
        return [(round(float(a), 7), round(float(b), 3)) for a, b in zip(t.time, t.h)]
    cls = dict(zip(key(ft), ft.extra["classed_pc_flag"]))
    inner = (bt.s >= bt.s.min() + 50) & (bt.s <= bt.s.max() - 50)
    got = np.asarray(bt.extra["classed_pc_flag"])[inner]
    want = np.array([cls[k] for k, m in zip(key(bt), inner) if m])
    kept = float(np.mean(got == want))
    assert kept >= 0.99, f"{100 * kept:.2f} % of the photons 50 m inside the box kept class"
    fb, bb = full.blocks.set_index("block"), box.blocks.set_index("block")
    same = [b for b in bb.index if b in fb.index and fb.loc[b, "n_photons"] ==
            bb.loc[b, "n_photons"]]
    assert len(same) >= len(bb) - 2, f"{len(same)} of {len(bb)} blocks hold the full run's"
    d = np.abs(bb.loc[same, "hmax"].to_numpy(float) - fb.loc[same, "hmax"].to_numpy(float))
    assert np.nanmax(d) < 1e-6, f"Hmax off by up to {np.nanmax(d):.2f} m"


def run_box_grid(i: dict[str, Any], folder: Path) -> Any:
    """``blocks --preset paper`` at 10, 25 and 50 m, on the command line, with and
    without ``--bbox`` (no ``--s0``: the grid's origin is the command's own)."""
    import pandas as pd

    out = {}
    for name, opts in (("full", []), ("box", [f"--bbox={','.join(map(str, BOX))}"])):
        path = folder / f"{name}.csv"
        _cli(["blocks", str(i["path"]), "--preset", "paper", "--length", "10", "--length",
              "25", "--length", "50", *opts, "-o", str(path)])
        out[name] = pd.read_csv(path)
    return out["full"], out["box"]


def check_box_grid(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    full, box = result
    m = box.merge(full, on=["track", "length", "s_start", "s_end"], how="left",
                  suffixes=("", "_full"), indicator=True)
    assert len(box) >= 30, f"{len(box)} box blocks"
    off = int((m["_merge"] != "both").sum())
    assert off == 0, f"{off} of {len(box)} box blocks are not on the full run's grid"
    for c in ("n_photons", "n_kept", "hmax", "h90", "ground", "top"):
        a, b = m[c].to_numpy(float), m[f"{c}_full"].to_numpy(float)
        bad = ~(np.isclose(a, b, rtol=0, atol=1e-9) | (np.isnan(a) & np.isnan(b)))
        assert not bad.any(), f"{c} differs from the full run's in {bad.sum()} blocks"
    assert (m["flag"] == m["flag_full"]).all(), "flags differ from the full run's"


def run_dual_free(i: dict[str, Any], folder: Path) -> Any:
    import geopandas as gpd
    import h5py

    path, out = folder / "dual0.h5", folder / "dual0.gpkg"
    _cli(["simulate", str(i["path"]), "--sensor", "dual", "--dual-noise", "0", "--azimuth",
          "30", "-o", str(path)])
    _cli(["waveforms", str(path), "-o", str(out)])
    with h5py.File(path) as f:
        truth = f["truth/ground"][()]
    return gpd.read_file(out, layer="footprints"), truth


def check_dual_free(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    fp, truth = result
    ok = fp["flag"].to_numpy() == "ok"
    err = fp["ground"].to_numpy(float)[ok] - truth[ok]
    assert ok.sum() >= 10, f"{ok.sum()} footprints ok"
    assert np.abs(err).max() < 2.5, f"'ok' ground off by up to {np.abs(err).max():.2f} m"


RUNNERS: dict[str, tuple[Callable[..., Any], Callable[..., None]]] = {
    "options": (run_options, check_options), "box-context": (run_box, check_box),
    "box-grid": (run_box_grid, check_box_grid),
    "dual-free": (run_dual_free, check_dual_free)}


def _bow_tie(base: Any) -> str:
    import laspy

    with laspy.open(base.topo) as r:
        lo, hi = r.header.mins, r.header.maxs
    return (f"POLYGON (({lo[0]} {lo[1]}, {hi[0]} {hi[1]}, {hi[0]} {lo[1]}, {lo[0]} {hi[1]}, "
            f"{lo[0]} {lo[1]}))")


def options_cases() -> list[Any]:
    from .make_corpus import Case

    def blocks(*opts: str) -> Callable[..., list[str]]:
        return lambda f, b, e: ["blocks", str(b.vegr), "--length", "25", *opts,
                                "-o", str(f / "out" / "b.gpkg")]
    preset_paper = ("--preset paper",)
    rows: list[tuple[str, str, Callable[..., list[str]], tuple[str, ...], tuple[str, ...],
                     Callable[[Path, Any], dict] | None]] = [
        ("opt-blocks-top-cutoff-atl08", "--top-cutoff", blocks("--top-cutoff", "0.2"),
         preset_paper, (), None),
        ("opt-blocks-ground-cutoff-mabel", "--ground-cutoff",
         blocks("--preset", "mabel", "--ground-cutoff", "0.3"), preset_paper, (), None),
        ("opt-blocks-top-cutoff-icesat2", "--top-cutoff",
         blocks("--preset", "icesat2", "--top-cutoff", "0.3"), preset_paper, (), None),
        ("opt-blocks-k-sigma-atl08", "--k-sigma", blocks("--k-sigma", "3"), preset_paper, (),
         None),
        ("opt-blocks-k-and-k-sigma", "--k-sigma",
         blocks("--preset", "paper", "--k", "1.5", "--k-sigma", "2.5"), ("deprecated --k",),
         (), None),
        ("opt-run-preset-boreal-photon-rate", "--photon-rate",
         lambda f, b, e: ["run", str(b.topo), "--simulate", "--preset", "boreal",
                          "--photon-rate", "tropical", "-o", str(f / "out")],
         ("deprecated --preset boreal",), (), None),
        ("opt-waveforms-k-sigma-gedi", "--k-sigma",
         lambda f, b, e: ["waveforms", str(e["gedi"]), "--k-sigma", "4", "-o",
                          str(f / "out" / "fp.gpkg")],
         ("flash-lidar",), ("--noise-threshold",),
         lambda f, b: {"gedi": _gedi(f, b)}),
        ("opt-validate-diameter-gedi", "--diameter",
         lambda f, b, e: ["validate", str(e["fp"]), "--points", str(b.topo), "--diameter",
                          "13", "-o", str(f / "out" / "v.gpkg")],
         ("GEDI footprint",), (), lambda f, b: {"fp": _footprints(f, b)}),
        ("polygon-bow-tie-rasters", "--polygon",
         lambda f, b, e: ["rasters", str(b.topo), "-o", str(f / "out"), "--polygon",
                          _bow_tie(b)], ("self-intersection",), (), None),
        ("net-run-tile-url", "{url}/tile.laz",
         lambda f, b, e, u: ["run", f"{u}/tile.laz", "--simulate", "-o", str(f / "out")],
         ("download",), ("no such file", "http:/1"),
         lambda f, b: {"served": _served(f, b)}),
        ("net-https-to-http", "/atl03.h5",
         lambda f, b, e, u: ["blocks", u.replace("http:", "https:") + "/atl03.h5", "-o",
                             str(f / "out" / "b.csv")],
         ("does not speak https",), ("SSL", "ClientConnector"),
         lambda f, b: {"served": _served(f, b)}),
        ("net-batch-no-byte-ranges", "{url}/norange/atl03.h5",
         lambda f, b, e, u: ["batch", f"{u}/norange/atl03.h5", "--tiles", str(b.topo), "-o",
                             str(f / "out")],
         ("byte ranges",), ("crosses", "StorageError"),
         lambda f, b: {"served": _served(f, b)}),
    ]
    for k in (3,):
        rows.append((f"net-server-dies-after-{k}", "{url}/atl03.h5",
                     lambda f, b, e, u: ["blocks", f"{u}/atl03.h5", "-o",
                                         str(f / "out" / "b.csv")],
                     ("503", "no answer"), ("no usable photons", "no photons"),
                     lambda f, b, k=k: {"served": _served(f, b), "fail_after": k}))
    cases: list[Any] = []
    for cid, name, args, needles, forbidden, prepare in rows:
        def make(folder: Path, base: Any, args: Any = args, prepare: Any = prepare,
                 name: str = name) -> dict[str, Any]:
            extra = prepare(folder, base) if prepare is not None else {}
            out: dict[str, Any] = {"path": None, "name": name,
                                   "args": lambda f, *u: args(f, base, extra, *u)}
            out.update({k: v for k, v in extra.items() if k in ("served", "fail_after")})
            return out
        cases.append(Case(cid, "options", make, needles=needles, forbidden=forbidden,
                          must_refuse=True))
    cases.append(Case("box-context-vegr-atl08", "box-context",
                      lambda f, b: {"path": b.vegr}, must_accept=True))
    cases.append(Case("box-grid-vegr-paper", "box-grid",
                      lambda f, b: {"path": b.vegr}, must_accept=True))
    cases.append(Case("dual-noise-free-bcts", "dual-free",
                      lambda f, b: {"path": b.data_file("als/lasR_bcts_1.laz")},
                      must_accept=True))
    return cases
