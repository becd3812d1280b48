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
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import FileFormatError
from ._h5 import _looks_like_hdf5, open_h5

__all__ = ["WaveformProduct", "EsflFile", "DualFile", "waveform_product", "read_esfl_file",
           "read_dual_file", "flash_dual_sensor", "flash_dual_file_info"]

WaveformProduct = Literal["GEDI L1B", "ESFL", "dual"]


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
    raise FileFormatError(
        f"{p}: HDF5 file but not GEDI L1B (BEAMxxxx/rxwaveform), flash-lidar cubes or "
        f"dual-wavelength pairs (root attribute sensor = esfl | dual, as `canopyblocks "
        f"simulate --sensor esfl|dual` writes); top-level groups: {', '.join(keys) or 'none'}"
        + ("; photons (ATL03, MABEL) go through `canopyblocks blocks`"
           if any(k.startswith(("gt", "photon")) for k in keys) else ""))


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
        cubes = f.read("cubes", dtype=np.float64)
        top, x, y = (f.read(k, dtype=np.float64) for k in ("top", "x", "y"))
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
    return EsflFile(cubes, top, x, y, (float(along[0] / norm), float(along[1] / norm)),
                    bin_size, pixel_size, crs, vd, truth)


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
        d = {k: f.read(k, dtype=np.float64) for k in names}
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
    return DualFile(vis, nir, d["top"], d["x"], d["y"],
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
