"""The solar background rate of an ATL03 beam (``gtXX/bckgrd_atlas``).

ATL03 records, every 50 shots (~35 m), the background photon rate the onboard
algorithm measured in the telemetry band: ``bckgrd_atlas/delta_time`` (s, the photons'
clock) and ``bckgrd_atlas/bckgrd_rate`` (photons per second; ~0.1-0.3 MHz at night,
1-5 MHz by day).  Only the records spanning the photons read are kept.  Fill values
(3.4028235e38), negative and non-finite rates are dropped; a beam without the group,
or without one valid record, has no background rate (None), and the classifier then
estimates it from the photons.
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import FileFormatError
from ..photons import BackgroundRate
from ._h5 import H5File

__all__ = ["read_background_rate", "RATE_LIMIT_HZ"]

log = logging.getLogger(__name__)

RATE_LIMIT_HZ = 1.0e9
"""Rates at or above this (photons/s) are fill values or damage, never a measurement
(the brightest daytime scenes give ~10 MHz)."""

_MARGIN_S = 0.05  # one record (50 shots = 5 ms) is enough; keep a few more
_NEAREST_S = 1.0  # a record further than this (7 km of track) from the photons is not theirs


def read_background_rate(f: H5File, beam: str, t_min: float, t_max: float
                         ) -> BackgroundRate | None:
    """The beam's background rate between ``t_min`` and ``t_max`` (``delta_time``, s).

    Returns
    -------
    BackgroundRate or None
        None when the file has no usable ``bckgrd_atlas`` for this beam.
    """
    g = f"{beam}/bckgrd_atlas"
    if not (f.is_dataset(f"{g}/delta_time") and f.is_dataset(f"{g}/bckgrd_rate")):
        return None
    try:
        shape_t, shape_r = f.shape(f"{g}/delta_time"), f.shape(f"{g}/bckgrd_rate")
    except FileFormatError as exc:
        log.warning("%s: %s cannot be read (%s); the background rate is estimated from "
                    "the photons instead", f.path, g, str(exc).splitlines()[0])
        return None
    if len(shape_t) != 1 or shape_t != shape_r or shape_t[0] == 0:
        log.warning("%s: %s/delta_time and bckgrd_rate differ in shape (%s, %s); the "
                    "background rate is estimated from the photons instead",
                    f.path, g, shape_t, shape_r)
        return None
    try:
        t = f.read(f"{g}/delta_time", dtype=np.float64)
        r = f.read(f"{g}/bckgrd_rate", dtype=np.float64)
    except FileFormatError as exc:  # damage here must not cost the photons
        log.warning("%s: %s cannot be read (%s); the background rate is estimated from "
                    "the photons instead", f.path, g, str(exc).splitlines()[0])
        return None
    ok = np.isfinite(t) & np.isfinite(r) & (r >= 0) & (r < RATE_LIMIT_HZ)
    if np.isfinite(t_min) and np.isfinite(t_max):
        near = ok & (t >= t_min - _MARGIN_S) & (t <= t_max + _MARGIN_S)
        if not near.any() and ok.any():  # photons between two records: the nearest one
            i = np.flatnonzero(ok)
            j = i[np.argmin(np.abs(t[i] - 0.5 * (t_min + t_max)))]
            near = np.zeros_like(ok)
            near[j] = abs(t[j] - 0.5 * (t_min + t_max)) <= _NEAREST_S + 0.5 * (t_max - t_min)
        ok = near
    if not ok.any():
        log.warning("%s: %s/bckgrd_rate holds no valid rate for these photons; the "
                    "background rate is estimated from the photons instead", f.path, g)
        return None
    return BackgroundRate(t[ok], r[ok])
