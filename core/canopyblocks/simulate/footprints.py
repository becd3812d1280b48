"""Airborne points inside each simulated footprint, with Gaussian weights.

The cloud is binned once into a regular grid of square cells (a few dozen points per
cell, points of a cell in cloud order).  A run of shots on a straight line (the usual
case: a chunk of one track segment) gathers the points of the cells along its corridor
once; each point within ``R`` of the line then lies in the footprints of a contiguous
run of shots, those within the half chord ``sqrt(R^2 - v^2)`` of it along the line
(``v``: the point's distance from the line).  Any other set of shots is answered by
slabs along the run's direction and the exact distance test.  Everything is vectorised:
the result is a CSR-like set of (shot, point) pairs sorted by shot and, within a shot,
by height (ties in cloud order), so the order depends only on the cloud.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

try:  # scipy's C++ counting sort of COO entries into CSR (stable; optional speed-up)
    from scipy.sparse._sparsetools import coo_tocsr as _coo_tocsr
except ImportError:  # pragma: no cover - private scipy API moved
    _coo_tocsr = None

__all__ = ["FootprintPairs", "CloudIndex", "footprint_weights"]

log = logging.getLogger(__name__)

#: Mean number of points per grid cell of :class:`CloudIndex`.
POINTS_PER_CELL = 24.0

#: Shots farther than this from the line through a run's first and last shot (metres)
#: make the run "bent": it is answered by the general (slower) method.
_LINE_TOL = 1e-7


def footprint_weights(r2: np.ndarray, radius: float) -> np.ndarray:
    """Gaussian footprint weights ``exp(-2 r^2 / R^2)`` (1/e^2 at ``r = R``).

    Parameters
    ----------
    r2 : ndarray
        Squared horizontal distances to the footprint centre, m^2.
    radius : float
        Footprint radius R, metres.
    """
    return np.exp(np.asarray(r2, dtype=np.float64) * (-2.0 / (radius * radius)))


@dataclass(eq=False)
class FootprintPairs:
    """The (shot, point) pairs of a run of shots, sorted by shot.

    Attributes
    ----------
    n_shots : int
        Shots in the run (local ids 0..n_shots-1).
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
    height_sorted : bool
        True when the pairs of each shot are sorted by ``z`` (ties by ``point``), as
        :meth:`CloudIndex.pairs` returns them; :func:`~.truth.footprint_truth` sorts
        them otherwise.
    """

    n_shots: int
    shot: np.ndarray
    point: np.ndarray
    z: np.ndarray
    weight: np.ndarray
    indptr: np.ndarray
    height_sorted: bool = False
    _cw: np.ndarray | None = field(default=None, repr=False)

    @property
    def counts(self) -> np.ndarray:
        """Points per footprint."""
        return np.diff(self.indptr)

    @property
    def cumulative_weight(self) -> np.ndarray:
        """``cumsum(weight)`` over all pairs (computed once)."""
        if self._cw is None:
            self._cw = np.cumsum(self.weight)
        return self._cw

    def sorted_by_height(self) -> FootprintPairs:
        """These pairs with each shot's pairs sorted by (height, point)."""
        if self.height_sorted:
            return self
        order = np.lexsort((self.point, self.z, self.shot))
        return FootprintPairs(self.n_shots, self.shot[order], self.point[order],
                              self.z[order], self.weight[order], self.indptr, True)


def _empty_pairs(k: int) -> FootprintPairs:
    e = np.empty(0, np.int64)
    return FootprintPairs(k, e, e.copy(), np.empty(0), np.empty(0), np.zeros(k + 1, np.int64),
                          True)


def _ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + c)`` for each start ``s`` and count ``c``."""
    total = int(counts.sum())
    if total == 0:
        return np.empty(0, np.int64)
    first = np.cumsum(counts) - counts
    return np.arange(total, dtype=np.int64) + np.repeat(starts - first, counts)


def _sorted_index(edges: np.ndarray, t: np.ndarray, right: bool) -> np.ndarray:
    """``np.searchsorted(edges, t, side)`` for nearly evenly spaced sorted ``edges``.

    An arithmetic guess corrected by exact comparisons (identical result; cheaper than
    a binary search per value).
    """
    k = edges.size
    step = (float(edges[-1]) - float(edges[0])) / (k - 1) if k > 1 else 0.0
    if not step > 0:
        return np.searchsorted(edges, t, side="right" if right else "left")
    i = np.clip(np.ceil((t - float(edges[0])) / step), 0, k).astype(np.int64)
    for _ in range(4):
        # move left while edges[i-1] >= t (> for right), right while edges[i] < t (<=)
        prev = edges[np.maximum(i - 1, 0)]
        cur = edges[np.minimum(i, k - 1)]
        if right:
            left = (i > 0) & (prev > t)
            rgt = (i < k) & (cur <= t)
        else:
            left = (i > 0) & (prev >= t)
            rgt = (i < k) & (cur < t)
        if not (left.any() or rgt.any()):
            return i
        i = i - left + rgt
    return np.searchsorted(edges, t, side="right" if right else "left")


def _by_shot(k: int, m: int, shot: np.ndarray, pt: np.ndarray,
             w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stable counting sort of pairs by shot: (indptr int64, point, weight)."""
    total = shot.size
    if _coo_tocsr is not None and total < 2**31 - 1 and m < 2**31 - 1:
        bp = np.empty(k + 1, np.int32)
        bj = np.empty(total, np.int32)
        bx = np.empty(total, np.float64)
        try:
            _coo_tocsr(k, m, total, shot, pt, w, bp, bj, bx)
            return bp.astype(np.int64), bj, bx
        except (TypeError, ValueError):  # pragma: no cover - a changed private API
            pass
    perm = np.argsort(shot.astype(np.uint16) if k <= 65536 else shot, kind="stable")
    indptr = np.zeros(k + 1, np.int64)
    np.cumsum(np.bincount(shot, minlength=k), out=indptr[1:])
    return indptr, pt[perm], w[perm]


