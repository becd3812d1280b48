"""Checks of a GEDI L1B beam's geometry and samples, shot by shot (no loop over shots).

A shot's heights are only as good as the values that place its samples: the elevation
of sample ``j`` is ``elevation_bin0 + j (elevation_lastbin - elevation_bin0) / (n - 1)``
with ``n = rx_sample_count``, and its samples are ``rxwaveform[start - 1 : start - 1 + n]``
with ``start = rx_sample_start_index``. A shot fails when

* ``spacing``: its bin spacing ``(elevation_bin0 - elevation_lastbin) / (n - 1)`` is not
  GEDI's 1 ns sample, 0.1499 m of range, times the cosine of the off-nadir angle (GEDI
  points at most about 6 degrees off nadir: 0.6 % shorter), within
  :data:`SPACING_TOLERANCE` -- bin0 below lastbin (upside down), equal, or a sample count
  the elevation span cannot hold (one sample fewer than the span needs makes the
  spacing 0.12 % longer on a 850-sample shot: beyond the range);
* ``position``: ``elevation_bin0``/``elevation_lastbin``/latitude/longitude are missing
  (fill, NaN) for a shot with samples, or out of range (latitude beyond +-90 degrees,
  longitude beyond +-180, elevation outside :data:`ELEVATION_RANGE`), or the first and
  last samples lie further apart horizontally than a beam at most 8 degrees off nadir
  allows (:data:`MAX_TILT`: the footprint's latitude/longitude, interpolated between
  them, would be invented);
* ``pool``: its samples overlap another shot's or come before the previous shot's in the
  beam's ``rxwaveform`` (start indices increase, shot after shot, in real granules and
  subsets); both shots of an overlap are marked -- either one's index may be the wrong one;
* ``amplitude``: a sample lies outside :data:`DIGITISER_RANGE`;
* ``shot number``: two shots of the beam carry the same ``shot_number`` (a join with
  L2A/L2B by shot number would pair one with the other's values).

Shots that fail are flagged ``invalid_shot`` in the footprint table (their heights are
not given); when every shot of a beam fails, the file is refused.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import CanopyBlocksWarning

__all__ = ["SAMPLE_SPACING_M", "SPACING_TOLERANCE", "DIGITISER_RANGE", "ELEVATION_RANGE",
           "SPACING", "POSITION", "POOL", "AMPLITUDE", "DUPLICATE", "PROBLEM_NAMES", "INVALID_SHOT",
           "InvalidShotWarning", "geometry_problems", "amplitude_problems",
           "duplicate_problems", "describe_problems", "MAX_TILT"]

#: Range of GEDI's 1 ns sample (two-way), metres.
SAMPLE_SPACING_M = 0.299792458 / 2.0
#: Accepted bin spacing relative to :data:`SAMPLE_SPACING_M`: from 1 % shorter (8 degrees
#: off nadir) to 0.1 % longer (the sample clock). The 300 real shots in tests/data/gedi
#: lie 0.03-0.06 % short.
SPACING_TOLERANCE: tuple[float, float] = (-0.01, 0.001)
#: Plausible sample values, digitiser counts. Real L1B samples of the bundled subset
#: span 198-926 counts around noise means of 200-255; values far outside (here: beyond
#: 14-bit magnitudes) come from a damaged or rescaled ``rxwaveform``.
DIGITISER_RANGE: tuple[float, float] = (-1024.0, 16384.0)
#: Plausible elevations (m, WGS84 ellipsoid or the simulated tiles' datum) of the first
#: and last sample.
ELEVATION_RANGE: tuple[float, float] = (-1000.0, 10000.0)

#: Horizontal over vertical distance of the first and last sample at most (tan 8 degrees,
#: GEDI's pointing; the 300 real shots in tests/data/gedi: 0.020 median, 0.027 at most), plus
#: :data:`TILT_SLACK_M` for the positions' rounding.
MAX_TILT = 0.1405
TILT_SLACK_M = 5.0
_M_PER_DEG = 111_320.0

SPACING, POSITION, POOL, AMPLITUDE, DUPLICATE = 1, 2, 4, 8, 16
PROBLEM_NAMES = {SPACING: "bin spacing", POSITION: "position", POOL: "sample pool",
                 AMPLITUDE: "amplitude", DUPLICATE: "shot number"}
#: The footprint flag of shots with a problem.
INVALID_SHOT = "invalid_shot"


class InvalidShotWarning(CanopyBlocksWarning):
    """Some shots' L1B values are impossible (geometry, sample pool, amplitudes); they are
    flagged ``invalid_shot`` and their heights are not given."""


def geometry_problems(count: npt.ArrayLike, start: npt.ArrayLike, elev0: npt.ArrayLike,
                      elev1: npt.ArrayLike, lat0: npt.ArrayLike, lat1: npt.ArrayLike,
                      lon0: npt.ArrayLike, lon1: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """Problem bits (:data:`SPACING` | :data:`POSITION` | :data:`POOL`) of every shot.

    Parameters
    ----------
    count, start : array of int, shape (n,)
        ``rx_sample_count`` and ``rx_sample_start_index`` in file order.
    elev0, elev1 : array of float, shape (n,)
        ``elevation_bin0``/``elevation_lastbin`` (m), fill values already NaN.
    lat0, lat1, lon0, lon1 : array of float, shape (n,)
        Degrees, fill values already NaN.

    Returns
    -------
    ndarray of uint8, shape (n,)
        0 for a sound shot. Shots without samples (``count`` 0) are only checked for
        out-of-range positions (they are ``no_signal`` anyway).
    """
    c = np.asarray(count, dtype=np.int64)
    s = np.asarray(start, dtype=np.int64)
    e0, e1 = np.asarray(elev0, np.float64), np.asarray(elev1, np.float64)
    la = np.stack([np.asarray(lat0, np.float64), np.asarray(lat1, np.float64)])
    lo = np.stack([np.asarray(lon0, np.float64), np.asarray(lon1, np.float64)])
    out = np.zeros(c.size, dtype=np.uint8)
    has = c > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        # spacing (shots with at least two samples)
        two = c >= 2
        spacing = (e0 - e1) / np.where(two, c - 1, 1)
        rel = spacing / SAMPLE_SPACING_M - 1.0
        ok_spacing = (rel >= SPACING_TOLERANCE[0]) & (rel <= SPACING_TOLERANCE[1])
        out[two & np.isfinite(spacing) & ~ok_spacing] |= SPACING
        # one sample cannot span more than one sample's range
        out[(c == 1) & (np.abs(e0 - e1) > SAMPLE_SPACING_M)] |= SPACING
        # positions
        elev = np.stack([e0, e1])
        finite = np.isfinite(elev).all(0) & np.isfinite(la).all(0) & np.isfinite(lo).all(0)
        beyond = ((np.abs(la) > 90.0) | (np.abs(lo) > 180.0)).any(0)
        beyond |= ((elev < ELEVATION_RANGE[0]) | (elev > ELEVATION_RANGE[1])).any(0)
        dy = (la[0] - la[1]) * _M_PER_DEG
        dlon = (lo[0] - lo[1] + 180.0) % 360.0 - 180.0
        dx = dlon * _M_PER_DEG * np.cos(np.radians(la[0]))
        beyond |= np.hypot(dx, dy) > MAX_TILT * np.abs(e0 - e1) + TILT_SLACK_M
        out[(has & ~finite) | beyond] |= POSITION
    later, earlier = _pool_clashes(c, s)
    # of two clashing shots, one whose count already misfits its elevation span is the
    # culprit; otherwise either index may be the wrong one: both are marked
    sp_l, sp_e = (out[later] & SPACING) != 0, (out[earlier] & SPACING) != 0
    out[later[sp_l | ~sp_e]] |= POOL
    out[earlier[sp_e | ~sp_l]] |= POOL
    return out


def _pool_clashes(count: npt.NDArray[np.int64], start: npt.NDArray[np.int64]
                  ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """Pairs (shot, earlier shot) where a shot's samples start before the end of an
    earlier shot's (the earlier shot reaching furthest)."""
    idx = np.flatnonzero(count > 0)
    if idx.size < 2:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    st, end = start[idx], start[idx] + count[idx]
    run = np.maximum.accumulate(end)
    holder = np.maximum.accumulate(np.where(end == run, np.arange(idx.size), 0))
    clash = np.flatnonzero(st[1:] < run[:-1]) + 1
    return idx[clash], idx[holder[clash - 1]]


