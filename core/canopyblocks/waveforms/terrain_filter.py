"""The seed-003 terrain outlier filter over neighbouring footprints (DESIGN 4.6).

Per beam, in along-track order: a footprint is an outlier when its ground lies more
than ``max_below`` metres below the median ground of its neighbours (``neighbours``
footprints on either side, itself excluded) or its canopy height exceeds
``max_height`` metres. Outliers are flagged, not dropped. Footprints without a ground
(NaN) are skipped: they are never outliers and never anyone's neighbour.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import InputError

__all__ = ["terrain_outliers"]


def terrain_outliers(ground: npt.ArrayLike, height: npt.ArrayLike, *, neighbours: int = 5,
                     max_below: float = 10.0, max_height: float = 60.0
                     ) -> npt.NDArray[np.bool_]:
    """Flag terrain outliers along one beam.

    Parameters
    ----------
    ground : array-like, shape (n,)
        Ground elevation (m), in along-track order; NaN where unknown.
    height : array-like, shape (n,)
        Canopy height above the ground (m); NaN where unknown.
    neighbours : int
        Footprints on each side whose ground median is the reference (seed 003: 5).
    max_below : float
        Metres below that median beyond which the ground is an outlier (seed 003: 10).
    max_height : float
        Canopy heights above this (m) are outliers (seed 003: 60).

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    z = np.asarray(ground, dtype=np.float64)
    h = np.asarray(height, dtype=np.float64)
    if z.ndim != 1 or h.shape != z.shape:
        raise InputError(f"ground and height must be 1-D arrays of the same length; got "
                         f"shapes {z.shape} and {h.shape}")
    if isinstance(neighbours, bool) or not isinstance(neighbours, (int, np.integer)) \
            or neighbours < 1:
        raise InputError(f"neighbours must be an integer >= 1; got {neighbours!r}")
    if not (max_below > 0 and max_height > 0):
        raise InputError(f"max_below and max_height must be > 0 (m); got {max_below!r} "
                         f"and {max_height!r}")
    out = np.zeros(z.shape, dtype=bool)
    valid = np.isfinite(z)
    zv = z[valid]
    if len(zv) >= 2:
        w = int(neighbours)
        padded = np.concatenate([np.full(w, np.nan), zv, np.full(w, np.nan)])
        windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * w + 1).copy()
        windows[:, w] = np.nan                      # the footprint itself is no neighbour
        has = np.isfinite(windows).any(axis=1)
        median = np.full(len(zv), np.nan)
        if has.any():
            median[has] = np.nanmedian(windows[has], axis=1)
        low = np.zeros(len(zv), dtype=bool)
        low[has] = zv[has] < median[has] - max_below
        out[np.nonzero(valid)[0]] = low
    with np.errstate(invalid="ignore"):
        out |= valid & np.isfinite(h) & (h > max_height)
    return out
