"""GEDI L1B received waveforms -> :class:`~canopyblocks.waveforms.batch.WaveformBatch`.

Layout (DESIGN 4.1): beams ``BEAMxxxx`` (``description`` attribute: coverage or full
power); per shot ``shot_number`` (uint64), ``delta_time``, ``rx_sample_count``,
``rx_sample_start_index`` (1-based into the beam's ``rxwaveform``; a subset file keeps the
source granule's indices, so they are taken relative to the first shot), the noise
statistics ``noise_mean_corrected``/``noise_stddev_corrected``, ``stale_return_flag``, and
in ``geolocation/`` the elevation, latitude and longitude of the first and last sample
and ``degrade``.

Memory stays bounded: the per-shot 1-D arrays of a beam are read whole (subset files
keep the source chunking, so one read per dataset is much faster than many), and
``rxwaveform`` in slices of ``chunk_shots`` shots, gathered into the padded 2-D array
without a Python loop over shots.

Every shot's geometry is checked (:mod:`.gedi_geometry`): bin spacing, sample pool,
positions, amplitudes. The problem bits travel with the batch as
``extra["invalid_shot"]`` (0 for a sound shot) and become the footprint flag
``invalid_shot``; a beam without any sound shot is refused.
"""

from __future__ import annotations

import logging
import os
import re
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import CanopyBlocksWarning, FileFormatError, InputError, NoUsableDataError
from ..progress import Progress, as_progress
from ..waveforms.batch import WaveformBatch
from ._h5 import DamagedFileError, H5File, decode_attr, open_h5
from .gedi_geometry import (
    DIGITISER_RANGE,
    INVALID_SHOT,
    InvalidShotWarning,
    amplitude_problems,
    describe_problems,
    duplicate_problems,
    geometry_problems,
)

__all__ = ["GEDI_BEAMS", "GediBeamInfo", "SkippedBeamWarning", "gedi_beams", "gedi_beam_info", "is_gedi_l1b",
           "gedi_vertical_datum",
           "read_gedi_l1b", "iter_gedi_l1b", "gedi_file_info"]

log = logging.getLogger(__name__)

#: Beam groups of GEDI L1B/L2A/L2B: coverage beams 0000-0011, full power 0101-1011.
GEDI_BEAMS: tuple[str, ...] = ("BEAM0000", "BEAM0001", "BEAM0010", "BEAM0011", "BEAM0101",
                               "BEAM0110", "BEAM1000", "BEAM1011")
_FULL_POWER = ("BEAM0101", "BEAM0110", "BEAM1000", "BEAM1011")
_BEAM_RE = re.compile(r"^BEAM\d{4}$")

#: ``WaveformBatch.extra`` key of the L1B's DEM elevation per shot (the terrain-outlier check
#: of :mod:`canopyblocks.waveforms.gedi_outliers` compares the ground with it).
DEM = "digital_elevation_model"

_PER_SHOT = {
    "shot_number": "shot_number",
    "time": "delta_time",
    "n_samples": "rx_sample_count",
    "start": "rx_sample_start_index",
    "noise_mean": "noise_mean_corrected",
    "noise_sd": "noise_stddev_corrected",
    "stale": "stale_return_flag",
    "elev_bin0": "geolocation/elevation_bin0",
    "elev_lastbin": "geolocation/elevation_lastbin",
    "lat_bin0": "geolocation/latitude_bin0",
    "lat_lastbin": "geolocation/latitude_lastbin",
    "lon_bin0": "geolocation/longitude_bin0",
    "lon_lastbin": "geolocation/longitude_lastbin",
    "degraded": "geolocation/degrade",
    "dem": "geolocation/digital_elevation_model",
}
_OPTIONAL = ("geolocation/degrade", "geolocation/digital_elevation_model")
#: dtype kinds accepted per column (default: any number); counts and indices are integers.
_KINDS = {"shot_number": "iu", "n_samples": "iu", "start": "iu", "stale": "iub",
          "degraded": "iub"}
