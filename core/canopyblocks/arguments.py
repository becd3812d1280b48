"""Checks of a public function's arguments at the door, one line each.

Every check raises :class:`~canopyblocks.errors.InputError` (also a ``ValueError``) with
one line naming the argument, what is allowed and what was received, e.g.
``process_waveforms: batch must be a WaveformBatch (read_gedi_l1b or the simulator); got
None``. Checks return the value in the form the function uses (a ``Path``, a float, an
array), so a function's first lines read ``path = check_path(path, "read_table: path")``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from .errors import InputError

__all__ = ["describe", "check_path", "check_source", "check_paths", "check_instance", "check_frame",
           "check_array", "check_number", "check_mapping", "check_choice"]

T = TypeVar("T")


def describe(value: object) -> str:
    """A short, one-line account of a received value (type and a clipped repr)."""
    if value is None:
        return "None"
    if isinstance(value, np.ndarray):
        return f"a numpy array of shape {value.shape} ({value.dtype})"
    if isinstance(value, (list, tuple, set, dict)):
        n = len(value)
        return f"a {type(value).__name__} of {n} item{'s' if n != 1 else ''}" + (
            f" {_clip(repr(value))}" if n <= 4 else "")
    if hasattr(value, "shape") and hasattr(value, "columns"):
        return f"a {type(value).__name__} of {len(value)} rows"  # type: ignore[arg-type]
    return f"{type(value).__name__} {_clip(repr(value))}"


def _clip(text: str, n: int = 60) -> str:
    text = " ".join(text.split())
    return text if len(text) <= n else text[: n - 3] + "..."


def _fail(name: str, what: str, value: object) -> InputError:
    return InputError(f"{name} must be {what}; got {describe(value)}")


def _is_pathlike(value: object) -> bool:
    return (isinstance(value, str) and value.strip() != "") or isinstance(value, os.PathLike)


def check_path(value: object, name: str, what: str = "a file path (str or pathlib.Path)"
               ) -> Path:
    """``value`` as a :class:`~pathlib.Path`; refuses None, numbers, sequences, ''."""
    if not _is_pathlike(value):
        raise _fail(name, what, value)
    return Path(value)  # type: ignore[arg-type]


def check_source(value: object, name: str,
                 what: str = "a file path, an s3:// or https:// URL, or an open binary file"
                 ) -> Any:
    """A granule as given: a path or URL (str, ``os.PathLike``) or an open binary file object
    (``read`` and ``seek``, such as ``earthaccess.open`` returns); refuses None, numbers, ''."""
    if _is_pathlike(value) or (
            not isinstance(value, (str, bytes)) and callable(getattr(value, "read", None))
            and callable(getattr(value, "seek", None))):
        return value
    raise _fail(name, what, value)


def check_paths(value: object, name: str,
                what: str = "a file path or a non-empty list of file paths") -> list[Path]:
    """One path or a non-empty sequence of paths, as a list of :class:`~pathlib.Path`."""
    if _is_pathlike(value):
        return [Path(value)]  # type: ignore[arg-type]
    if (isinstance(value, Sequence) and not isinstance(value, (str, bytes)) and len(value)
            and all(_is_pathlike(v) for v in value)):
        return [Path(v) for v in value]
    raise _fail(name, what, value)


def check_instance(value: T, types: type | tuple[type, ...], name: str,
                   what: str | None = None) -> T:
    """``value`` itself when it is an instance of ``types``."""
    if isinstance(value, types) and not (isinstance(value, bool) and bool not in
                                         (types if isinstance(types, tuple) else (types,))):
        return value
    if what is None:
        names = [t.__name__ for t in (types if isinstance(types, tuple) else (types,))]
        what = "a " + " or ".join(names)
    raise _fail(name, what, value)


def check_frame(value: Any, name: str, what: str = "a table (pandas DataFrame)",
                columns: Sequence[str] = ()) -> Any:
    """A pandas (Geo)DataFrame holding ``columns``."""
    import pandas as pd

    if not isinstance(value, pd.DataFrame):
        raise _fail(name, what, value)
    missing = [c for c in columns if c not in value.columns]
    if missing:
        raise InputError(f"{name} lacks the column{'s' if len(missing) > 1 else ''} "
                         f"{', '.join(missing)}; got a table with "
                         f"{', '.join(map(str, list(value.columns)[:12])) or 'no columns'}")
    return value


def check_array(value: object, name: str, *, ndim: int = 1, what: str | None = None,
                scalar: bool = False, size: int | None = None) -> np.ndarray:
    """A numeric array of ``ndim`` dimensions (with ``scalar``, a number counts as 1-D)."""
    what = what or f"a {ndim}-D array of numbers"
    if value is None or isinstance(value, (str, bytes, Mapping)):
        raise _fail(name, what, value)
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        raise _fail(name, what, value) from None
    if scalar and ndim == 1 and arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim != ndim or arr.dtype.kind not in "iuf" or (size is not None and
                                                          arr.size != size):
        raise _fail(name, what, value)
    return arr


def check_number(value: object, name: str, *, minimum: float | None = None,
                 maximum: float | None = None, above: float | None = None,
                 integer: bool = False, unit: str = "") -> float:
    """A finite real number (an integer with ``integer``) within the bounds given."""
    kinds: tuple[type, ...] = (int, np.integer) if integer else (int, float, np.integer,
                                                                 np.floating)
    parts = ["an integer" if integer else "a finite number"]
    if above is not None:
        parts.append(f"> {above:g}{unit}")
    if minimum is not None:
        parts.append(f">= {minimum:g}{unit}")
    if maximum is not None:
        parts.append(f"<= {maximum:g}{unit}")
    what = " ".join(parts)
    if isinstance(value, bool) or not isinstance(value, kinds):
        raise _fail(name, what, value)
    v = float(value)  # type: ignore[arg-type]
    if not math.isfinite(v) or (above is not None and not v > above) or \
            (minimum is not None and v < minimum) or (maximum is not None and v > maximum):
        raise _fail(name, what, value)
    return v


def check_mapping(value: object, name: str, what: str, value_types: type | tuple[type, ...]
                  | None = None) -> Mapping[Any, Any]:
    """A mapping (whose values are ``value_types`` when given)."""
    if not isinstance(value, Mapping) or (value_types is not None and not all(
            isinstance(v, value_types) for v in value.values())):
        raise _fail(name, what, value)
    return value


def check_choice(value: object, name: str, choices: Sequence[str]) -> str:
    """One of ``choices`` (strings)."""
    if not isinstance(value, str) or value not in choices:
        raise _fail(name, "one of " + ", ".join(repr(c) for c in choices), value)
    return value


def check_optional(value: T, types: type | tuple[type, ...], name: str,
                   what: str | None = None) -> T:
    """None, or an instance of ``types`` (see :func:`check_instance`)."""
    return value if value is None else check_instance(value, types, name, what)


def check_path_or_frame(value: object, name: str, what: str) -> Any:
    """A path, or a pandas DataFrame already in memory."""
    import pandas as pd

    if isinstance(value, pd.DataFrame):
        return value
    return check_path(value, name, what)


def check_lonlat(lon: np.ndarray, lat: np.ndarray, name: str) -> None:
    """Refuse finite latitudes beyond +-90 or longitudes beyond +-180 degrees, saying so
    when the two look swapped."""
    with np.errstate(invalid="ignore"):
        bad_lat = np.isfinite(lat) & (np.abs(lat) > 90.0)
        bad_lon = np.isfinite(lon) & (np.abs(lon) > 180.0)
    if not (bad_lat.any() or bad_lon.any()):
        return
    lo, la = lon[np.isfinite(lon)], lat[np.isfinite(lat)]
    span = (f"lat {la.min():.6g}..{la.max():.6g}, lon {lo.min():.6g}..{lo.max():.6g}"
            if lo.size and la.size else "")
    swapped = bad_lat.any() and not bad_lon.any() and lo.size and \
        bool(np.all(np.abs(lo) <= 90.0))
    hint = ("; lat and lon look swapped: give lat, then lon" if swapped
            else "; give degrees WGS84")
    raise InputError(f"{name}: {int(bad_lat.sum())} latitudes beyond +-90 and "
                     f"{int(bad_lon.sum())} longitudes beyond +-180 degrees ({span}){hint}")


def check_metres_not_degrees(x: np.ndarray, y: np.ndarray, lon: np.ndarray,
                             lat: np.ndarray, crs: Any, name: str) -> None:
    """Refuse metric positions that are degrees: every x within +-180 and y within +-90,
    spanning at most 2 units each way (a track of degrees: up to ~200 km) and not all whole
    numbers (hand-made grids), while the positions they give lie outside the CRS's area
    of use."""
    fx, fy = x[np.isfinite(x)], y[np.isfinite(y)]
    if not fx.size or np.abs(fx).max() > 180.0 or np.abs(fy).max() > 90.0 or \
            np.ptp(fx) > 2.0 or np.ptp(fy) > 2.0 or \
            (np.all(fx == np.round(fx)) and np.all(fy == np.round(fy))):
        return
    area = getattr(crs, "area_of_use", None)
    fin = np.isfinite(lon) & np.isfinite(lat)
    if area is not None and fin.any():
        margin = 1.0
        inside = ((lon[fin] >= area.west - margin) & (lon[fin] <= area.east + margin)
                  & (lat[fin] >= area.south - margin) & (lat[fin] <= area.north + margin))
        if inside.all():
            return
    code = crs.to_string() if hasattr(crs, "to_string") else str(crs)
    raise InputError(
        f"{name}: x {fx.min():.6g}..{fx.max():.6g}, y {fy.min():.6g}..{fy.max():.6g} look "
        f"like degrees, but {code} is in metres (these would lie {fx.max() - fx.min():.3g} "
        "m apart, outside the CRS's area); give metres, or use from_lonlat for degrees")


def check_reference_metres(est: np.ndarray, ref: np.ndarray, est_name: str,
                           ref_name: str, name: str) -> None:
    """Refuse a reference whose heights are about 100 times the estimates' (centimetres)."""
    ok = np.isfinite(est) & np.isfinite(ref) & (np.abs(est) > 1.0)
    if ok.sum() < 3:
        return
    ratio = float(np.median(ref[ok] / est[ok]))
    med = float(np.median(ref[ok]))
    if 30.0 <= ratio <= 300.0 and med > 150.0:
        raise InputError(
            f"{name}: {ref_name} has a median of {med:.4g} against {est_name} "
            f"{float(np.median(est[ok])):.4g} (ratio {ratio:.3g}): taller than any tree; "
            "the reference looks like centimetres -- give heights in metres")


