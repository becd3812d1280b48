"""ATL08 signal-photon classes joined onto ATL03 photons.

ATL08 ``gtXX/signal_photons`` lists the photons it classified by
``ph_segment_id`` (the ATL03 geolocation ``segment_id`` of the photon) and
``classed_pc_indx`` (the photon's 1-based position inside that segment), with
``classed_pc_flag`` (0 noise, 1 ground, 2 canopy, 3 top of canopy).
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import CanopyBlocksWarning, FileFormatError, InputError
from ._h5 import H5File, open_h5

__all__ = ["Atl08Photons", "check_atl08_beams", "read_atl08_photons", "join_atl08", "photon_keys", "BEAMS"]

log = logging.getLogger(__name__)

BEAMS = ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")

_KEY_SHIFT = np.int64(32)


@dataclass(frozen=True, eq=False)
class Atl08Photons:
    """The classified photons of one ATL08 beam.

    Attributes
    ----------
    segment_id : ndarray int64
        ATL03 geolocation segment of each photon (``ph_segment_id``).
    index : ndarray int64
        1-based photon position inside that segment (``classed_pc_indx``).
    flag : ndarray int8
        ``classed_pc_flag``: 0 noise, 1 ground, 2 canopy, 3 top of canopy.
    delta_time : ndarray float64 or None
        ``signal_photons/delta_time`` when present (checks the join).
    rgt, cycle : int or None
        ``orbit_info/rgt`` and ``orbit_info/cycle_number`` when present.
    """

    segment_id: np.ndarray
    index: np.ndarray
    flag: np.ndarray
    delta_time: np.ndarray | None
    rgt: int | None
    cycle: int | None
    source: str


def photon_keys(segment_id: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Combined int64 key ``segment_id << 32 | index`` (index 1-based within the segment)."""
    return (np.asarray(segment_id, np.int64) << _KEY_SHIFT) | np.asarray(index, np.int64)


def check_atl08_beams(f: H5File, group: str, wanted: Sequence[str] | None = None) -> list[str]:
    """The beams of an open ATL08 file that hold ``gtXX/<group>``, checked against ``wanted``.

    Returns ``wanted`` (or every such beam when None).

    Raises
    ------
    FileFormatError
        No beam has the group: not an ATL08 file.
    InputError
        A wanted beam lacks the group (the message lists the beams that have it).
    """
    have = [b for b in BEAMS if f.is_group(f"{b}/{group}")]
    if not have:
        raise FileFormatError(
            f"{f.path}: not an ATL08 file (no gtXX/{group} group); pass the ATL08 granule "
            "that matches the ATL03 file"
        )
    want = have if wanted is None else list(wanted)
    bad = [b for b in want if b not in have]
    if bad:
        raise InputError(
            f"{f.path}: ATL08 has no {group.replace('_', ' ')} for beam(s) {', '.join(bad)}; "
            f"it has {', '.join(have)}"
        )
    return want


def read_atl08_photons(path: str | os.PathLike[str], beam: str) -> Atl08Photons:
    """Read ``beam``'s ``signal_photons`` from an ATL08 file.

    Raises
    ------
    FileFormatError
        Not an ATL08 file / datasets missing.
    InputError
        The beam is not in the file (the message lists the beams it has).
    """
    with open_h5(path, "ATL08") as f:
        check_atl08_beams(f, "signal_photons", [beam])
        g = f"{beam}/signal_photons"
        seg = f.read(f"{g}/ph_segment_id", dtype=np.int64)
        idx = f.read(f"{g}/classed_pc_indx", dtype=np.int64)
        flag = f.read(f"{g}/classed_pc_flag", dtype=np.int8)
        dt = f.read(f"{g}/delta_time", dtype=np.float64) if f.is_dataset(f"{g}/delta_time") \
            else None
        if not (seg.shape == idx.shape == flag.shape) or seg.ndim != 1:
            raise FileFormatError(
                f"{f.path}: {g}: ph_segment_id, classed_pc_indx and classed_pc_flag have "
                f"different shapes {seg.shape}, {idx.shape}, {flag.shape}"
            )
        if dt is not None and dt.shape != seg.shape:
            raise FileFormatError(
                f"{f.path}: {g}/delta_time has shape {dt.shape} but ph_segment_id "
                f"{seg.shape}; the file is damaged")
        bad = (flag < 0) | (flag > 4)
        if bad.any():
            warnings.warn(
                f"{f.path}: {g}: {int(bad.sum())} of {flag.size} photons have a "
                f"classed_pc_flag outside 0-4 ({', '.join(map(str, np.unique(flag[bad])[:5]))}); "
                "they are read as unclassified (-1)", CanopyBlocksWarning, stacklevel=2)
            flag = np.where(bad, -1, flag).astype(np.int8)
        return Atl08Photons(seg, idx, flag, dt, _int_or_none(f, "orbit_info/rgt"),
                            _int_or_none(f, "orbit_info/cycle_number"), str(f.path))


