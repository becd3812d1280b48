"""Checks and masks shared by the readers: bounding boxes and along-track ranges."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..errors import InputError

__all__ = ["BBox", "SRange", "check_bbox", "check_s_range", "bbox_mask", "s_mask"]

BBox = tuple[float, float, float, float]
SRange = tuple[float, float]


def check_bbox(bbox: Sequence[float] | None) -> BBox | None:
    """Validate ``(lon_min, lat_min, lon_max, lat_max)`` in WGS84 degrees.

    Raises
    ------
    InputError
        Wrong length, non-finite values, min > max, or out of range.
    """
    if bbox is None:
        return None
    try:
        vals = tuple(float(v) for v in bbox)
    except (TypeError, ValueError):
        raise InputError(
            f"bbox {bbox!r} must be four numbers (lon_min, lat_min, lon_max, lat_max) in degrees"
        ) from None
    if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
        raise InputError(
            f"bbox {bbox!r} must be four finite numbers (lon_min, lat_min, lon_max, lat_max) "
            "in degrees"
        )
    lon0, lat0, lon1, lat1 = vals
    if lon0 > lon1 or lat0 > lat1:
        raise InputError(
            f"bbox {bbox!r}: lon_min > lon_max or lat_min > lat_max; give "
            "(lon_min, lat_min, lon_max, lat_max) (a box across the antimeridian is not "
            "supported: read the two halves separately)"
        )
    if lat0 < -90 or lat1 > 90 or lon0 < -180 or lon1 > 180:
        raise InputError(f"bbox {bbox!r}: latitudes must be in [-90, 90], longitudes in "
                         "[-180, 180] degrees")
    return (lon0, lat0, lon1, lat1)


def check_s_range(s_range: Sequence[float] | None) -> SRange | None:
    """Validate ``(s_min, s_max)`` in metres along track (s_min <= s_max)."""
    if s_range is None:
        return None
    try:
        vals = tuple(float(v) for v in s_range)
    except (TypeError, ValueError):
        raise InputError(f"s_range {s_range!r} must be two numbers (s_min, s_max) in metres"
                         ) from None
    if len(vals) != 2 or any(math.isnan(v) for v in vals) or vals[0] > vals[1]:
        raise InputError(
            f"s_range {s_range!r} must be (s_min, s_max) in metres with s_min <= s_max"
        )
    return (vals[0], vals[1])


def bbox_mask(lon: np.ndarray, lat: np.ndarray, bbox: BBox | None) -> np.ndarray:
    """Photons inside ``bbox`` (edges included)."""
    if bbox is None:
        return np.ones(np.shape(lon), dtype=bool)
    lon0, lat0, lon1, lat1 = bbox
    return (lon >= lon0) & (lon <= lon1) & (lat >= lat0) & (lat <= lat1)


def s_mask(s: np.ndarray, s_range: SRange | None) -> np.ndarray:
    """Photons with ``s_min <= s <= s_max``."""
    if s_range is None:
        return np.ones(np.shape(s), dtype=bool)
    return (s >= s_range[0]) & (s <= s_range[1])
