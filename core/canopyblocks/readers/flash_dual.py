"""Read flash-lidar (ESFL) cubes and dual-wavelength waveform pairs, and tell the
waveform products apart.

The two layouts are those ``canopyblocks simulate --sensor esfl|dual`` writes
(:mod:`canopyblocks.simulate.sensor_files`): an HDF5 file whose root attribute ``sensor``
is ``"esfl"`` or ``"dual"``. :func:`waveform_product` is what ``canopyblocks waveforms``,
``run`` and the QGIS algorithm ask first: ``"GEDI L1B"``, ``"ESFL"`` or ``"dual"``.

Positions are in the file's CRS (attribute ``crs``, metres); elevations in its vertical
datum (attribute ``vertical_datum``; ``unknown`` when the file states none).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import CanopyBlocksWarning, FileFormatError
from ._h5 import _looks_like_hdf5, open_h5

__all__ = ["WaveformProduct", "EsflFile", "DualFile", "waveform_product", "read_esfl_file",
           "read_dual_file", "flash_dual_sensor", "flash_dual_file_info",
           "refuse_unlabelled", "MAX_ELEVATION_M", "MIN_ELEVATION_M"]

WaveformProduct = Literal["GEDI L1B", "ESFL", "dual"]

MAX_ELEVATION_M = 9_000.0
"""Highest plausible top of an elevation window (m; Everest is 8,849 m)."""
MIN_ELEVATION_M = -1_000.0
"""Lowest plausible bottom of an elevation window (m; the Dead Sea shore is at -430 m)."""


@dataclass(frozen=True)
class EsflFile:
    """One flight line of flash-lidar cubes as read from a file (see the module).

    ``cubes`` (footprints, rows, cols, bins): bin k of footprint i centred on
    ``top[i] - k * bin_size`` (m); ``x``, ``y`` footprint centres (m, ``crs``); ``along``
    the track's unit vector; ``pixel_size`` (m); ``truth`` the file's truth columns
    (``ground``, ``top``, ``height``, m) when it has them, else None.
    """

    cubes: np.ndarray
    top: np.ndarray
    x: np.ndarray
    y: np.ndarray
    along: tuple[float, float]
    bin_size: float
    pixel_size: float
    crs: str
    vertical_datum: str
    truth: dict[str, np.ndarray] | None


@dataclass(frozen=True)
class DualFile:
    """Visible and near-infrared waveform pairs as read from a file (see the module).

    ``visible``, ``nir`` (footprints, bins): sample k of footprint i centred on
    ``top[i] - k * bin_size`` (m); per band the noise mean and sd the file states
    (``noise_mean``, ``noise_sd``: (visible, nir) pairs of per-footprint arrays);
    ``noise``: the simulated noise sd as a share of the near-infrared peak.
    """

    visible: np.ndarray
    nir: np.ndarray
    top: np.ndarray
    x: np.ndarray
    y: np.ndarray
    noise_mean: tuple[np.ndarray, np.ndarray]
    noise_sd: tuple[np.ndarray, np.ndarray]
    bin_size: float
    noise: float
    crs: str
    vertical_datum: str
    truth: dict[str, np.ndarray] | None


def waveform_product(path: str | os.PathLike[str]) -> WaveformProduct:
    """The waveform product of ``path``: ``"GEDI L1B"``, ``"ESFL"`` or ``"dual"``.

    Raises
    ------
    FileFormatError
        Missing, not HDF5, or none of the three (the message names what the file holds).
    """
    from ..arguments import check_path
    from .gedi import is_gedi_l1b

    p = check_path(path, "waveform file")
    if not p.exists():
        from .remote import missing_message
        raise FileFormatError(missing_message(path))
    if not _looks_like_hdf5(p):
        raise FileFormatError(f"{p}: not HDF5; `canopyblocks waveforms` reads GEDI L1B, "
                              "flash-lidar (ESFL) cubes and dual-wavelength pairs")
    with open_h5(p, "waveform file") as f:
        sensor = str(f.attr("/", "sensor", "") or "").strip().lower()
        keys = f.keys()
    if sensor == "esfl":
        return "ESFL"
    if sensor == "dual":
        return "dual"
    if is_gedi_l1b(p):
        return "GEDI L1B"
    refuse_unlabelled(p, keys)
    raise FileFormatError(
        f"{p}: HDF5 file but not GEDI L1B (BEAMxxxx/rxwaveform), flash-lidar cubes or "
        f"dual-wavelength pairs (root attribute sensor = esfl | dual, as `canopyblocks "
        f"simulate --sensor esfl|dual` writes); top-level groups: {', '.join(keys) or 'none'}"
        + ("; photons (ATL03, MABEL) go through `canopyblocks blocks`"
           if any(k.startswith(("gt", "photon")) for k in keys) else ""))


def refuse_unlabelled(path: str | os.PathLike[str], keys: list[str] | None = None) -> None:
    """Refuse an HDF5 file that holds ESFL cubes or dual-wavelength pairs but lacks the root
    attribute ``sensor`` that names them (the message names the product, not GEDI).

    Raises
    ------
    FileFormatError
        The file has ``cubes`` (ESFL) or ``visible`` and ``nir`` (dual) and no ``sensor``.
    """
    p = Path(path)
    if keys is None:
        try:
            if not (p.is_file() and _looks_like_hdf5(p)):
                return
            with open_h5(p, "waveform file") as f:
                if str(f.attr("/", "sensor", "") or "").strip():
                    return
                keys = f.keys()
        except (FileFormatError, OSError):
            return
    what = ("flash-lidar (ESFL) cubes" if "cubes" in keys else "dual-wavelength pairs"
            if {"visible", "nir"} <= set(keys) else None)
    if what is not None:
        tag = "esfl" if "cubes" in keys else "dual"
        raise FileFormatError(
            f"{p}: holds {what} but lacks the root attribute sensor = {tag!r} that names "
            "them (as `canopyblocks simulate` writes it); restore it (e.g. h5py: "
            f"f.attrs['sensor'] = {tag!r}) after checking the file is what it seems")


def _numbers(f: object, name: str, path: Path, product: str) -> np.ndarray:
    """Dataset ``name`` as float64, refused when stored as integers (rounded or clipped
    energy), text, or holding infinities."""
    dt = f.dtype(name)  # type: ignore[attr-defined]
    if dt.kind in "iub":
        lim = f" (clipped at {np.iinfo(dt).max})" if dt.kind in "iu" else ""
        raise FileFormatError(
            f"{path}: {product} dataset {name} is stored as {dt}{lim}, not floating point: "
            "rounded or clipped energy gives wrong heights; write it as float32, as "
            "`canopyblocks simulate` does")
    if dt.kind != "f":
        raise FileFormatError(f"{path}: {product} dataset {name} holds {dt} values, not "
                              "numbers; the file is damaged or not such a file")
    arr = f.read(name, dtype=np.float64)  # type: ignore[attr-defined]
    n_inf = int(np.count_nonzero(np.isinf(arr)))
    if n_inf:
        raise FileFormatError(f"{path}: {product} dataset {name} holds {n_inf} infinite "
                              "values; the file is damaged (write it again)")
    return arr


def _check_window(path: Path, product: str, top: np.ndarray, n_bins: int,
                  bin_size: float) -> None:
    """Refuse elevation windows no land surface can be in (non-finite, above
    ``MAX_ELEVATION_M`` or reaching below ``MIN_ELEVATION_M``)."""
    bottom = top - n_bins * bin_size
    bad = ~np.isfinite(top) | (top > MAX_ELEVATION_M) | (bottom < MIN_ELEVATION_M)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise FileFormatError(
            f"{path}: {product}: {int(bad.sum())} of {top.size} footprints have an elevation "
            f"window from {bottom[i]:,.1f} to {top[i]:,.1f} m, outside any land surface "
            f"({MIN_ELEVATION_M:,.0f} to {MAX_ELEVATION_M:,.0f} m); the file's top is "
            "damaged or in other units")


def _drop_nan_footprints(path: Path, product: str, data: np.ndarray) -> np.ndarray:
    """Footprints (first axis) whose samples are all finite; a warning names the others,
    a refusal when none is left."""
    good = np.isfinite(data.reshape(data.shape[0], -1)).all(axis=1)
    if good.all():
        return good
    if not good.any():
        raise FileFormatError(f"{path}: {product}: every footprint holds NaN samples; "
                              "nothing can be measured")
    warnings.warn(f"{path}: {product}: {int((~good).sum())} of {good.size} footprints hold "
                  "NaN samples (missing data) and are left out", CanopyBlocksWarning,
                  stacklevel=3)
    return good


def _need(f: object, names: tuple[str, ...], path: Path, what: str) -> None:
    missing = [n for n in names if not f.is_dataset(n)]  # type: ignore[attr-defined]
    if missing:
        raise FileFormatError(f"{path}: {what} file lacks dataset(s) {', '.join(missing)}; "
                              "it is damaged or not written by `canopyblocks simulate`")


def _strings(f: object) -> tuple[str, str]:
    crs = str(f.attr("/", "crs", "") or "")  # type: ignore[attr-defined]
    vd = str(f.attr("/", "vertical_datum", "") or "").strip() or "unknown"  # type: ignore[attr-defined]
    return crs, vd


def _positive(value: object, name: str, path: Path) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        v = float("nan")
    if not (np.isfinite(v) and v > 0):
        raise FileFormatError(f"{path}: attribute {name} must be a positive number of "
                              f"metres; got {value!r}")
    return v


def read_esfl_file(path: str | os.PathLike[str]) -> EsflFile:
    """Flash-lidar cubes of one flight line (layout of the module docstring).

    Raises
    ------
    FileFormatError
        Not such a file, or a dataset missing or of the wrong shape.
    """
    p = Path(path)
    with open_h5(p, "flash-lidar cubes") as f:
        _need(f, ("cubes", "top", "x", "y"), p, "flash-lidar")
        cubes = _numbers(f, "cubes", p, "flash-lidar (ESFL)")
        top, x, y = (_numbers(f, k, p, "flash-lidar (ESFL)") for k in ("top", "x", "y"))
        along = np.asarray(f.attr("/", "along", (1.0, 0.0)), float).reshape(-1)
        bin_size = _positive(f.attr("/", "bin_size"), "bin_size", p)
        pixel_size = _positive(f.attr("/", "pixel_size"), "pixel_size", p)
        crs, vd = _strings(f)
        truth = ({k: f.read(f"truth/{k}", dtype=np.float64) for k in ("ground", "top", "height")}
                 if all(f.is_dataset(f"truth/{k}") for k in ("ground", "top", "height"))
                 else None)
    n = cubes.shape[0] if cubes.ndim == 4 else -1
    if n < 0 or any(a.shape != (n,) for a in (top, x, y)) or along.size != 2:
        raise FileFormatError(f"{p}: flash-lidar cubes must be (footprints, rows, cols, bins) "
                              f"with one top, x and y per footprint; got cubes {cubes.shape}")
    norm = float(np.hypot(*along))
    if not norm > 0:
        raise FileFormatError(f"{p}: attribute along is not a direction: {along.tolist()}")
    _check_window(p, "flash-lidar (ESFL)", top, cubes.shape[3], bin_size)
    good = _drop_nan_footprints(p, "flash-lidar (ESFL) cubes", cubes)
    out = EsflFile(cubes, top, x, y, (float(along[0] / norm), float(along[1] / norm)),
                   bin_size, pixel_size, crs, vd, truth)
    if good.all():
        return out
    return replace(out, cubes=cubes[good], top=top[good], x=x[good], y=y[good],
                   truth=None if truth is None else {k: v[good] for k, v in truth.items()})


def read_dual_file(path: str | os.PathLike[str]) -> DualFile:
    """Dual-wavelength waveform pairs (layout of the module docstring).

    Raises
    ------
    FileFormatError
        Not such a file, or a dataset missing or of the wrong shape.
    """
    p = Path(path)
    names = ("visible", "nir", "top", "x", "y", "noise_mean_visible", "noise_mean_nir",
             "noise_sd_visible", "noise_sd_nir")
    with open_h5(p, "dual-wavelength pairs") as f:
        _need(f, names, p, "dual-wavelength")
        d = {k: _numbers(f, k, p, "dual-wavelength") for k in names}
        bin_size = _positive(f.attr("/", "bin_size"), "bin_size", p)
        noise = float(f.attr("/", "noise", np.nan))  # type: ignore[arg-type]
        crs, vd = _strings(f)
        truth = ({k: f.read(f"truth/{k}", dtype=np.float64) for k in ("ground", "cover")}
                 if f.is_dataset("truth/ground") and f.is_dataset("truth/cover") else None)
    vis, nir = d["visible"], d["nir"]
    n = vis.shape[0] if vis.ndim == 2 else -1
    if n < 0 or nir.shape != vis.shape or any(d[k].shape != (n,) for k in names[2:]):
        raise FileFormatError(f"{p}: visible and nir must be (footprints, bins) arrays of one "
                              f"shape with one value per footprint in the others; got "
                              f"{vis.shape} and {nir.shape}")
    for k in ("noise_sd_visible", "noise_sd_nir"):
        if (d[k] < 0).any():
            raise FileFormatError(f"{p}: dual-wavelength: {k} is negative in "
                                  f"{int((d[k] < 0).sum())} footprints; a noise level cannot "
                                  "be, the file is damaged")
    _check_window(p, "dual-wavelength", d["top"], vis.shape[1], bin_size)
    good = _drop_nan_footprints(p, "dual-wavelength pairs", np.concatenate([vis, nir], 1))
    d = {k: v[good] for k, v in d.items()}
    if truth is not None:
        truth = {k: v[good] for k, v in truth.items()}
    return DualFile(d["visible"], d["nir"], d["top"], d["x"], d["y"],
                    (d["noise_mean_visible"], d["noise_mean_nir"]),
                    (d["noise_sd_visible"], d["noise_sd_nir"]), bin_size, noise, crs, vd,
                    truth)


def flash_dual_sensor(path: str | os.PathLike[str]) -> str | None:
    """``"esfl"`` or ``"dual"`` when ``path`` is such a file (its root attribute
    ``sensor``), else None (never raises)."""
    try:
        p = Path(path)
        if not (p.is_file() and _looks_like_hdf5(p)):
            return None
        with open_h5(p) as f:
            sensor = str(f.attr("/", "sensor", "") or "").strip().lower()
    except (FileFormatError, OSError):
        return None
    return sensor if sensor in ("esfl", "dual") else None


def flash_dual_file_info(path: str | os.PathLike[str]) -> dict[str, object]:
    """What ``canopyblocks info`` prints for ESFL cubes or dual-wavelength pairs."""
    p = Path(path)
    sensor = flash_dual_sensor(p)
    name = "datasets"
    with open_h5(p, "waveform file") as f:
        crs, vd = _strings(f)
        name = "cubes" if sensor == "esfl" else "visible"
        shape = f.shape(name) if f.is_dataset(name) else ()
        noise = f.attr("/", "noise")
    product = ("ESFL flash-lidar cubes" if sensor == "esfl"
               else "dual-wavelength waveform pairs")
    info: dict[str, object] = {"path": str(p), "product": product,
                               "n_shots": int(shape[0]) if shape else 0,
                               "crs": crs or None, "vertical_datum": vd,
                               "note": "process with `canopyblocks waveforms` (or `run "
                                       "--photons`)"}
    if noise is not None:
        info["noise"] = noise
    return info
