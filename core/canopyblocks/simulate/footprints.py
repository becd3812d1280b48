"""Airborne points inside each simulated footprint, with Gaussian weights.

For a chunk of consecutive shots, one ball query on a 2-D KD-tree (built once per
cloud) gathers the candidate points; they are sorted along the chunk's direction, so
the points within R of each shot lie in a contiguous slab found by ``searchsorted``;
the exact distance test then keeps the points with ``r <= R``.  Everything is
vectorised: the ragged result is a CSR-like set of (shot, point) pairs sorted by shot.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["FootprintPairs", "CloudIndex", "footprint_weights"]

log = logging.getLogger(__name__)


def footprint_weights(r2: np.ndarray, radius: float) -> np.ndarray:
    """Gaussian footprint weights ``exp(-2 r^2 / R^2)`` (1/e^2 at ``r = R``).

    Parameters
    ----------
    r2 : ndarray
        Squared horizontal distances to the footprint centre, m^2.
    radius : float
        Footprint radius R, metres.
    """
    return np.exp(-2.0 * np.asarray(r2, dtype=np.float64) / (radius * radius))


@dataclass(eq=False)
class FootprintPairs:
    """The (shot, point) pairs of a chunk of shots, sorted by shot.

    Attributes
    ----------
    n_shots : int
        Shots in the chunk (local ids 0..n_shots-1).
    shot : ndarray int64
        Local shot id of each pair (non-decreasing).
    point : ndarray int64
        Index of the airborne point in the cloud.
    z : ndarray float64
        The point's height, metres.
    weight : ndarray float64
        Footprint weight ``exp(-2 r^2 / R^2)`` (not normalised).
    indptr : ndarray int64
        ``indptr[k]:indptr[k+1]`` are the pairs of shot ``k``.
    """

    n_shots: int
    shot: np.ndarray
    point: np.ndarray
    z: np.ndarray
    weight: np.ndarray
    indptr: np.ndarray

    @property
    def counts(self) -> np.ndarray:
        """Points per footprint."""
        return np.diff(self.indptr)


class CloudIndex:
    """A 2-D KD-tree over an airborne cloud, built once, answering footprint queries.

    Parameters
    ----------
    x, y, z : ndarray
        Point coordinates, metres (one metric CRS).
    ids : ndarray of int, optional
        Index of each point in the original cloud (when these are a subset of it);
        default ``arange(len(x))``.
    """

    def __init__(self, x: np.ndarray, y: np.ndarray, z: np.ndarray,
                 ids: np.ndarray | None = None) -> None:
        self.x = np.ascontiguousarray(x, dtype=np.float64)
        self.y = np.ascontiguousarray(y, dtype=np.float64)
        self.z = np.ascontiguousarray(z, dtype=np.float64)
        self.ids = (np.arange(self.x.size, dtype=np.int64) if ids is None
                    else np.asarray(ids, dtype=np.int64))
        # centre coordinates so the tree works with small numbers
        self._ox, self._oy = (float(self.x.mean()), float(self.y.mean())) if self.x.size else (0, 0)
        xy = np.column_stack([self.x - self._ox, self.y - self._oy])
        self.tree = cKDTree(xy, leafsize=32, balanced_tree=False, compact_nodes=False)

    def pairs(self, sx: np.ndarray, sy: np.ndarray, radius: float) -> FootprintPairs:
        """Points within ``radius`` (metres) of each shot centre ``(sx, sy)``.

        The shots should be a short run along the track (tens to a few hundred metres);
        the cost grows with the run's width across its own direction.
        """
        sx = np.asarray(sx, dtype=np.float64)
        sy = np.asarray(sy, dtype=np.float64)
        k = sx.size
        empty = FootprintPairs(k, np.empty(0, np.int64), np.empty(0, np.int64),
                               np.empty(0), np.empty(0), np.zeros(k + 1, np.int64))
        if k == 0 or self.x.size == 0:
            return empty
        lx, ly = sx - self._ox, sy - self._oy
        cx, cy = float(lx.mean()), float(ly.mean())
        reach = float(np.max(np.hypot(lx - cx, ly - cy))) + radius
        found = self.tree.query_ball_point([cx, cy], reach * (1 + 1e-9) + 1e-6,
                                           return_sorted=False)
        cand = np.fromiter(found, dtype=np.int64, count=len(found))
        if cand.size == 0:
            return empty
        # the chunk's own direction (first -> last shot), or x when it is a single shot
        dx, dy = lx[-1] - lx[0], ly[-1] - ly[0]
        norm = float(np.hypot(dx, dy))
        ux, uy = (dx / norm, dy / norm) if norm > 0 else (1.0, 0.0)
        px = self.x[cand] - self._ox
        py = self.y[cand] - self._oy
        v = -(px - cx) * uy + (py - cy) * ux
        v_shot = -(lx - cx) * uy + (ly - cy) * ux
        keep = (v >= v_shot.min() - radius) & (v <= v_shot.max() + radius)
        # candidates in cloud order: the pair order (hence the photons drawn for a seed)
        # then depends only on the cloud, not on the tree's internals or a cropped read
        by_id = np.argsort(cand[keep])
        cand, px, py = cand[keep][by_id], px[keep][by_id], py[keep][by_id]
        u = (px - cx) * ux + (py - cy) * uy
        order = np.argsort(u, kind="stable")
        cand, px, py, u = cand[order], px[order], py[order], u[order]
        u_shot = (lx - cx) * ux + (ly - cy) * uy
        lo = np.searchsorted(u, u_shot - radius, side="left")
        hi = np.searchsorted(u, u_shot + radius, side="right")
        cnt = hi - lo
        total = int(cnt.sum())
        if total == 0:
            return empty
        shot = np.repeat(np.arange(k, dtype=np.int64), cnt)
        start = np.cumsum(cnt) - cnt
        pos = np.arange(total, dtype=np.int64) - np.repeat(start - lo, cnt)
        if float(np.max(np.abs(v_shot))) < 1e-9:
            # shots on the chunk's line (a straight chunk): r^2 = du^2 + v^2
            v_c = -(px - cx) * uy + (py - cy) * ux
            du = u[pos] - np.repeat(u_shot, cnt)
            r2 = du * du + (v_c * v_c)[pos]
        else:
            ddx = px[pos] - np.repeat(lx, cnt)
            ddy = py[pos] - np.repeat(ly, cnt)
            r2 = ddx * ddx + ddy * ddy
        inside = r2 <= radius * radius
        shot, pos, r2 = shot[inside], pos[inside], r2[inside]
        point = cand[pos]
        indptr = np.zeros(k + 1, np.int64)
        np.cumsum(np.bincount(shot, minlength=k), out=indptr[1:])
        return FootprintPairs(k, shot, point, self.z[point], footprint_weights(r2, radius),
                              indptr)
