"""Airborne points under large footprints, weighted as a waveform sees them (DESIGN 4.9).

Shared by the waveform simulators (GEDI, dual-wavelength): for footprint centres, the
points within 3 sigma (found with the ``simulate`` spatial index, never by scanning every
point per footprint), each weighted by the Gaussian footprint and by ``1 / (points in its
1.5 m cell within that footprint)`` so a denser survey patch does not count more.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import NoUsableDataError
from ..readers.las import LasPoints
from .footprint_index import CloudIndex

__all__ = ["FootprintReturns", "footprint_returns", "footprint_index", "EXCLUDED_CLASSES"]

#: ASPRS classes that are not surfaces (low and high noise): never part of a waveform.
EXCLUDED_CLASSES: tuple[int, ...] = (7, 18)


def footprint_index(points: LasPoints) -> tuple[CloudIndex, np.ndarray]:
    """A spatial index over the points waveforms see (finite, not noise classes) and
    their positions in ``points``; build it once for several simulations."""
    keep = np.isfinite(points.x) & np.isfinite(points.y) & np.isfinite(points.z)
    keep &= ~np.isin(points.classification, EXCLUDED_CLASSES)
    ids = np.flatnonzero(keep)
    return CloudIndex(points.x[ids], points.y[ids], points.z[ids]), ids


@dataclass(frozen=True)
class FootprintReturns:
    """Point returns of ``n`` footprints (flat arrays, one entry per point-footprint pair).

    Attributes
    ----------
    n : int
        Footprints.
    shot : ndarray int64
        Footprint of each return.
    z : ndarray float64
        Elevation (m, the points' vertical datum).
    weight : ndarray float64
        Footprint x density weight.
    ground : ndarray bool
        Class-2 point.
    r2 : ndarray float64
        Squared distance to the footprint centre (m^2).
    """

    n: int
    shot: np.ndarray
    z: np.ndarray
    weight: np.ndarray
    ground: np.ndarray
    r2: np.ndarray

    def per_shot(self, values: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """Sum of ``values`` per footprint (over ``mask``)."""
        if mask is None:
            return np.bincount(self.shot, weights=values, minlength=self.n)
        return np.bincount(self.shot[mask], weights=values[mask], minlength=self.n)


def footprint_returns(points: LasPoints, sx: np.ndarray, sy: np.ndarray, sigma: float, *,
                      density_cell: float = 1.5,
                      index: tuple[CloudIndex, np.ndarray] | None = None
                      ) -> FootprintReturns:
    """Weighted returns of the points within ``3 sigma`` of each centre ``(sx, sy)``.

    Parameters
    ----------
    points : LasPoints
        Airborne points (metric CRS, metres).
    sx, sy : ndarray
        Footprint centres in the points' CRS.
    sigma : float
        Gaussian footprint sigma (m); GEDI 5.5.
    density_cell : float
        Cell (m) of the density weight; 0 disables it.
    index : optional
        :func:`footprint_index` of ``points``, built once for several calls.

    Raises
    ------
    NoUsableDataError
        No point under any footprint.
    """
    cloud, ids = footprint_index(points) if index is None else index
    pairs = cloud.pairs(np.asarray(sx, float), np.asarray(sy, float), 3.0 * sigma)
    shot, pt = pairs.shot.astype(np.int64), pairs.point
    if pt.size == 0:
        raise NoUsableDataError("no airborne point under the simulated footprints: check "
                                "the track against the tiles' extent")
    x, y, z = cloud.x[pt], cloud.y[pt], cloud.z[pt]
    r2 = (x - np.asarray(sx, float)[shot]) ** 2 + (y - np.asarray(sy, float)[shot]) ** 2
    w = np.exp(-r2 / (2.0 * sigma ** 2))
    if density_cell > 0:
        cell = (np.floor(x / density_cell).astype(np.int64) * 1_000_003
                + np.floor(y / density_cell).astype(np.int64))
        key = shot * (1 << 40) + (cell % (1 << 40))
        _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
        w = w / counts[inv]
    ground = points.classification[ids[pt]] == 2
    return FootprintReturns(int(np.asarray(sx).size), shot, z, w, ground, r2)