class CloudIndex:
    """A regular grid over an airborne cloud, built once, answering footprint queries.

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
        n = self.x.size
        # centre coordinates so the geometry works with small numbers
        self._ox, self._oy = (float(self.x.mean()), float(self.y.mean())) if n else (0.0, 0.0)
        if n == 0:
            self._cell, self._nx, self._ny, self._x0, self._y0 = 1.0, 1, 1, 0.0, 0.0
            self._ptr = np.zeros(2, np.int64)
            self._gx = self._gy = self._gz = np.empty(0)
            self._grow = self._grank = np.empty(0, np.int64)
            return
        lx, ly = self.x - self._ox, self.y - self._oy
        self._x0, self._y0 = float(lx.min()), float(ly.min())
        w, h = float(lx.max()) - self._x0, float(ly.max()) - self._y0
        cell = max(math.sqrt(POINTS_PER_CELL * max(w * h, 1e-6) / n), 1e-3)
        while True:
            nx, ny = int(w // cell) + 1, int(h // cell) + 1
            if nx * ny <= 4 * n + 1024:
                break
            cell *= 2.0
        self._cell, self._nx, self._ny = cell, nx, ny
        ix = np.minimum(((lx - self._x0) / cell).astype(np.int64), nx - 1)
        iy = np.minimum(((ly - self._y0) / cell).astype(np.int64), ny - 1)
        cid = iy * nx + ix
        order = np.argsort(cid, kind="stable")  # points of a cell in cloud order
        self._ptr = np.zeros(nx * ny + 1, np.int64)
        np.cumsum(np.bincount(cid, minlength=nx * ny), out=self._ptr[1:])
        self._gx, self._gy, self._gz = lx[order], ly[order], self.z[order]
        self._grow = order
        rank = np.empty(n, np.int64)
        rank[np.argsort(self.z, kind="stable")] = np.arange(n, dtype=np.int64)
        self._grank = rank[order]  # order by (height, cloud order)

    # ------------------------------------------------------------------ candidates
    def _cells_near(self, ax: float, ay: float, bx: float, by: float,
                    reach: float) -> np.ndarray:
        """Grid positions of the points in cells within ``reach`` of segment a-b."""
        c = self._cell
        i0 = max(int(math.floor((min(ax, bx) - reach - self._x0) / c)), 0)
        i1 = min(int(math.floor((max(ax, bx) + reach - self._x0) / c)), self._nx - 1)
        j0 = max(int(math.floor((min(ay, by) - reach - self._y0) / c)), 0)
        j1 = min(int(math.floor((max(ay, by) + reach - self._y0) / c)), self._ny - 1)
        if i1 < i0 or j1 < j0:
            return np.empty(0, np.int64)
        ii, jj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1))
        ii, jj = ii.ravel(), jj.ravel()
        ccx = self._x0 + (ii + 0.5) * c - ax
        ccy = self._y0 + (jj + 0.5) * c - ay
        dx, dy = bx - ax, by - ay
        ll = dx * dx + dy * dy
        t = np.clip((ccx * dx + ccy * dy) / ll, 0.0, 1.0) if ll > 0 else np.zeros(ii.size)
        d2 = (ccx - t * dx) ** 2 + (ccy - t * dy) ** 2
        lim = reach + c * math.sqrt(0.5) + 1e-9
        cid = (jj * self._nx + ii)[d2 <= lim * lim]
        return _ranges(self._ptr[cid], self._ptr[cid + 1] - self._ptr[cid])

    # ------------------------------------------------------------------ queries
    def pairs(self, sx: np.ndarray, sy: np.ndarray, radius: float) -> FootprintPairs:
        """Points within ``radius`` (metres) of each shot centre ``(sx, sy)``.

        Pairs are sorted by shot, then by height (ties in cloud order).  The shots
        should be a short run along the track (tens to a few hundred metres); runs on
        a straight line, in order along it, are answered fastest.
        """
        sx = np.asarray(sx, dtype=np.float64)
        sy = np.asarray(sy, dtype=np.float64)
        k = sx.size
        if k == 0 or self.x.size == 0:
            return _empty_pairs(k)
        lx, ly = sx - self._ox, sy - self._oy
        dx, dy = lx[-1] - lx[0], ly[-1] - ly[0]
        norm = float(math.hypot(dx, dy))
        ux, uy = (dx / norm, dy / norm) if norm > 0 else (1.0, 0.0)
        u_shot = (lx - lx[0]) * ux + (ly - ly[0]) * uy
        v_shot = -(lx - lx[0]) * uy + (ly - ly[0]) * ux
        if float(np.max(np.abs(v_shot))) <= _LINE_TOL and bool(np.all(np.diff(u_shot) >= 0)):
            return self._pairs_line(lx, ly, u_shot, ux, uy, radius)
        return self._pairs_general(lx, ly, radius)

    def _pairs_line(self, lx: np.ndarray, ly: np.ndarray, u_shot: np.ndarray, ux: float,
                    uy: float, radius: float) -> FootprintPairs:
        k = lx.size
        ax, ay = float(lx[0]), float(ly[0])
        pos = self._cells_near(ax, ay, float(lx[-1]), float(ly[-1]), radius)
        px, py = self._gx[pos] - ax, self._gy[pos] - ay
        u = px * ux + py * uy
        v = py * ux - px * uy
        c2 = radius * radius - v * v
        keep = (c2 >= 0) & (u >= u_shot[0] - radius) & (u <= u_shot[-1] + radius)
        pos, u, c2 = pos[keep], u[keep], c2[keep]
        m = pos.size
        if m == 0:
            return _empty_pairs(k)
        # candidates by (height, cloud order): one sort of packed integer keys
        bits = int(m).bit_length()
        order = np.sort((self._grank[pos] << bits) | np.arange(m, dtype=np.int64))
        order &= (1 << bits) - 1
        pos, u, c2 = pos[order], u[order], c2[order]
        c = np.sqrt(c2)
        # shot k holds the point when |u_k - u| <= sqrt(R^2 - v^2)
        lo = _sorted_index(u_shot, u - c, right=False)
        cnt = _sorted_index(u_shot, u + c, right=True) - lo
        total = int(cnt.sum())
        if total == 0:
            return _empty_pairs(k)
        # pairs point by point (heights ascending), each point's run of shots
        pt = np.repeat(np.arange(m, dtype=np.int32), cnt)
        shot = np.arange(total, dtype=np.int32)
        shot -= np.repeat((np.cumsum(cnt) - cnt - lo).astype(np.int32), cnt)
        du = u_shot[shot] - np.repeat(u, cnt)
        du *= du
        du += np.repeat(radius * radius - c2, cnt)  # r^2 = du^2 + v^2
        w = footprint_weights(du, radius)
        # to shot order, keeping the height order within each shot (a counting sort)
        indptr, pt, w = _by_shot(k, m, shot, pt, w)
        shot = np.repeat(np.arange(k, dtype=np.int64), np.diff(indptr))
        return FootprintPairs(k, shot, self._grow[pos][pt], self._gz[pos][pt], w, indptr, True)

    def _pairs_general(self, lx: np.ndarray, ly: np.ndarray, radius: float) -> FootprintPairs:
        k = lx.size
        pos = self._cells_near(float(lx.min()), float(ly.min()), float(lx.max()),
                               float(ly.max()), radius + 0.5 * math.hypot(
                                   float(lx.max() - lx.min()), float(ly.max() - ly.min())))
        if pos.size == 0:
            return _empty_pairs(k)
        # slabs along x: candidates sorted by x, the points within R of a shot lie in
        # the x-slab around it; the exact distance test keeps r <= R
        px, py = self._gx[pos], self._gy[pos]
        order = np.argsort(px, kind="stable")
        pos, px, py = pos[order], px[order], py[order]
        lo = np.searchsorted(px, lx - radius, side="left")
        cnt = np.searchsorted(px, lx + radius, side="right") - lo
        total = int(cnt.sum())
        if total == 0:
            return _empty_pairs(k)
        shot = np.repeat(np.arange(k, dtype=np.int64), cnt)
        j = _ranges(lo, cnt)
        ddx = px[j] - lx[shot]
        ddy = py[j] - ly[shot]
        r2 = ddx * ddx + ddy * ddy
        inside = r2 <= radius * radius
        shot, j, r2 = shot[inside], j[inside], r2[inside]
        order = np.lexsort((self._grank[pos][j], shot))
        shot, j, r2 = shot[order], j[order], r2[order]
        indptr = np.zeros(k + 1, np.int64)
        np.cumsum(np.bincount(shot, minlength=k), out=indptr[1:])
        g = pos[j]
        return FootprintPairs(k, shot, self._grow[g], self._gz[g], footprint_weights(r2, radius),
                              indptr, True)