def _int_or_none(f: H5File, name: str) -> int | None:
    v = f.scalar(name)
    try:
        return None if v is None else int(v)  # type: ignore[call-overload]
    except (TypeError, ValueError):
        return None


def join_atl08(
    ph_segment_id: np.ndarray,
    ph_index: np.ndarray,
    ph_time: np.ndarray,
    atl08: Atl08Photons,
    *,
    what: str = "",
    time_tolerance: float = 1e-6,
) -> np.ndarray:
    """Classes of ATL03 photons from ATL08 (vectorised join on ``(segment_id, index)``).

    Parameters
    ----------
    ph_segment_id, ph_index : ndarray
        Geolocation ``segment_id`` of each ATL03 photon and its 1-based position
        inside the segment.
    ph_time : ndarray
        ATL03 ``delta_time`` of each photon, seconds; checked against ATL08's.
    atl08 : Atl08Photons
    what : str
        Names the ATL03 beam/file in messages.
    time_tolerance : float
        Largest allowed |ATL03 - ATL08| ``delta_time`` of a joined photon, seconds.

    Returns
    -------
    ndarray int8
        ``classed_pc_flag`` per ATL03 photon, -1 where ATL08 did not classify it.

    Raises
    ------
    InputError
        When more than 1 % of the joined photons have a different ``delta_time``:
        the ATL08 file is not the partner of this ATL03 granule.
    """
    keys = photon_keys(ph_segment_id, ph_index)
    k8 = photon_keys(atl08.segment_id, atl08.index)
    order = np.argsort(k8, kind="stable")
    k8s = k8[order]
    pos = np.searchsorted(k8s, keys)
    pos_c = np.minimum(pos, max(k8s.size - 1, 0))
    hit = (pos < k8s.size) & (k8s[pos_c] == keys) if k8s.size else np.zeros(keys.size, bool)
    out = np.full(keys.size, -1, dtype=np.int8)
    src = order[pos_c[hit]]
    out[hit] = atl08.flag[src]
    if atl08.delta_time is not None and hit.any():
        dt = np.abs(np.asarray(ph_time, np.float64)[hit] - atl08.delta_time[src])
        off = ~(dt <= time_tolerance)
        bad = int(np.sum(off))
        if bad > 0.01 * hit.sum():
            raise InputError(
                f"{what}: ATL08 file {atl08.source} does not match: {bad} of {int(hit.sum())} "
                "photons joined by (segment_id, index) have a different delta_time; pass the "
                "ATL08 granule made from this ATL03 granule"
            )
        if bad:
            stale = np.flatnonzero(hit)[off]
            out[stale] = -1
            hit[stale] = False
            warnings.warn(
                f"{what}: {bad} photons joined from ATL08 file {atl08.source} have another "
                "delta_time; they are left unclassified", CanopyBlocksWarning, stacklevel=2)
    if keys.size and not hit.any():
        warnings.warn(
            f"{what}: ATL08 file {atl08.source} joins none of its {keys.size} photons (no "
            "matching segment_id and index): no photon is classified; check that it is the "
            "ATL08 granule made from this ATL03 granule", CanopyBlocksWarning, stacklevel=2)
    log.info("%s: %d of %d ATL03 photons classified by ATL08 (%d ATL08 photons)",
             what, int(hit.sum()), keys.size, k8.size)
    return out
