"""GEDI L2A (ground, RH, flags) and L2B (cover, PAI) as tables, joined by shot number.

For comparing the waveform processing with the official products and as a reference
layer. Heights in metres (WGS84 ellipsoid); L2A's per-setting ``geolocation/rh_aN`` are
stored in centimetres and converted; positions at the lowest mode (degrees WGS84).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from ..errors import FileFormatError, InputError
from ._h5 import H5File, open_h5

__all__ = ["read_gedi_l2a", "read_gedi_l2b", "l2a_has_setting", "L2A_SETTINGS"]

L2A_SETTINGS: tuple[str, ...] = ("a1", "a2", "a3", "a4", "a5", "a6")


def _beams(f: H5File, beams: Sequence[str] | str | None, need: str) -> list[str]:
    present = sorted(k for k in f.keys() if k.startswith("BEAM") and f.is_group(k))
    if not present:
        raise FileFormatError(f"{f.path}: no BEAMxxxx group; not a GEDI L2 file")
    if not beams:
        return [b for b in present if f.is_dataset(f"{b}/{need}")]
    wanted = [beams] if isinstance(beams, str) else list(beams)
    unknown = [b for b in wanted if b not in present]
    if unknown:
        raise InputError(f"{f.path}: no beam {', '.join(unknown)}; the file has "
                         f"{', '.join(present)}")
    return wanted


def _num(a: np.ndarray) -> np.ndarray:
    out = np.asarray(a, dtype=np.float64).copy()
    out[~np.isfinite(out) | (np.abs(out) > 1e30) | (out == -9999.0)] = np.nan
    return out


def _read(f: H5File, beam: str, name: str, n: int) -> np.ndarray:
    a = f.read(f"{beam}/{name}")
    if a.shape[0] != n:
        raise FileFormatError(f"{f.path}: {beam}/{name} holds {a.shape[0]} values but "
                              f"{beam}/shot_number holds {n}")
    return a


def _shot_columns(f: H5File, beam: str) -> tuple[int, dict[str, Any]]:
    """The beam's shot count and its ``beam`` and ``shot_number`` (int64) columns."""
    sn = f.read(f"{beam}/shot_number")
    n = sn.shape[0]
    return n, {"beam": np.full(n, beam, dtype=object),
               "shot_number": np.asarray(sn, dtype=np.uint64).astype(np.int64)}


def _bbox(df: pd.DataFrame, bbox: tuple[float, float, float, float] | None) -> pd.DataFrame:
    if bbox is None:
        return df
    lo, la = df["lon"].to_numpy(float), df["lat"].to_numpy(float)
    with np.errstate(invalid="ignore"):
        keep = (lo >= bbox[0]) & (lo <= bbox[2]) & (la >= bbox[1]) & (la <= bbox[3])
    return df[keep].reset_index(drop=True)


def l2a_has_setting(path: str | os.PathLike[str], setting: str) -> bool:
    """True when the L2A file holds the values of setting group ``setting`` (``geolocation/
    elev_lowestmode_aN``) in some beam; False for a file that holds only the selected
    algorithm's values (what subsetting services keep)."""
    if setting not in L2A_SETTINGS:
        raise InputError(f"setting must be one of {', '.join(L2A_SETTINGS)}; got {setting!r}")
    with open_h5(path) as f:
        beams = [k for k in f.keys() if k.startswith("BEAM") and f.is_group(k)]
        return any(f.is_dataset(f"{b}/geolocation/elev_lowestmode_{setting}") for b in beams)


