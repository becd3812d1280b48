"""Corpus cases of API misuse: every public function of ``canopyblocks`` (its ``__all__``)
called with each misuse value in every required argument; only the project's own
one-line error (or, for the few misuses that are valid calls, a result) is right.

Registered in :func:`badinputs.make_corpus.all_cases`; the runner ``api`` is added to the
corpus test's runners through :data:`RUNNERS`. ``tests/test_api_door.py`` runs the same
walk with the issue's named calls and the plausibility checks.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["MISUSE", "VALID", "public_functions", "required", "resolve", "api_cases", "RUNNERS"]

MISUSE: dict[str, Any] = {
    "None": None,
    "int": 42,
    "str": "abc",
    "list": [1, 2],
    "dict": {"a": 1},
    "array2d": np.zeros((2, 2)),
    "nan": float("nan"),
}

#: Misuse that is in fact a valid call (value: why), so a result is right.
VALID = {
    "along_track_distance-list": "x = y = [1, 2]: two points are a track",
    "error_stats-list": "[1, 2] against [1, 2]: two pairs of numbers",
    "utm_crs_for-int": "42 E, 42 N is a place",
    "utm_crs_for-list": "[1, 2] E, [1, 2] N are places",
    "default_cutoffs-int": "a 42 m block length",
    "find_pdal-None": "None: look for pdal where it is installed",
    "atomic_output-str": "'abc' is a file name to write (not entered here)",
    "PhotonTrack.from_lonlat-int": "one photon at 42 E 42 N, 42 m, time 42 s",
    "PhotonTrack.from_lonlat-list": "two photons at 1-2 E 1-2 N",
}


def public_functions() -> list[tuple[str, Callable[..., Any]]]:
    """Every function in ``canopyblocks.__all__`` and every class method of its classes
    that takes an argument (``PhotonTrack.from_xy``, ``Grid.from_bounds`` ...)."""
    import canopyblocks

    out = []
    for n in canopyblocks.__all__:
        obj = getattr(canopyblocks, n)
        if inspect.isfunction(obj):
            out.append((n, obj))
        elif inspect.isclass(obj) and not issubclass(obj, BaseException):
            for m, raw in vars(obj).items():
                fn = getattr(obj, m)
                if not m.startswith("_") and isinstance(raw, classmethod) and \
                        required(fn)[0] >= 1:
                    out.append((f"{n}.{m}", fn))
    return out


def resolve(name: str) -> Callable[..., Any]:
    """The public callable called ``name`` (``read_las`` or ``PhotonTrack.from_xy``)."""
    import canopyblocks

    obj: Any = canopyblocks
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj  # type: ignore[no-any-return]


def required(fn: Callable[..., Any]) -> tuple[int, list[str]]:
    """How many positional arguments, and which keyword-only ones, the function needs."""
    sig = inspect.signature(inspect.unwrap(fn))
    pos = sum(1 for p in sig.parameters.values() if p.default is p.empty
              and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD))
    kw = [p.name for p in sig.parameters.values() if p.default is p.empty
          and p.kind == p.KEYWORD_ONLY]
    return pos, kw


def _make(name: str, kind: str) -> Callable[[Path, Any], dict[str, Any]]:
    def make(folder: Path, base: Any) -> dict[str, Any]:
        return {"path": None, "function": name, "kind": kind}
    return make


def run_api(i: dict[str, Any], folder: Path) -> Any:
    import os

    fn = resolve(i["function"])
    value = MISUSE[i["kind"]]
    pos, kw = required(fn)
    here = os.getcwd()
    os.chdir(folder)   # a function that wrongly accepted "abc" writes here
    try:
        result = fn(*[value] * max(1, pos), **dict.fromkeys(kw, value))
        if hasattr(result, "__enter__") and f"{i['function']}-{i['kind']}" not in VALID:
            with result:
                pass
    finally:
        os.chdir(here)
    return result


def check_api(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    key = f"{i['function']}-{i['kind']}"
    assert key in VALID, f"{key}: accepted ({type(result).__name__})"


RUNNERS: dict[str, tuple[Callable[..., Any], Callable[..., None]]] = {
    "api": (run_api, check_api)}


def api_cases() -> list[Any]:
    from .make_corpus import Case

    return [Case(f"api-{name}-{kind}", "api", _make(name, kind))
            for name, _fn in public_functions() for kind in MISUSE]
