"""The Python API's door: every public function re-exported from ``canopyblocks`` answers
misuse (None, numbers for paths and tables, strings for numbers, lists, dicts, arrays of
the wrong shape, NaN) with the project's own error -- one line naming what was received
-- never with a TypeError/AttributeError/ValueError from deep inside; and plausibility
where units are stated (an upside-down waveform, swapped lat/lon, degrees given as
metres, a reference in centimetres)."""

from __future__ import annotations

import signal
import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from canopyblocks.errors import CanopyBlocksError, InputError  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from badinputs.api_corpus import MISUSE, VALID, public_functions, required  # noqa: E402


def _functions() -> list[tuple[str, Callable[..., Any]]]:
    return public_functions()


def _required(fn: Callable[..., Any]) -> tuple[int, list[str]]:
    return required(fn)


class _Hung(BaseException):
    pass


@contextmanager
def _limit(seconds: float) -> Iterator[None]:
    def hung(signum: int, frame: object) -> None:
        raise _Hung(f"no answer within {seconds:g} s")

    old = signal.signal(signal.SIGALRM, hung)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _call(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    result = fn(*args, **kwargs)
    if hasattr(result, "__enter__") and hasattr(result, "__exit__"):  # context managers
        with result:
            pass
    return result


def _refused(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> str:
    """The project's one-line refusal of the call (anything else fails the test)."""
    with _limit(20), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            result = _call(fn, *args, **kwargs)
        except CanopyBlocksError as exc:
            msg = str(exc)
            assert msg and "\n" not in msg.strip(), f"not one line: {msg!r}"
            return msg
        except _Hung:
            raise AssertionError("hung instead of refusing") from None
        except Exception as exc:  # noqa: BLE001 - the point of the test
            raise AssertionError(f"{type(exc).__name__} instead of the project's error: "
                                 f"{exc}") from None
    raise AssertionError(f"accepted: {type(result).__name__}")


CASES = [pytest.param(fn, kind, id=f"{name}-{kind}") for name, fn in _functions()
         for kind in MISUSE]


def test_the_walk_covers_the_api() -> None:
    assert len(_functions()) >= 50 and len(CASES) >= 28 * 7
    names = {n for n, _ in _functions()}
    assert {"PhotonTrack.from_xy", "PhotonTrack.from_lonlat", "Grid.from_bounds",
            "SimTrack.line"} <= names, names
    assert {"BlockParams", "EsflParams", "DualParams", "BatchConfig"} <= set(PARAM_CLASSES)


@pytest.mark.parametrize(("fn", "kind"), CASES)
def test_misuse_is_refused_at_the_door(fn, kind, tmp_path, monkeypatch, request) -> None:
    monkeypatch.chdir(tmp_path)   # a function that wrongly accepted "abc" writes here
    value = MISUSE[kind]
    pos, kw = _required(fn)
    args, kwargs = [value] * max(1, pos), dict.fromkeys(kw, value)
    if request.node.callspec.id in VALID:  # a valid call: a result, or the project's line
        with _limit(20), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                result = fn(*args, **kwargs)  # a context manager is not entered
            except CanopyBlocksError as exc:  # e.g. no pdal on this machine: said in one line
                assert str(exc) and "\n" not in str(exc).strip(), f"not one line: {exc!r}"
                return
        assert result is not None, f"{VALID[request.node.callspec.id]}: gave no result"
        return
    _refused(fn, *args, **kwargs)


# ---- the calls named in the issue, with otherwise valid arguments ---------------------------------


def _batch() -> Any:
    from canopyblocks.waveforms.batch import WaveformBatch

    n, m = 3, 200
    j = np.arange(m)
    wf = 230.0 + 150.0 * np.exp(-0.5 * ((j - 150) / 4.0) ** 2)
    top = np.full(n, 500.0)
    f = np.zeros(n, bool)
    return WaveformBatch(
        beam="BEAM0101", shot_number=np.arange(1, n + 1, dtype=np.uint64),
        time=np.arange(n, dtype=float), waveforms=np.tile(wf, (n, 1)).astype(np.float32),
        n_samples=np.full(n, m), elev_bin0=top, elev_lastbin=top - 0.1499 * (m - 1),
        lat_bin0=np.full(n, 45.0), lat_lastbin=np.full(n, 45.0), lon_bin0=np.full(n, 7.0),
        lon_lastbin=np.full(n, 7.0), noise_mean=np.full(n, 230.0), noise_sd=np.full(n, 3.0),
        stale=f, degraded=f, power="full")


def _track() -> Any:
    from canopyblocks import PhotonTrack

    rng = np.random.default_rng(0)
    x = np.linspace(500000.0, 500200.0, 400)
    return PhotonTrack.from_xy(x, np.full(400, 4000000.0), 100.0 + rng.normal(0, 1, 400),
                               crs="EPSG:32617")


def _blocks() -> pd.DataFrame:
    return pd.DataFrame({"track": ["t"] * 3, "length": [25.0] * 3, "block": [0, 1, 2],
                         "x": [500000.0, 500025.0, 500050.0], "y": [4e6] * 3,
                         "top": [120.0] * 3, "ground": [100.0] * 3, "hmax": [20.0] * 3,
                         "h90": [15.0] * 3, "z90": [115.0] * 3, "flag": ["ok"] * 3})


def test_named_calls() -> None:
    from canopyblocks import (
        apply_offset,
        coregister_file,
        estimate_blocks,
        fit_bias_calibration,
        preset,
        process_waveforms,
    )

    assert "batch" in _refused(process_waveforms, None)
    assert "params" in _refused(process_waveforms, _batch(), params="a1")
    assert "a1" in _refused(process_waveforms, _batch(), params="a1")
    assert "path" in _refused(coregister_file, None, "dtm.tif")
    assert "offset" in _refused(apply_offset, _blocks(), {"east": 1.0})
    assert "residuals" in _refused(fit_bias_calibration, None)
    assert "icesat2" in _refused(preset, ["icesat2"])
    assert "params" in _refused(estimate_blocks, _track(), {"ground": "mean"})
    assert "estimators" in _refused(estimate_blocks, _track(), None, {"ground": "mean"})


# ---- plausibility where the units are stated ---------------------------------------------------------


def test_upside_down_waveforms_are_refused() -> None:
    from dataclasses import replace

    from canopyblocks import process_waveforms

    b = _batch()
    flipped = replace(b, elev_bin0=b.elev_lastbin, elev_lastbin=b.elev_bin0)
    msg = _refused(process_waveforms, flipped)
    assert "elev_bin0" in msg and "below" in msg, msg
    good = process_waveforms(b)             # the same shots the right way up
    assert (good["flag"] == "ok").all()
    # the pulse at sample 150 lies 150 samples below the top: known ground
    np.testing.assert_allclose(good["ground"], 500.0 - 150 * 0.1499, atol=0.08)


def test_swapped_lat_lon_is_refused() -> None:
    from canopyblocks import PhotonTrack

    lat = np.linspace(45.0, 45.01, 50)
    lon = np.full(50, -120.0)
    msg = _refused(PhotonTrack.from_lonlat, np.arange(50.0), lon, lat, np.zeros(50),
                   track="t")   # lat and lon passed the wrong way round
    assert "swapped" in msg and "-120" in msg, msg


def test_degrees_given_as_metres_are_refused() -> None:
    from canopyblocks import PhotonTrack

    lon = np.linspace(-80.50, -80.49, 50)
    lat = np.linspace(35.00, 35.01, 50)
    msg = _refused(PhotonTrack.from_xy, lon, lat, np.zeros(50), crs="EPSG:32617")
    assert "degrees" in msg and "EPSG:32617" in msg, msg
    t = PhotonTrack.from_xy(np.linspace(500000, 500100, 50), np.full(50, 3.9e6),
                            np.zeros(50), crs="EPSG:32617")   # metres: accepted
    assert len(t) == 50


def test_reference_in_centimetres_is_refused() -> None:
    from canopyblocks import fit_bias_calibration

    rng = np.random.default_rng(1)
    n = 40
    est = rng.uniform(10, 30, n)
    table = pd.DataFrame({"track": "gt1r", "length": 25.0, "block": np.arange(n),
                          "hmax": est, "h90": est * 0.8, "use": True,
                          "ref_hmax": (est + rng.normal(0, 1, n)) * 100.0,
                          "ref_h90": (est * 0.8 + rng.normal(0, 1, n)) * 100.0})
    msg = _refused(fit_bias_calibration, table)
    assert "centimetres" in msg and "ref_hmax" in msg, msg
    metres = table.assign(ref_hmax=table["ref_hmax"] / 100, ref_h90=table["ref_h90"] / 100)
    cal = fit_bias_calibration(metres)                   # the same in metres: fitted
    assert cal.models and all(abs(m.slope - 1.0) < 0.2 or m.slope == 1.0 for m in cal.models)


def test_messages_name_what_was_received() -> None:
    from canopyblocks import read_las

    msg = _refused(read_las, 42)
    assert "42" in msg and "path" in msg, msg
    assert isinstance(InputError("x"), ValueError)


# ---- parameter objects: every field checked against its annotation ------------------------------

def _param_classes() -> tuple[str, ...]:
    """Every public parameter set: the ``...Params`` dataclasses, BatchConfig, Estimators."""
    import dataclasses

    import canopyblocks

    return tuple(n for n in canopyblocks.__all__
                 if dataclasses.is_dataclass(getattr(canopyblocks, n))
                 and (n.endswith("Params") or n in ("BatchConfig", "Estimators")))


PARAM_CLASSES = _param_classes()
FIELD_MISUSE = {"str": "abc", "list": [1, 2], "dict": {"a": 1}, "nan": float("nan")}


def _field_cases() -> list[Any]:
    import dataclasses

    import canopyblocks

    out = []
    for cname in PARAM_CLASSES:
        cls = getattr(canopyblocks, cname)
        for f in dataclasses.fields(cls):
            if not f.init:
                continue
            for kind in FIELD_MISUSE:
                out.append(pytest.param(cls, f.name, kind, id=f"{cname}-{f.name}-{kind}"))
    return out


#: Fields whose misuse value is a valid setting (value: why).
VALID_FIELDS = {
    "BatchConfig-geoid-str": "'abc' is a geoid file name, checked when the batch runs",
    "BatchConfig-photon_vcrs-str": "a CRS name, checked when the batch runs",
    "BatchConfig-reference_vcrs-str": "a CRS name, checked when the batch runs",
    "Estimators-name-str": "a label",
    "BlockParams-lengths-list": "block lengths of 1 and 2 m",
    "BatchConfig-lengths-list": "block lengths of 1 and 2 m",
    "SimParams-exclude_classes-list": "ASPRS classes 1 and 2",
    "FootprintReferenceParams-exclude_classes-list": "ASPRS classes 1 and 2",
}


@pytest.mark.parametrize(("cls", "field", "kind"), _field_cases())
def test_parameter_fields_are_checked(cls, field, kind, request) -> None:
    if request.node.callspec.id in VALID_FIELDS:
        cls(**{field: FIELD_MISUSE[kind]})
        return
    msg = _refused(cls, **{field: FIELD_MISUSE[kind]})
    assert field.rstrip("s") in msg.replace(" ", "_"), msg   # (lengths: "block length")