def read_gedi_l2a(path: str | os.PathLike[str], beams: Sequence[str] | str | None = None, *,
                  setting: str | None = "a1",
                  bbox: tuple[float, float, float, float] | None = None) -> pd.DataFrame:
    """L2A ground, top and RH0-RH100 of every shot.

    Parameters
    ----------
    path : path
        GEDI L2A granule or subset.
    beams : str or sequence, optional
        Default every beam.
    setting : {"a1".."a6"} or None
        Setting group whose values to read (``geolocation/*_aN``, ``rh_aN`` in cm and
        ``rx_processing_aN/rx_algrunflag``); None: the product's selected algorithm
        (``elev_lowestmode``, ``rh`` in metres).
    bbox : (lon_min, lat_min, lon_max, lat_max), optional

    Returns
    -------
    DataFrame
        ``beam, shot_number (int64), lon, lat, ground, top, rh0 .. rh100 (m),
        quality_flag, degrade, sensitivity, algrunflag, selected_algorithm, setting``.
    """
    if setting is not None and setting not in L2A_SETTINGS:
        raise InputError(f"setting must be one of {', '.join(L2A_SETTINGS)} or None; "
                         f"got {setting!r}")
    frames = []
    with open_h5(path) as f:
        for beam in _beams(f, beams, "elev_lowestmode"):
            n, cols = _shot_columns(f, beam)
            if setting is None:
                lon = _read(f, beam, "lon_lowestmode", n)
                lat = _read(f, beam, "lat_lowestmode", n)
                ground = _read(f, beam, "elev_lowestmode", n)
                top = _read(f, beam, "elev_highestreturn", n)
                rh = _num(_read(f, beam, "rh", n))
                run = np.ones(n, dtype=np.int64)
            else:
                g = f"geolocation/{{}}_{setting}"
                lon = _read(f, beam, g.format("lon_lowestmode"), n)
                lat = _read(f, beam, g.format("lat_lowestmode"), n)
                ground = _read(f, beam, g.format("elev_lowestmode"), n)
                top = _read(f, beam, g.format("elev_highestreturn"), n)
                rh = _num(_read(f, beam, g.format("rh"), n)) / 100.0   # stored in cm
                run = _read(f, beam, f"rx_processing_{setting}/rx_algrunflag", n)
            if rh.ndim != 2 or rh.shape[1] != 101:
                raise FileFormatError(f"{f.path}: {beam} rh has shape {rh.shape}; expected "
                                      "(shots, 101)")
            cols.update(lon=_num(lon), lat=_num(lat), ground=_num(ground), top=_num(top))
            for k in range(101):
                cols[f"rh{k}"] = rh[:, k]
            for key, name in (("quality_flag", "quality_flag"), ("degrade", "degrade_flag"),
                              ("sensitivity", "sensitivity"),
                              ("selected_algorithm", "selected_algorithm")):
                if f.is_dataset(f"{beam}/{name}"):
                    cols[key] = np.asarray(_read(f, beam, name, n))
            cols["algrunflag"] = np.asarray(run)
            cols["setting"] = np.full(n, setting or "selected", dtype=object)
            frames.append(pd.DataFrame(cols))
    if not frames:
        raise FileFormatError(f"{path}: no beam with elev_lowestmode; not a GEDI L2A file")
    return _bbox(pd.concat(frames, ignore_index=True), bbox)


def read_gedi_l2b(path: str | os.PathLike[str], beams: Sequence[str] | str | None = None, *,
                  bbox: tuple[float, float, float, float] | None = None) -> pd.DataFrame:
    """L2B canopy cover, PAI, foliage height diversity and flags of every shot.

    Returns
    -------
    DataFrame
        ``beam, shot_number (int64), lon, lat, cover (0..1), pai, fhd_normal, rh100 (m),
        l2b_quality_flag`` (and ``algorithmrun_flag``, ``selected_l2a_algorithm`` -- the L2A
        setting group each shot's values come from, 1..6 -- when present).
    """
    frames = []
    with open_h5(path) as f:
        for beam in _beams(f, beams, "cover"):
            n, cols = _shot_columns(f, beam)
            for key, names in (("lon", ("geolocation/lon_lowestmode", "lon_lowestmode")),
                               ("lat", ("geolocation/lat_lowestmode", "lat_lowestmode"))):
                name = next((nm for nm in names if f.is_dataset(f"{beam}/{nm}")), None)
                if name is None:
                    raise FileFormatError(f"{f.path}: {beam} lacks {names[0]}")
                cols[key] = _num(_read(f, beam, name, n))
            cols["cover"] = _num(_read(f, beam, "cover", n))
            for key in ("pai", "fhd_normal", "rh100", "l2b_quality_flag", "algorithmrun_flag",
                        "selected_l2a_algorithm"):
                if f.is_dataset(f"{beam}/{key}"):
                    a = _read(f, beam, key, n)
                    cols[key] = _num(a) if key in ("pai", "fhd_normal") else np.asarray(a)
            if "rh100" in cols:   # L2B stores rh100 in cm
                cols["rh100"] = _num(cols["rh100"]) / 100.0
            frames.append(pd.DataFrame(cols))
    if not frames:
        raise FileFormatError(f"{path}: no beam with cover; not a GEDI L2B file")
    return _bbox(pd.concat(frames, ignore_index=True), bbox)