_KIND_WORDS = {"iu": "integer", "iub": "integer", "iufb": "number"}


def _describe(shape: tuple[int, ...], dtype: np.dtype) -> str:
    kind = {"S": "strings", "U": "strings", "O": "objects", "V": "compound records"}.get(
        dtype.kind, f"{dtype} values")
    dims = "1-D" if len(shape) == 1 else f"{len(shape)}-D, shape {tuple(shape)},"
    return f"a {dims} array of {kind}"


class SkippedBeamWarning(CanopyBlocksWarning):
    """A beam group of the file has no waveforms and was not read."""


@dataclass(frozen=True)
class GediBeamInfo:
    """One beam of a GEDI L1B file."""

    name: str
    power: str        # "full" or "coverage"
    n_shots: int
    n_stale: int
    n_degraded: int


def _power(f: H5File, beam: str) -> str:
    desc = str(decode_attr(f.attr(beam, "description") or "")).lower()
    if "full" in desc:
        return "full"
    if "coverage" in desc:
        return "coverage"
    return "full" if beam in _FULL_POWER else "coverage"


def _beams_in(f: H5File) -> list[str]:
    """The beam groups of ``f``; a damaged file (its root group or a beam it lists cannot
    be read) is refused as damaged, never taken for another product or fewer beams."""
    names = [k for k in f.keys() if _BEAM_RE.match(k)]
    where = f.unreadable("/") if not names else next(
        (w for k in names if not f.is_group(k) and (w := f.unreadable(k))), None)
    if where is not None:
        raise f.damaged(where)
    return sorted(k for k in names if f.is_group(k))


#: GEDI L1B/L2A elevations are heights above the WGS84 ellipsoid.
GEDI_ELLIPSOID = "EPSG:4979"


def gedi_vertical_datum(path: str | os.PathLike[str]) -> str:
    """The vertical CRS of an L1B file's elevations: the ``vertical_datum`` a simulated
    file states (that of the airborne lidar it was simulated from, e.g. ``EPSG:5713``),
    otherwise GEDI's WGS84 ellipsoid (``EPSG:4979``)."""
    try:
        with open_h5(path) as f:
            stated = f.attr("/", "vertical_datum")
    except Exception:  # noqa: BLE001 - an unreadable file is refused by the reader itself
        return GEDI_ELLIPSOID
    return stated.strip() if isinstance(stated, str) and stated.strip() else GEDI_ELLIPSOID


