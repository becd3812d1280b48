"""Simulated ground tracks: straight lines or polylines, and shot positions along them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, NoUsableDataError

__all__ = ["SimTrack", "line_through", "shots_along"]


@dataclass(frozen=True)
class SimTrack:
    """A polyline in the point cloud's metric CRS (metres); shots run from first vertex.

    Attributes
    ----------
    vertices : tuple of (x, y)
        At least two distinct points.
    name : str
        Track id used in outputs (default ``"gt1r"``, an ATL03 strong beam).
    """

    vertices: tuple[tuple[float, float], ...]
    name: str = "gt1r"

    def __post_init__(self) -> None:
        try:
            v = np.asarray(self.vertices, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"a track needs at least two finite (x, y) vertices in metres; "
                             f"got {_describe(self.vertices)}") from None
        if v.ndim != 2 or v.shape[0] < 2 or v.shape[1] != 2 or not np.all(np.isfinite(v)):
            raise InputError(
                f"a track needs at least two finite (x, y) vertices in metres; got "
                f"{_describe(self.vertices)}")
        if float(np.sum(np.hypot(*np.diff(v, axis=0).T))) <= 0:
            raise InputError("the track has zero length: give two different end points")
        object.__setattr__(self, "vertices", tuple((float(a), float(b)) for a, b in v))

    @classmethod
    def line(cls, x0: float, y0: float, x1: float, y1: float, name: str = "gt1r") -> SimTrack:
        """A straight track from (x0, y0) to (x1, y1), metres."""
        return cls(((x0, y0), (x1, y1)), name)

    @property
    def length(self) -> float:
        """Polyline length, metres."""
        v = np.asarray(self.vertices)
        return float(np.sum(np.hypot(*np.diff(v, axis=0).T)))


def line_through(bounds: tuple[float, float, float, float], azimuth: float, *,
                 inset: float = 0.0, centre: tuple[float, float] | None = None,
                 name: str = "gt1r") -> SimTrack:
    """A straight track through ``centre`` (default the middle of ``bounds``) at an azimuth.

    Parameters
    ----------
    bounds : (xmin, ymin, xmax, ymax)
        Survey extent, metres.
    azimuth : float
        Degrees clockwise from grid north (0 = northward, 90 = eastward); the track
        runs in that direction.
    inset : float
        Clip to the extent shrunk by this many metres on every side (e.g. the footprint
        radius, so footprints stay inside the survey).
    centre : (x, y), optional
        A point the line passes through; must lie inside the (shrunk) extent.

    Raises
    ------
    NoUsableDataError
        When the shrunk extent is empty or the centre lies outside it.
    """
    from ..arguments import check_array, check_number
    check_array(bounds, "line_through: bounds", what="(xmin, ymin, xmax, ymax) in metres", size=4)
    check_number(azimuth, "line_through: azimuth", unit=" degrees")
    if not math.isfinite(azimuth):
        raise InputError(f"azimuth must be a finite number of degrees; got {azimuth!r}")
    xmin, ymin, xmax, ymax = (float(b) for b in bounds)
    xmin, ymin, xmax, ymax = xmin + inset, ymin + inset, xmax - inset, ymax - inset
    if not (xmin < xmax and ymin < ymax):
        raise NoUsableDataError(
            f"the survey extent {bounds} is smaller than twice the inset ({inset} m): "
            "use a smaller footprint or a larger survey")
    cx, cy = ((xmin + xmax) / 2, (ymin + ymax) / 2) if centre is None else centre
    if not (xmin <= cx <= xmax and ymin <= cy <= ymax):
        raise NoUsableDataError(f"track centre {(cx, cy)} lies outside the usable extent")
    a = math.radians(azimuth)
    dx, dy = math.sin(a), math.cos(a)
    # Liang-Barsky: parameter range of the line cx + t*d inside the box
    t_lo, t_hi = -math.inf, math.inf
    for p, d, lo, hi in ((cx, dx, xmin, xmax), (cy, dy, ymin, ymax)):
        if abs(d) < 1e-12:
            continue
        t1, t2 = (lo - p) / d, (hi - p) / d
        t_lo, t_hi = max(t_lo, min(t1, t2)), min(t_hi, max(t1, t2))
    return SimTrack(((cx + t_lo * dx, cy + t_lo * dy), (cx + t_hi * dx, cy + t_hi * dy)), name)


def shots_along(track: SimTrack, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Footprint centres every ``spacing`` metres along ``track`` from its first vertex.

    Returns
    -------
    x, y, s : ndarray float64
        Centres (metres, track CRS) and along-track distance (metres, from 0).
    """
    if not (spacing > 0):
        raise InputError(f"shot spacing must be > 0 m; got {spacing!r}")
    v = np.asarray(track.vertices, dtype=np.float64)
    seg = np.hypot(*np.diff(v, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    n = int(math.floor(cum[-1] / spacing + 1e-9)) + 1
    s = np.arange(n, dtype=np.float64) * spacing
    return np.interp(s, cum, v[:, 0]), np.interp(s, cum, v[:, 1]), s


def polyline_from_points(points: Sequence[tuple[float, float]], name: str = "gt1r") -> SimTrack:
    """A :class:`SimTrack` from a sequence of (x, y) vertices (metres)."""
    return SimTrack(tuple((float(x), float(y)) for x, y in points), name)


def _describe(value: object) -> str:
    from ..arguments import describe

    return describe(value)