def check_fields(obj: Any) -> None:
    """Check a parameter dataclass's fields against their annotations, at the top of its
    ``__post_init__``: ``float`` a real number (not NaN), ``int`` an integer, ``bool`` a
    bool, ``str`` a string, a ``Literal`` name a string (which one is the class's to
    judge), ``tuple[float, ...]`` no mapping and numbers inside, a nested parameter class
    an instance of it; each may be None when annotated ``| None`` or defaulting to None."""
    import dataclasses
    import typing

    try:
        hints = typing.get_type_hints(type(obj))
    except Exception:  # noqa: BLE001 - unresolvable annotations: nothing to check here
        return
    cls = type(obj).__name__
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if not f.init or f.name not in hints or (value is None and f.default is None):
            continue
        _check_field(value, hints[f.name], f"{cls}: {f.name}")


def _check_field(value: object, hint: Any, name: str) -> None:
    import types
    import typing

    args = typing.get_args(hint)
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return
        rest = [a for a in args if a is not type(None)]
        if len(rest) == 1:
            _check_field(value, rest[0], name)
        return
    if hint is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise _fail(name, "True or False", value)
    elif hint is int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise _fail(name, "an integer", value)
    elif hint is float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(
                value, (int, float, np.integer, np.floating)) or math.isnan(float(value)):
            raise _fail(name, "a number", value)
    elif hint is str:
        if not isinstance(value, str):
            raise _fail(name, "a string", value)
    elif origin is typing.Literal:   # a string is the class's to judge (its own message)
        if not isinstance(value, str):
            raise _fail(name, "one of " + ", ".join(repr(a) for a in args), value)
    elif isinstance(hint, type) and hasattr(hint, "__dataclass_fields__"):
        if not isinstance(value, hint):
            raise _fail(name, f"a {hint.__name__}", value)
    elif origin is tuple and len(args) == 2 and args[1] is Ellipsis and args[0] in (int, float):
        # one length and strings are the class's to judge; mappings and sets never fit, nor
        # anything but a sequence for integers (class codes)
        if isinstance(value, (Mapping, set)) or (args[0] is int and not isinstance(
                value, (list, tuple, np.ndarray))):
            raise _fail(name, f"a sequence of {args[0].__name__}s", value)
        if isinstance(value, (list, tuple, np.ndarray)):
            for v in value:
                _check_field(v, args[0], name)
        elif not isinstance(value, (str, bytes)):   # one number: a number (not NaN)
            _check_field(value, args[0], name)
