"""Corpus cases of odd inputs that gave silent wrong numbers: an option the estimators do not
use (``min_signal_conf`` with the ATL08-style classifier), an ATL03 without its
``bckgrd_atlas`` (subsetters drop it), a box read whose background must be the whole
track's.

Registered in :func:`badinputs.make_corpus.all_cases`; the runner ``odd`` joins the corpus
test's runners through :data:`RUNNERS`.  The independent truths: the clip's own file rate
(1.5-2.6 MHz, a day pass) for the rate counted from the photons; ATL08's canopy height over
the clip (<= 10.5 m, tests/data/PROVENANCE.md) for the blocks kept.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np

__all__ = ["odd_cases", "RUNNERS"]

CLIP_CANOPY_MAX = 25.0  # metres: ATL08's h_canopy over the clip reaches 10.5 m
BOX = (-106.58, 41.5338, -106.56, 41.5378)  # the middle half of the clip's track


def _copy(name: str, drop: str | None) -> Callable[[Path, Any], dict[str, Any]]:
    def make(folder: Path, base: Any) -> dict[str, Any]:
        p = folder / f"{name}.h5"
        shutil.copy(base.vegr, p)
        if drop is not None:
            with h5py.File(p, "r+") as f:
                del f[drop]
        return {"path": p, "call": name}
    return make


def run_odd(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks import BlockParams, blocks_from_file
    from canopyblocks.readers import read_atl03

    call = i["call"]
    if call.startswith("conf-"):
        return blocks_from_file(i["path"], BlockParams(min_signal_conf=2)).blocks
    if call.startswith("box-"):
        return read_atl03(i["path"], "gt1r", bbox=BOX)
    return blocks_from_file(i["path"], None).blocks


def check_odd(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    call = i["call"]
    assert not call.startswith("conf-"), f"{call}: an option the estimators ignore accepted"
    if case.warn_words:
        assert any(w.lower() in m.lower() for m in ws for w in case.warn_words), ws
    if call.startswith("box-"):
        bg = result.background
        assert bg is not None and bg.settled, "the box's rate was not settled on the track"
        assert 1.0e6 < float(np.median(bg.rate)) < 3.0e6, float(np.median(bg.rate))
        return
    est = result[result["flag"].isin(["ok", "low_confidence"])]
    assert len(result) >= 20 and len(est) >= 20, f"{len(result)} blocks, {len(est)} estimated"
    ok = result[result["flag"] == "ok"]
    assert not len(ok) or float(ok["hmax"].max()) < CLIP_CANOPY_MAX


RUNNERS: dict[str, tuple[Callable[..., Any], Callable[..., None]]] = {"odd": (run_odd, check_odd)}


def odd_cases() -> list[Any]:
    from .make_corpus import Case

    missing = ("no usable bckgrd_atlas",)
    return [
        Case("odd-min-signal-conf-atl08", "odd", _copy("conf-atl08", None),
             needles=("not used by the atl08",), must_refuse=True),
        Case("odd-min-signal-conf-no-column", "odd",
             _copy("conf-nocol", "gt1r/heights/signal_conf_ph"),
             needles=("signal_conf_ph",), must_refuse=True),
        Case("odd-bckgrd-rate-missing", "odd", _copy("rate-missing",
                                                     "gt1r/bckgrd_atlas/bckgrd_rate"),
             warn_words=missing),
        Case("odd-bckgrd-group-missing", "odd", _copy("group-missing", "gt1r/bckgrd_atlas"),
             warn_words=missing),
        Case("odd-box-file-rate", "odd", _copy("box-file-rate", None)),
        Case("odd-box-group-missing", "odd", _copy("box-group-missing", "gt1r/bckgrd_atlas"),
             warn_words=missing),
    ]