def duplicate_problems(shot_number: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """:data:`DUPLICATE` for every shot whose ``shot_number`` another shot also carries."""
    sn = np.asarray(shot_number)
    _, inverse, counts = np.unique(sn, return_inverse=True, return_counts=True)
    return np.where(counts[inverse] > 1, DUPLICATE, 0).astype(np.uint8)


def amplitude_problems(waveforms: npt.NDArray[np.floating], n_samples: npt.ArrayLike
                       ) -> npt.NDArray[np.uint8]:
    """:data:`AMPLITUDE` for shots with a finite sample outside :data:`DIGITISER_RANGE`
    (padding samples beyond ``n_samples`` are ignored)."""
    n = np.asarray(n_samples, dtype=np.int64)
    w = np.asarray(waveforms)
    if w.size == 0:
        return np.zeros(n.size, dtype=np.uint8)
    valid = np.arange(w.shape[1])[None, :] < n[:, None]
    with np.errstate(invalid="ignore"):
        outside = (w < DIGITISER_RANGE[0]) | (w > DIGITISER_RANGE[1])
    return np.where((outside & valid).any(axis=1), AMPLITUDE, 0).astype(np.uint8)


def describe_problems(problems: npt.NDArray[np.uint8], shot_number: npt.ArrayLike,
                      count: npt.ArrayLike, elev0: npt.ArrayLike, elev1: npt.ArrayLike
                      ) -> str:
    """One clause per kind of problem: how many shots, the first shot and its numbers."""
    sn = np.asarray(shot_number)
    c = np.asarray(count, dtype=np.int64)
    e0, e1 = np.asarray(elev0, np.float64), np.asarray(elev1, np.float64)
    parts = []
    for bit, name in PROBLEM_NAMES.items():
        hit = np.flatnonzero(problems & bit)
        if not hit.size:
            continue
        i = int(hit[0])
        what = f"{hit.size} with impossible {name} (first: shot {int(sn[i])}"
        if bit == SPACING:
            sp = (e0[i] - e1[i]) / max(int(c[i]) - 1, 1)
            what += (f", elevation_bin0 {e0[i]:.2f} m, elevation_lastbin {e1[i]:.2f} m, "
                     f"rx_sample_count {int(c[i])}: {sp:+.4f} m per sample where GEDI "
                     f"samples are {SAMPLE_SPACING_M:.4f} m apart (less up to 1 % off "
                     "nadir), bin0 highest")
        elif bit == POSITION:
            what += (": elevation, latitude or longitude missing or out of range, or the "
                     "first and last samples impossibly far apart")
        elif bit == DUPLICATE:
            what += ": another shot of the beam has the same shot_number"
        elif bit == POOL:
            what += ": its rx_sample_start_index/rx_sample_count overlap another shot's "
            what += "samples in rxwaveform"
        else:
            what += (f": a sample outside {DIGITISER_RANGE[0]:g}..{DIGITISER_RANGE[1]:g} "
                     "digitiser counts")
        parts.append(what + ")")
    return "; ".join(parts)
