"""UTC date and time of ICESat-2 and GEDI ``delta_time``.

Both missions count ``delta_time`` in GPS seconds since their standard data product epoch,
2018-01-01T00:00:00 UTC (ATL03 ``ancillary_data/atlas_sdp_gps_epoch`` and GEDI
``ancillary/master_time_epoch``: 1198800018 GPS seconds).  GPS time runs ahead of UTC by
the leap seconds inserted since 1980: 18 s from 2017-01-01, the last one so far; so a
``delta_time`` of the missions' era is UTC = 2018-01-01 + ``delta_time`` seconds.  A
time before 2017-01-01 (another epoch: MABEL, simulated files that count from their first
shot) gives NaT rather than a wrong date.
"""

from __future__ import annotations

import os

import numpy as np
import numpy.typing as npt

__all__ = ["SDP_EPOCH_GPS_SECONDS", "utc_from_delta_time", "file_counts_from_sdp_epoch"]

#: GPS seconds (since 1980-01-06) of 2018-01-01T00:00:00 UTC, the missions' epoch.
SDP_EPOCH_GPS_SECONDS: float = 1198800018.0

_GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ns")
_GPS_MINUS_UTC = 18.0  # leap seconds since 2017-01-01 (IERS; none inserted since)
_LAST_LEAP = np.datetime64("2017-01-01T00:00:00", "ns")


def utc_from_delta_time(delta_time: npt.ArrayLike,
                        epoch_gps_seconds: float = SDP_EPOCH_GPS_SECONDS
                        ) -> npt.NDArray[np.datetime64]:
    """UTC (``datetime64[ns]``) of ``delta_time`` seconds after the epoch.

    Parameters
    ----------
    delta_time : array-like of float
        Seconds since the epoch (ATL03 ``delta_time``, GEDI ``delta_time``).
    epoch_gps_seconds : float
        The epoch in GPS seconds (default the missions' 1198800018, 2018-01-01 UTC).

    Returns
    -------
    ndarray of datetime64[ns]
        NaT where ``delta_time`` is not finite or falls before 2017-01-01 (the last leap
        second: an older time is not of these missions' clock).
    """
    from ..arguments import check_array, check_number
    arr = check_array(delta_time, "utc_from_delta_time: delta_time", scalar=True,
                      what="seconds since the epoch (numbers)") \
        if not (isinstance(delta_time, np.ndarray) and delta_time.dtype.kind == "f") \
        else delta_time
    check_number(epoch_gps_seconds, "utc_from_delta_time: epoch_gps_seconds")
    t = np.asarray(arr, dtype=np.float64) + float(epoch_gps_seconds) - _GPS_MINUS_UTC
    ok = np.isfinite(t)
    whole = np.floor(np.where(ok, t, 0.0))
    ns = np.round((np.where(ok, t, 0.0) - whole) * 1e9)
    out = (_GPS_EPOCH + whole.astype(np.int64).astype("timedelta64[s]")
           + ns.astype(np.int64).astype("timedelta64[ns]"))
    out[~ok | (out < _LAST_LEAP)] = np.datetime64("NaT")
    return out


def file_counts_from_sdp_epoch(path: str | os.PathLike[str]) -> bool:
    """False for a file written by canopyblocks (simulated GEDI waveforms, ATL03-layout
    photons simulated or converted: their ``delta_time`` counts from the first shot, not
    from the missions' epoch), True otherwise."""
    from ._h5 import open_h5

    try:
        with open_h5(path) as f:  # (a path, a URL or a file object)
            attrs = f.attrs("/")
            said = str(attrs.get("description", ""))
            return "simulated" not in attrs and "written by canopyblocks" not in said
    except (OSError, ImportError):
        return True
