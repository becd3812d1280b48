"""The telemetry window of simulated background photons (DESIGN.md 3.3).

ATL03 keeps the photons of a height window (the telemetry band) that the instrument
sets from a coarse onboard DEM, tens to hundreds of metres tall; solar background
photons fill it uniformly. The simulator does the same: the window follows a coarse
terrain made from the airborne cloud's ground, smoothed over ``smoothing`` metres, and
is ``2 x half_height`` tall. It knows nothing of any footprint's ground or canopy, so an
estimator that sees only the background photons learns nothing about the canopy.

Coarse terrain: the ground points (ASPRS class 2; when the cloud has none, the lowest
point of each cell) are averaged on cells of ``smoothing / 8`` metres; the terrain at a
place is the mean of the cells weighted by a Gaussian of standard deviation
``smoothing / 4`` of their distance (so a 1 km smoothing behaves like a moving average
about 1 km wide). It is evaluated at points every ``smoothing / 8`` metres along the
track and interpolated to the shots. Heights are in the cloud's vertical datum.
"""

from __future__ import annotations

import numpy as np

from ..errors import NoUsableDataError
from ..readers.las import LasPoints
from .tracks import SimTrack, shots_along

__all__ = ["coarse_terrain", "telemetry_window"]

_MAX_PAIRS = 4_000_000  # query x cell pairs evaluated at once


def _cells(points: LasPoints, exclude: tuple[int, ...],
           cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (x, y) and coarse ground height of the cells holding ground points."""
    keep = np.isfinite(points.x) & np.isfinite(points.y) & np.isfinite(points.z)
    if exclude:
        keep &= ~np.isin(points.classification, exclude)
    ground = keep & (points.classification == 2)
    use_min = not ground.any()
    sel = keep if use_min else ground
    x, y, z = points.x[sel], points.y[sel], points.z[sel]
    if x.size == 0:
        raise NoUsableDataError("the airborne cloud holds no usable point to set the "
                                "telemetry window of the background photons from")
    x0, y0 = float(x.min()), float(y.min())
    i = np.floor((x - x0) / cell).astype(np.int64)
    j = np.floor((y - y0) / cell).astype(np.int64)
    nx = int(i.max()) + 1
    key = j * nx + i
    uniq, inv = np.unique(key, return_inverse=True)
    if use_min:
        v = np.full(uniq.size, np.inf)
        np.minimum.at(v, inv, z)
    else:
        v = np.bincount(inv, z, minlength=uniq.size) / np.bincount(inv, minlength=uniq.size)
    cx = x0 + (uniq % nx + 0.5) * cell
    cy = y0 + (uniq // nx + 0.5) * cell
    return cx, cy, v


def coarse_terrain(points: LasPoints, track: SimTrack, s: np.ndarray, *,
                   smoothing: float = 1000.0,
                   exclude_classes: tuple[int, ...] = (7, 18)) -> np.ndarray:
    """The airborne ground smoothed over ``smoothing`` metres, at distances ``s`` along
    ``track`` (metres; heights in the cloud's vertical datum).

    Raises
    ------
    NoUsableDataError
        The cloud has no usable point.
    """
    cell = smoothing / 8.0
    sigma = smoothing / 4.0
    cx, cy, v = _cells(points, tuple(exclude_classes), cell)
    qx, qy, qs = shots_along(track, cell)
    if qs.size == 0 or qs[-1] < track.length:  # the track's end point too
        end = np.asarray(track.vertices[-1], dtype=np.float64)
        qx, qy, qs = (np.append(qx, end[0]), np.append(qy, end[1]),
                      np.append(qs, track.length))
    out = np.empty(qs.size)
    step = max(1, _MAX_PAIRS // max(cx.size, 1))
    for a in range(0, qs.size, step):  # chunks of query points: bounded memory
        d2 = (qx[a:a + step, None] - cx[None, :]) ** 2 + (qy[a:a + step, None] - cy[None, :]) ** 2
        # relative to the nearest cell, so a query far from every cell still gets one
        w = np.exp(-(d2 - d2.min(axis=1, keepdims=True)) / (2.0 * sigma * sigma))
        out[a:a + step] = (w @ v) / w.sum(axis=1)
    return np.interp(np.asarray(s, dtype=np.float64), qs, out)


def telemetry_window(points: LasPoints, track: SimTrack, s: np.ndarray, *,
                     half_height: float, smoothing: float,
                     exclude_classes: tuple[int, ...] = (7, 18)
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Bottom and top (metres, the cloud's vertical datum) of the telemetry window at
    distances ``s`` along ``track``: the coarse terrain -/+ ``half_height``."""
    centre = coarse_terrain(points, track, s, smoothing=smoothing,
                            exclude_classes=exclude_classes)
    return centre - half_height, centre + half_height