def is_gedi_l1b(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is an HDF5 file with a ``BEAMxxxx/rxwaveform`` dataset."""
    from .remote import StorageError
    try:
        with open_h5(path) as f:
            return any(f.is_dataset(f"{b}/rxwaveform") for b in _beams_in(f))
    except (StorageError, DamagedFileError):
        raise  # said once (storage failing, or the file damaged), not tried as another kind
    except (FileFormatError, OSError):
        return False


def gedi_beams(path: str | os.PathLike[str]) -> list[str]:
    """The beams (``BEAMxxxx``) present in a GEDI file."""
    with open_h5(path) as f:
        beams = _beams_in(f)
    if not beams:
        raise FileFormatError(f"{path}: no GEDI beam group (BEAM0000 .. BEAM1011); not a "
                              "GEDI L1B/L2A/L2B file")
    return beams


def gedi_beam_info(path: str | os.PathLike[str]) -> list[GediBeamInfo]:
    """Beam, power, shot count and stale/degraded counts of each beam of an L1B file."""
    out = []
    with open_h5(path) as f:
        for b in _beams_in(f):
            if not f.is_dataset(f"{b}/shot_number"):
                continue
            n = int(f.shape(f"{b}/shot_number")[0])
            stale = (int(np.count_nonzero(f.read(f"{b}/stale_return_flag")))
                     if f.is_dataset(f"{b}/stale_return_flag") else 0)
            degr = (int(np.count_nonzero(f.read(f"{b}/geolocation/degrade")))
                    if f.is_dataset(f"{b}/geolocation/degrade") else 0)
            out.append(GediBeamInfo(b, _power(f, b), n, stale, degr))
    return out


def gedi_file_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """What ``canopyblocks info`` prints for a GEDI L1B file."""
    from .remote import source_label
    info: dict[str, Any] = {"path": source_label(path), "product": "GEDI L1B", "beams": []}
    lon_all, lat_all = [], []
    with open_h5(path) as f:
        for b in _beams_in(f):
            if not f.is_dataset(f"{b}/shot_number"):
                continue
            n = int(f.shape(f"{b}/shot_number")[0])
            row: dict[str, Any] = {"beam": b, "power": _power(f, b), "n_shots": n}
            if n:
                lon = f.read(f"{b}/geolocation/longitude_bin0", dtype=np.float64)
                lat = f.read(f"{b}/geolocation/latitude_bin0", dtype=np.float64)
                ok = np.isfinite(lon) & np.isfinite(lat) & (np.abs(lat) <= 90)
                lon_all.append(lon[ok])
                lat_all.append(lat[ok])
                for key, name in (("n_stale", "stale_return_flag"),
                                  ("n_degraded", "geolocation/degrade")):
                    if f.is_dataset(f"{b}/{name}"):
                        row[key] = int(np.count_nonzero(f.read(f"{b}/{name}")))
            info["beams"].append(row)
    info["n_shots"] = sum(r["n_shots"] for r in info["beams"])
    if lon_all and sum(len(v) for v in lon_all):
        lo, la = np.concatenate(lon_all), np.concatenate(lat_all)
        info["bbox"] = (float(lo.min()), float(la.min()), float(lo.max()), float(la.max()))
    return info


def _check_beam(f: H5File, beam: str) -> None:
    if not isinstance(beam, str):
        raise InputError(f"beam must be a string like 'BEAM0101'; got {beam!r}")
    present = _beams_in(f)
    if beam not in present:
        raise InputError(f"{f.path}: no beam {beam!r}; the file has "
                         f"{', '.join(present) or 'no BEAMxxxx group'}")
    missing = [name for name in ("rxwaveform", *_PER_SHOT.values())
               if name not in _OPTIONAL and not f.is_dataset(f"{beam}/{name}")]
    where = next((w for name in missing if (w := f.unreadable(f"{beam}/{name}"))), None)
    if where is not None:
        raise f.damaged(where)
    if missing:
        raise FileFormatError(f"{f.path}: {beam} lacks {', '.join(missing)}; not a complete "
                              "GEDI L1B beam (was the subset made without these datasets?)")
    rx = f"{beam}/rxwaveform"
    shape, kind = f.shape(rx), f.dtype(rx).kind
    if len(shape) != 1 or kind not in "iuf":
        raise FileFormatError(
            f"{f.path}: {rx} is {_describe(shape, f.dtype(rx))}; GEDI L1B keeps every "
            "shot's samples end to end in one 1-D array of numbers (the file is damaged "
            "or not a GEDI L1B product)")


def _read_shots(f: H5File, beam: str) -> dict[str, np.ndarray]:
    cols: dict[str, np.ndarray] = {}
    n = None
    for key, name in _PER_SHOT.items():
        path = f"{beam}/{name}"
        if name in _OPTIONAL and not f.is_dataset(path):
            continue
        a = f.read(path)
        if a.ndim != 1 or a.dtype.kind not in _KINDS.get(key, "iufb"):
            raise FileFormatError(
                f"{f.path}: {path} is {_describe(a.shape, a.dtype)}; expected one "
                f"{_KIND_WORDS[_KINDS.get(key, 'iufb')]} per shot (the file is damaged or "
                "not a GEDI L1B product)")
        if n is None:
            n = a.shape[0]
        elif a.shape[0] != n:
            raise FileFormatError(f"{f.path}: {path} holds {a.shape[0]} values but "
                                  f"{beam}/shot_number holds {n}; the beam's arrays disagree")
        cols[key] = a
    if "degraded" not in cols:
        cols["degraded"] = np.zeros(n or 0, dtype=np.int8)
    return cols


def _dem(a: np.ndarray) -> np.ndarray:
    """The L1B's DEM elevation per shot (m, WGS84 ellipsoid, as the bin elevations); its
    fill value (-999999) and anything below -1000 m as NaN."""
    out = _float(a)
    out[out < -1000.0] = np.nan
    return out


def _float(a: np.ndarray, fill_above: float = 1e30) -> np.ndarray:
    """float64 with fill values (GEDI uses 3.4028235e38 / -9999) as NaN."""
    out = np.asarray(a, dtype=np.float64).copy()
    out[~np.isfinite(out) | (np.abs(out) > fill_above) | (out == -9999.0)] = np.nan
    return out


def _bbox_mask(cols: dict[str, np.ndarray],
               bbox: tuple[float, float, float, float] | None) -> np.ndarray:
    n = len(cols["shot_number"])
    if bbox is None:
        return np.ones(n, dtype=bool)
    if len(bbox) != 4 or not all(np.isfinite(bbox)) or bbox[0] > bbox[2] or bbox[1] > bbox[3]:
        raise InputError(f"bbox must be (lon_min, lat_min, lon_max, lat_max) in degrees; "
                         f"got {bbox!r}")
    lon, lat = _float(cols["lon_bin0"]), _float(cols["lat_bin0"])
    with np.errstate(invalid="ignore"):
        return (lon >= bbox[0]) & (lon <= bbox[2]) & (lat >= bbox[1]) & (lat <= bbox[3])


def _gather(rx: np.ndarray, rel: np.ndarray, count: np.ndarray,
            noise_mean: np.ndarray) -> npt.NDArray[np.float32]:
    """Padded 2-D waveforms of shots whose samples start at ``rel`` within ``rx``."""
    width = int(count.max()) if count.size else 0
    wf = np.broadcast_to(noise_mean[:, None], (count.size, max(width, 1))).astype(np.float32)
    if width == 0:
        return wf
    j = np.arange(width)
    inside = j[None, :] < count[:, None]
    idx = rel[:, None] + j[None, :]
    wf[inside] = rx[idx[inside]]
    return wf


def _relative_starts(f: H5File, beam: str, cols: dict[str, np.ndarray]) -> np.ndarray:
    """Each shot's first sample within ``rxwaveform`` (0-based); refuses the file when a
    shot's samples lie outside it."""
    n_rx = int(f.shape(f"{beam}/rxwaveform")[0])
    count = cols["n_samples"].astype(np.int64)
    start = cols["start"].astype(np.int64)
    rel_all = start - int(start.min()) if count.size and start.size else start
    bad = (count > 0) & ((rel_all < 0) | (rel_all + count > n_rx))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        k = int(np.argmin(start))   # its index places every shot: it may be the wrong one
        first = "" if k == i else (
            f" (or shot {int(cols['shot_number'][k])}'s rx_sample_start_index {int(start[k])}, "
            "the smallest, from which the samples are counted, is too small)")
        raise FileFormatError(
            f"{f.path}: {beam} shot {int(cols['shot_number'][i])} points at samples "
            f"{int(rel_all[i])}..{int(rel_all[i] + count[i])} of an rxwaveform of {n_rx}"
            f"{first}; rx_sample_start_index/rx_sample_count do not match rxwaveform "
            "(truncated or inconsistent subset)")
    return rel_all


def _problems(f: H5File, beam: str, cols: dict[str, np.ndarray]) -> np.ndarray:
    """Geometry problem bits per shot; refuses the beam when no shot with samples is sound,
    warns when some are not."""
    count = cols["n_samples"].astype(np.int64)
    e0, e1 = _float(cols["elev_bin0"]), _float(cols["elev_lastbin"])
    problems = geometry_problems(count, cols["start"].astype(np.int64), e0, e1,
                                 _float(cols["lat_bin0"]), _float(cols["lat_lastbin"]),
                                 _float(cols["lon_bin0"]), _float(cols["lon_lastbin"]))
    problems |= duplicate_problems(cols["shot_number"])
    bad = problems != 0
    if not bad.any():
        return problems
    what = describe_problems(problems, cols["shot_number"], count, e0, e1)
    if not (~bad & (count > 0)).any():
        raise FileFormatError(
            f"{f.path}: no shot of {beam} has sound L1B values: {what}; the file is "
            "damaged or not a GEDI L1B product")
    warnings.warn(f"{f.path}: {int(bad.sum())} of {bad.size} shots of {beam} flagged "
                  f"{INVALID_SHOT}, their heights not given: {what}", InvalidShotWarning,
                  stacklevel=4)
    return problems


def _batches(f: H5File, beam: str, mask: np.ndarray, cols: dict[str, np.ndarray],
             chunk_shots: int, source: str, prog: Progress) -> Iterator[WaveformBatch]:
    rx_name = f"{beam}/rxwaveform"
    count = cols["n_samples"].astype(np.int64)
    rel_all = _relative_starts(f, beam, cols)
    power = _power(f, beam)
    sel = np.flatnonzero(mask)
    n_chunks = max(1, -(-sel.size // chunk_shots))
    for c in range(n_chunks):
        rows = sel[c * chunk_shots:(c + 1) * chunk_shots]
        if rows.size == 0:
            break
        cnt = count[rows]
        rel = rel_all[rows]
        has = cnt > 0
        lo = int(rel[has].min()) if has.any() else 0
        hi = int((rel[has] + cnt[has]).max()) if has.any() else 0
        rx = (f.read(rx_name, np.s_[lo:hi], dtype=np.float32) if hi > lo
              else np.zeros(0, np.float32))
        nm = _float(cols["noise_mean"][rows])
        wf = _gather(rx, np.where(has, rel - lo, 0), cnt, np.nan_to_num(nm, nan=0.0))
        amp = amplitude_problems(wf, cnt)
        if amp.any():
            warnings.warn(
                f"{f.path}: {int(np.count_nonzero(amp))} of {rows.size} shots of {beam} have "
                f"samples outside {DIGITISER_RANGE[0]:g}..{DIGITISER_RANGE[1]:g} digitiser "
                f"counts (largest {float(np.nanmax(np.abs(wf[amp > 0]))):.4g}); they are "
                f"flagged {INVALID_SHOT} and their heights are not given",
                InvalidShotWarning, stacklevel=3)
        yield WaveformBatch(
            beam=beam,
            shot_number=np.asarray(cols["shot_number"][rows], dtype=np.uint64),
            time=_float(cols["time"][rows]),
            waveforms=wf,
            n_samples=cnt,
            elev_bin0=_float(cols["elev_bin0"][rows]),
            elev_lastbin=_float(cols["elev_lastbin"][rows]),
            lat_bin0=_float(cols["lat_bin0"][rows]),
            lat_lastbin=_float(cols["lat_lastbin"][rows]),
            lon_bin0=_float(cols["lon_bin0"][rows]),
            lon_lastbin=_float(cols["lon_lastbin"][rows]),
            noise_mean=nm,
            noise_sd=_float(cols["noise_sd"][rows]),
            stale=np.asarray(cols["stale"][rows]) != 0,
            degraded=np.asarray(cols["degraded"][rows]) != 0,
            power=power,
            source=source,
            extra={INVALID_SHOT: cols["problems"][rows] | amp,
                   **({DEM: _dem(cols["dem"][rows])} if "dem" in cols else {})},
        )
        prog.update((c + 1) / n_chunks, f"{beam}: {int(rows[-1]) + 1} shots read")


def iter_gedi_l1b(path: str | os.PathLike[str], beams: Sequence[str] | str | None = None, *,
                  bbox: tuple[float, float, float, float] | None = None,
                  quality: bool = False, chunk_shots: int = 4096,
                  progress: Progress | None = None) -> Iterator[WaveformBatch]:
    """Batches of at most ``chunk_shots`` shots, beam after beam (bounded memory).

    Parameters
    ----------
    path : path
        GEDI L1B granule or subset (HDF5).
    beams : str or sequence of str, optional
        Beams to read (default every beam in the file).
    bbox : (lon_min, lat_min, lon_max, lat_max), optional
        Keep shots whose first sample lies inside (degrees WGS84).
    quality : bool
        Drop stale and degraded shots (default: keep them; the processing flags them).
    chunk_shots : int
        Shots per batch.

    Raises
    ------
    FileFormatError
        Not a readable GEDI L1B file, a missing dataset, inconsistent arrays.
    InputError
        Unknown beam or bad bbox.
    """
    if isinstance(chunk_shots, bool) or not isinstance(chunk_shots, int) or chunk_shots < 1:
        raise InputError(f"chunk_shots must be a positive integer; got {chunk_shots!r}")
    from ..arguments import check_path
    check_path(path, "GEDI L1B path", "a GEDI L1B file path")
    if bbox is not None:
        try:
            bbox = tuple(float(v) for v in bbox)  # type: ignore[assignment]
        except (TypeError, ValueError):
            raise InputError(f"bbox must be (lon_min, lat_min, lon_max, lat_max) in degrees "
                             f"(four numbers); got {bbox!r}") from None
    prog = as_progress(progress)
    from .remote import source_label
    p = source_label(path)  # a path, or a URL without its query string
    with open_h5(path) as f:
        present = _beams_in(f)
        if not present or not any(f.is_dataset(f"{b}/rxwaveform") for b in present):
            raise FileFormatError(f"{p}: not a GEDI L1B file (no BEAMxxxx/rxwaveform); give "
                                  "an L1B granule (GEDI01_B_*.h5)")
        wanted = ([beams] if isinstance(beams, str) else list(beams)) if beams else \
            [b for b in present if f.is_dataset(f"{b}/rxwaveform")]
        if not beams and len(wanted) < len(present):
            skipped = [b for b in present if b not in wanted]
            warnings.warn(f"{p}: {', '.join(skipped)} {'has' if len(skipped) == 1 else 'have'}"
                          " no rxwaveform dataset (not an L1B beam or a damaged subset); "
                          f"read {', '.join(wanted)} only", SkippedBeamWarning, stacklevel=2)
        for i, beam in enumerate(wanted):
            _check_beam(f, beam)
            cols = _read_shots(f, beam)
            _relative_starts(f, beam, cols)   # the pool first: a refusal, not a flag
            cols["problems"] = _problems(f, beam, cols)
            mask = _bbox_mask(cols, bbox)
            if quality:
                mask &= (cols["stale"] == 0) & (np.asarray(cols["degraded"]) == 0)
            if not mask.any():
                continue
            yield from _batches(f, beam, mask, cols, chunk_shots, str(p),
                                prog.sub(i / len(wanted), (i + 1) / len(wanted)))


def read_gedi_l1b(path: str | os.PathLike[str], beam: str, *,
                  bbox: tuple[float, float, float, float] | None = None,
                  quality: bool = False) -> WaveformBatch:
    """All shots of one beam as one :class:`WaveformBatch` (see :func:`iter_gedi_l1b`).

    Raises
    ------
    NoUsableDataError
        No shot of the beam inside ``bbox`` (or passing ``quality``).
    """
    parts = list(iter_gedi_l1b(path, [beam], bbox=bbox, quality=quality,
                               chunk_shots=1 << 30))
    if not parts:
        raise NoUsableDataError(f"{path}: no shot of {beam} "
                                + ("inside the bbox" if bbox is not None else "to read")
                                + (" passes the stale/degrade flags" if quality else ""))
    return parts[0]
