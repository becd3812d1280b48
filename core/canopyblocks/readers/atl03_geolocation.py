"""The horizontal geolocation uncertainty an ATL03 file states for its photons.

ATL03 carries, per ~20 m geolocation segment, ``gtXX/geolocation/sigma_along`` and
``sigma_across``: the estimated 1-sigma along- and across-track uncertainty (m) of the
segment's reference photon from pointing and orbit knowledge. The per-block error bar
(``blocks/uncertainty.py``) propagates them through the terrain slope and the canopy
relief; where a file has none (subsetters drop them; the simulator writes none), it uses
ICESat-2's published figure instead.
"""

from __future__ import annotations

import numpy as np

from ._h5 import H5File

__all__ = ["GEOLOCATION_SIGMA_COLUMN", "segment_geolocation_sigma"]

#: ``track.extra`` column holding each photon's horizontal geolocation 1-sigma (m):
#: ``sqrt(sigma_along^2 + sigma_across^2)`` of its segment, NaN where not stated.
GEOLOCATION_SIGMA_COLUMN = "geolocation_sigma"

#: Stated values above this (m) are taken as not stated (fill values, damaged files).
_PLAUSIBLE_MAX_M = 100.0


def segment_geolocation_sigma(f: H5File, beam: str, segment_id: np.ndarray
                              ) -> np.ndarray | None:
    """``sqrt(sigma_along^2 + sigma_across^2)`` (m) of each of the given segments.

    Parameters
    ----------
    f : H5File
        The open ATL03 file.
    beam : str
        Beam group (``"gt1r"``).
    segment_id : ndarray of int
        ``geolocation/segment_id`` of the segments wanted.

    Returns
    -------
    ndarray of float or None
        One value per ``segment_id``; NaN where the file's value is missing, a fill value,
        not positive or over 100 m. None when the file states none at all.
    """
    g = f"{beam}/geolocation"
    names = (f"{g}/segment_id", f"{g}/sigma_along", f"{g}/sigma_across")
    if not all(f.is_dataset(n) for n in names):
        return None
    ids = f.read(names[0], dtype=np.int64)
    along = f.read(names[1], dtype=np.float64)
    across = f.read(names[2], dtype=np.float64)
    if not (ids.ndim == 1 and along.shape == ids.shape == across.shape) or not ids.size:
        return None
    with np.errstate(invalid="ignore", over="ignore"):
        radial = np.hypot(along, across)
        bad = ~(np.isfinite(along) & np.isfinite(across) & (along > 0) & (across > 0)
                & (radial <= _PLAUSIBLE_MAX_M))
    radial[bad] = np.nan
    order = np.argsort(ids, kind="stable")
    sid = ids[order]
    want = np.asarray(segment_id, np.int64)
    pos = np.clip(np.searchsorted(sid, want), 0, sid.size - 1)
    out = np.where(sid[pos] == want, radial[order][pos], np.nan)
    return out if np.isfinite(out).any() else None
