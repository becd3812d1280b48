"""Corpus cases of odd inputs that gave silent wrong numbers: an option the estimators do not
use (``min_signal_conf`` with the ATL08-style classifier), an ATL03 without its
``bckgrd_atlas`` (subsetters drop it), a box read whose background must be the whole
track's; damaged flash-lidar (ESFL) cubes and dual-wavelength pairs (checked for
consistency as GEDI L1B files are: numbers stored as floats, no infinities, a plausible
elevation window, a noise level that is not negative, the sensor attribute naming them).

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


def _sensor(kind: str, damage: Callable[[Any], None]) -> Callable[[Path, Any], dict[str, Any]]:
    """A simulated ESFL or dual file of the conifer tile, damaged by ``damage(h5file)``."""
    def make(folder: Path, base: Any) -> dict[str, Any]:
        from canopyblocks.cli import cli
        from canopyblocks.cli.common import run_main

        p = folder / f"{kind}.h5"
        code = run_main(cli, ["-q", "simulate", str(base.conifer), "--sensor", kind,
                              "--azimuth", "0", "-o", str(p)])
        assert code == 0 and p.exists(), code
        with h5py.File(p, "r+") as f:
            damage(f)
        return {"path": p, "call": f"sensor-{kind}"}
    return make


def _rewrite(name: str, fn: Callable[[np.ndarray], np.ndarray]) -> Callable[[Any], None]:
    def damage(f: Any) -> None:
        data = fn(f[name][()])
        del f[name]
        f.create_dataset(name, data=data)
    return damage


def _half_nan(f: Any) -> None:
    c = f["cubes"][()]
    c[::2] = np.nan
    f["cubes"][...] = c


def run_odd(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks import BlockParams, blocks_from_file
    from canopyblocks.readers import read_atl03

    call = i["call"]
    if call.startswith("sensor-"):
        from canopyblocks.workflows.waveforms import footprints_to_file

        return footprints_to_file(i["path"], folder / "out" / "footprints.gpkg")
    if call.startswith("conf-"):
        return blocks_from_file(i["path"], BlockParams(min_signal_conf=2)).blocks
    if call.startswith("box-"):
        return read_atl03(i["path"], "gt1r", bbox=BOX)
    return blocks_from_file(i["path"], None).blocks


def check_odd(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    call = i["call"]
    assert not call.startswith("conf-"), f"{call}: an option the estimators ignore accepted"
    if call.startswith("sensor-"):  # accepted only with the damaged footprints left out
        assert case.warn_words and any(w in m for m in ws for w in case.warn_words), ws
        return
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
    cases = [
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
    esfl = "flash-lidar (ESFL)"
    sensor_cases = [
        ("esfl-cubes-inf", "esfl", lambda f: f["cubes"].__setitem__((0, 0, 0, 0), np.inf),
         ("infinite",)),
        ("esfl-cubes-text", "esfl", _rewrite("cubes", lambda c: np.full(c.shape[:1], b"abc")),
         ("not numbers",)),
        ("esfl-cubes-int8", "esfl",
         _rewrite("cubes", lambda c: np.clip(c, -128, 127).astype(np.int8)), ("int8",)),
        ("esfl-top-10km", "esfl", lambda f: f["top"].__setitem__(slice(None),
                                                                   f["top"][()] + 10_000),
         ("elevation window",)),
        ("esfl-no-sensor", "esfl", lambda f: f.attrs.__delitem__("sensor"), (esfl,)),
        ("dual-noise-sd-negative", "dual",
         lambda f: f["noise_sd_nir"].__setitem__(slice(None), -f["noise_sd_nir"][()]),
         ("negative",)),
        ("dual-int16", "dual", _rewrite("visible", lambda w: np.round(w).astype(np.int16)),
         ("int16",)),
        ("dual-no-sensor", "dual", lambda f: f.attrs.__delitem__("sensor"),
         ("dual-wavelength pairs",)),
    ]
    cases += [Case(f"odd-{name}", "odd", _sensor(kind, damage), needles=words,
                   must_refuse=True) for name, kind, damage, words in sensor_cases]
    cases.append(Case("odd-esfl-half-nan", "odd", _sensor("esfl", _half_nan),
                      warn_words=("NaN samples",)))
    return cases
