"""Recognise a photon file's product, open a track from it, and summarise it.

``open_track`` is what the CLI and the QGIS plugin call: it picks the reader from
the file's content (ATL03 by ``gtXX/heights`` or its identifiers, MABEL by
``photon/channelNNN``, ATL08 refused with advice) or, for tables, its suffix.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyproj

from ..errors import FileFormatError, InputError, NoUsableDataError
from ..photons import PhotonTrack
from ..progress import Progress
from ._h5 import H5File, _looks_like_hdf5, open_h5
from .atl03 import BEAMS, _beam_info, _read_segments, _sc_orient, atl03_beams, read_atl03
from .mabel import _channels, channel_name, read_mabel
from .table import TABLE_SUFFIXES, read_table

__all__ = ["Product", "detect_product", "open_track", "file_info", "format_info",
           "default_beam"]

log = logging.getLogger(__name__)

Product = Literal["ATL03", "ATL08", "MABEL", "table"]

_LIDAR_SUFFIXES = (".las", ".laz")


def _h5_product(f: H5File) -> Product | None:
    if any(f.is_group(f"{b}/heights") for b in BEAMS):
        return "ATL03"
    if any(f.is_group(f"{b}/signal_photons") or f.is_group(f"{b}/land_segments")
           for b in BEAMS):
        return "ATL08"
    if _channels(f):
        return "MABEL"
    ident = " ".join(str(v) for v in (
        f.attr("/", "short_name"), f.attr("/", "identifier_product_type"),
        f.scalar("METADATA/DatasetIdentification/shortName"),
        f.attr("METADATA/DatasetIdentification", "shortName"),
        f.scalar("ancillary_data/data_product"),
    ) if v)
    if "ATL03" in ident.upper():
        return "ATL03"
    if "ATL08" in ident.upper():
        return "ATL08"
    return None


def detect_product(path: str | os.PathLike[str]) -> Product:
    """The product of ``path``: ``"ATL03"``, ``"ATL08"``, ``"MABEL"`` or ``"table"``.

    Raises
    ------
    FileFormatError
        Missing, unreadable, or not a recognised photon product.
    """
    from ..arguments import check_path, check_source
    from .remote import is_file_object, is_url, source_label
    remote = is_url(path) or is_file_object(path)
    p: Any = check_source(path, "photon file") if remote else check_path(path, "photon file")
    if remote:
        label = source_label(path)
        suf = Path(label).suffix.lower()
        if suf in TABLE_SUFFIXES or suf in _LIDAR_SUFFIXES:
            raise FileFormatError(f"{label}: tables and point clouds are read from local "
                                  "files; download it first")
        return _hdf5_product(path, label)
    if not p.exists():
        from .remote import missing_message
        raise FileFormatError(missing_message(path))
    suf = p.suffix.lower()
    if suf in TABLE_SUFFIXES:
        return "table"
    if suf in _LIDAR_SUFFIXES:
        raise FileFormatError(
            f"{p}: is an airborne lidar point cloud (LAS/LAZ), not a photon track; use it as "
            "the reference (canopyblocks rasters / validate), or simulate photons from it"
        )
    if not _looks_like_hdf5(p):
        raise FileFormatError(
            f"{p}: not a recognised photon file: not HDF5 (ATL03/MABEL) and not a table "
            f"({', '.join(TABLE_SUFFIXES)})"
        )
    return _hdf5_product(p, str(p))


def _hdf5_product(p: Any, label: str) -> Product:
    with open_h5(p, "ATL03/MABEL") as f:
        prod = _h5_product(f)
        if prod is None:
            raise FileFormatError(
                f"{label}: HDF5 file but neither ATL03 (gtXX/heights) nor MABEL L2A "
                f"(photon/channelNNN); top-level groups: {', '.join(f.keys()) or 'none'}"
                + ("; GEDI: L1B waveforms go through `canopyblocks waveforms`, L2A/L2B "
                   "serve as its --l2a/--l2b"
                   if any(k.startswith("BEAM") for k in f.keys()) else "")
            )
        return prod


def default_beam(path: str | os.PathLike[str]) -> str:
    """The first strong beam with photons (gt1l..gt3r order), else the first with photons."""
    beams = [b for b in atl03_beams(path) if b.n_photons > 0]
    if not beams:
        raise NoUsableDataError(f"{path}: no ATL03 beam has photons")
    strong = [b for b in beams if b.strength == "strong"]
    return (strong or beams)[0].name


def open_track(
    path: str | os.PathLike[str],
    *,
    beam: str | None = None,
    channel: int | str | None = None,
    bbox: Sequence[float] | None = None,
    s_range: Sequence[float] | None = None,
    atl08: str | os.PathLike[str] | None = None,
    crs: pyproj.CRS | str | int | None = None,
    min_signal_conf: int | None = None,
    progress: Progress | None = None,
    **table_options: Any,
) -> PhotonTrack:
    """Open one track of any supported photon file.

    Parameters
    ----------
    path : path-like
        ATL03 or MABEL L2A HDF5 file, or a CSV/Parquet table.
    beam : str, optional
        ATL03 beam; default the first strong beam that has photons.
    channel : int or "most", optional
        MABEL channel; default ``"most"`` (the channel with the most photons).
    bbox, s_range, crs : optional
        As in :func:`~canopyblocks.readers.read_atl03` (degrees WGS84; metres).
    atl08 : path-like, optional
        ATL08 partner of an ATL03 file (classes into ``track.classification``).
    min_signal_conf : int, optional
        ATL03 only: keep photons with land signal confidence >= this.
    progress : Progress, optional
    **table_options
        Passed to :func:`~canopyblocks.readers.read_table` (column names, ``track``).

    Raises
    ------
    FileFormatError, InputError, NoUsableDataError, CRSError
        With the file named; options that do not fit the product are refused.
    """
    from ..arguments import check_source
    check_source(path, "open_track: path")
    prod = detect_product(path)
    if prod == "ATL08":
        raise InputError(
            f"{path}: is an ATL08 file (land and vegetation heights), not photons; open its "
            "ATL03 granule and pass this file as atl08=... (--atl08)"
        )
    if prod != "ATL03":
        for opt, val in (("beam", beam), ("atl08", atl08), ("min_signal_conf", min_signal_conf)):
            if val is not None:
                raise InputError(f"{path}: {opt} applies to ATL03 files only; this is {prod}")
    if prod != "MABEL" and channel is not None:
        raise InputError(f"{path}: channel applies to MABEL files only; this is {prod}")
    if prod != "table" and table_options:
        raise InputError(f"{path}: options {sorted(table_options)} apply to tables only")
    if prod == "ATL03":
        return read_atl03(path, beam or default_beam(path), bbox=bbox, s_range=s_range,
                          atl08=atl08, crs=crs, min_signal_conf=min_signal_conf,
                          progress=progress)
    if prod == "MABEL":
        return read_mabel(path, "most" if channel is None else channel, bbox=bbox,
                          s_range=s_range, crs=crs, progress=progress)
    return read_table(path, crs=crs, bbox=bbox, s_range=s_range, **table_options)


def _span(values: list[np.ndarray]) -> tuple[float, float] | None:
    v = np.concatenate([a[np.isfinite(a)] for a in values]) if values else np.empty(0)
    return (float(v.min()), float(v.max())) if v.size else None


def _bbox(lon: list[np.ndarray], lat: list[np.ndarray]) -> tuple[float, ...] | None:
    lo = _span(lon)
    la = _span(lat)
    return None if lo is None or la is None else (lo[0], la[0], lo[1], la[1])


def file_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Summary of a photon file for ``canopyblocks info``.

    Returns
    -------
    dict
        ``path``, ``product``; for ATL03 ``beams`` (list of dicts name, strength,
        n_photons, spot), ``rgt``, ``cycle``, ``sc_orient``, ``default_beam``; for
        MABEL ``channels`` (list of dicts channel, track, n_photons),
        ``most_photons``; for tables ``n_photons``, ``track``; and ``time_span``
        (s, the product's delta_time) and ``bbox`` (lon_min, lat_min, lon_max,
        lat_max, degrees).  ATL03 spans come from the geolocation segments; MABEL
        spans from every k-th photon (at most 100,000 per channel).
    """
    from ..arguments import check_source
    check_source(path, "file_info: path")
    from .gedi import gedi_file_info, is_gedi_l1b
    from .remote import is_file_object, source_label

    if (is_file_object(path) or Path(source_label(path)).suffix.lower()
            in (".h5", ".hdf5", ".he5")) and is_gedi_l1b(path):
        return gedi_file_info(path)
    from .flash_dual import flash_dual_file_info, flash_dual_sensor

    if flash_dual_sensor(path) is not None:   # ESFL cubes or dual-wavelength pairs
        return flash_dual_file_info(path)
    prod = detect_product(path)
    info: dict[str, Any] = {"path": source_label(path), "product": prod}
    if prod == "table":
        tr = read_table(path)
        info.update(n_photons=len(tr), track=tr.track, crs=tr.crs.to_string(),
                    time_span=_span([tr.time]), bbox=_bbox([tr.lon], [tr.lat]))
        return info
    with open_h5(path, prod) as f:
        if prod in ("ATL03", "ATL08"):
            orient = _sc_orient(f)
            info.update(rgt=_int(f.scalar("orbit_info/rgt")),
                        cycle=_int(f.scalar("orbit_info/cycle_number")), sc_orient=orient)
        if prod == "ATL03":
            beams = [_beam_info(f, b, orient) for b in BEAMS if f.is_group(f"{b}/heights")]
            info["beams"] = [dict(name=b.name, strength=b.strength, n_photons=b.n_photons,
                                  spot=b.spot) for b in beams]
            lats, lons, times = [], [], []
            for b in beams:
                if b.n_photons == 0:
                    continue
                segs = _read_segments(f, b.name, b.n_photons)
                if segs.ref_lat is not None and segs.ref_lon is not None:
                    ok = (np.abs(segs.ref_lat) <= 90) & (np.abs(segs.ref_lon) <= 360)
                    lats.append(segs.ref_lat[ok])
                    lons.append(segs.ref_lon[ok])
                t = f.read(f"{b.name}/heights/delta_time", np.s_[0:1], dtype=np.float64)
                t1 = f.read(f"{b.name}/heights/delta_time", np.s_[b.n_photons - 1:],
                            dtype=np.float64)
                times += [t, t1]
            info["time_span"] = _span(times)
            info["bbox"] = _bbox(lons, lats)
            with_ph = [b for b in beams if b.n_photons > 0]
            strong = [b for b in with_ph if b.strength == "strong"]
            info["default_beam"] = (strong or with_ph)[0].name if with_ph else None
        elif prod == "MABEL":
            chans = _channels(f)
            info["channels"] = [dict(channel=c, track=channel_name(c), n_photons=n)
                                for c, n in chans.items()]
            info["most_photons"] = max(chans, key=lambda c: (chans[c], -c))
            lats, lons, times = [], [], []
            for c, n in chans.items():
                if n == 0:
                    continue
                step = max(1, n // 100_000)
                g = f"photon/{channel_name(c)}"
                sel = np.s_[::step]
                lat = f.read(f"{g}/latitude", sel, dtype=np.float64)
                lon = f.read(f"{g}/longitude", sel, dtype=np.float64)
                ok = (np.abs(lat) <= 90) & (np.abs(lon) <= 360)
                lats.append(lat[ok])
                lons.append(lon[ok])
                times.append(f.read(f"{g}/delta_time", sel, dtype=np.float64))
                times.append(f.read(f"{g}/delta_time", np.s_[n - 1:], dtype=np.float64))
            info["time_span"] = _span(times)
            info["bbox"] = _bbox(lons, lats)
        else:  # ATL08
            info["beams"] = [b for b in BEAMS if f.is_group(f"{b}/signal_photons")]
            info["note"] = "ATL08: pass it with its ATL03 granule as --atl08"
    return info


def _int(v: Any) -> int | None:
    """``int(v)`` of an untyped HDF5 value; None if it is missing or not a number."""
    try:
        return None if v is None else int(v)
    except (TypeError, ValueError):
        return None


def format_info(info: dict[str, Any]) -> str:
    """Human-readable lines of :func:`file_info`'s dict (for the CLI)."""
    lines = [f"{info['path']}: {info['product']}"]
    for key in ("rgt", "cycle", "sc_orient", "track", "crs", "n_photons"):
        if info.get(key) is not None:
            lines.append(f"  {key}: {info[key]}")
    if info.get("n_shots") is not None:
        lines.append(f"  shots: {info['n_shots']}")
    for b in info.get("beams", []):
        if isinstance(b, dict) and "n_shots" in b:
            flags = "".join(f", {b[k]} {k[2:]}" for k in ("n_stale", "n_degraded") if b.get(k))
            lines.append(f"  beam {b['beam']}: {b['power']} power, {b['n_shots']} shots"
                         f"{flags}")
        elif isinstance(b, dict):
            spot = f", spot {b['spot']}" if b.get("spot") else ""
            lines.append(f"  beam {b['name']}: {b['strength']}{spot}, {b['n_photons']} photons")
        else:
            lines.append(f"  beam {b}")
    for c in info.get("channels", []):
        lines.append(f"  {c['track']}: {c['n_photons']} photons")
    if info.get("default_beam"):
        lines.append(f"  default beam: {info['default_beam']}")
    if info.get("most_photons") is not None:
        lines.append(f"  channel with most photons: {info['most_photons']}")
    if info.get("time_span"):
        t0, t1 = info["time_span"]
        lines.append(f"  time: {t0:.6f} .. {t1:.6f} s ({t1 - t0:.3f} s)")
    if info.get("bbox"):
        lines.append("  bbox (lon_min, lat_min, lon_max, lat_max): "
                     + ", ".join(f"{v:.6f}" for v in info["bbox"]))
    if info.get("note"):
        lines.append(f"  {info['note']}")
    return "\n".join(lines)
