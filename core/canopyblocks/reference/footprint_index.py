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
from typing import Literal

import numpy as np

try:  # scipy's C++ counting sort of COO entries into CSR (stable; optional speed-up)
    from scipy.sparse._sparsetools import coo_tocsr as _coo_tocsr
except ImportError:  # pragma: no cover - private scipy API moved
    _coo_tocsr = None

__all__ = ["FootprintPairs", "CloudIndex", "footprint_weights", "footprints_area",
           "occupancy_cell"]

log = logging.getLogger(__name__)

#: Mean number of points per grid cell of :class:`CloudIndex`.
POINTS_PER_CELL = 24.0

#: Shots farther than this from the line through a run's first and last shot (metres)
#: make the run "bent": it is answered by the general (slower) method.
_LINE_TOL = 1e-7


def footprints_area(x: np.ndarray, y: np.ndarray, radius: float) -> object:
    """The union of discs of ``radius`` metres around the positions ``(x, y)``.

    The area whose points a footprint reference needs (a track's footprints make a
    corridor; scattered ones, scattered discs), for reading the tiles by it rather than
    by the positions' bounding box.  Each disc's polygon circumscribes the circle (its
    sides lie outside it), so no point within ``radius`` is left out.  None when no
    position is finite.
    """
    import shapely

    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        return None
    quad = 8
    r = float(radius) / math.cos(math.pi / (4 * quad))
    return shapely.MultiPoint(np.c_[x[ok], y[ok]]).buffer(r, quad_segs=quad)


_DENSITY_CELL = 5.0
"""Cell (m, at multiples of it in the points' CRS) on which the occupied area is counted."""


def occupancy_cell(x: np.ndarray, y: np.ndarray) -> float:
    """The coverage lattice's cell (m): about 16 points a cell at the points' density
    over the area they occupy (points / occupied 5 m cells' area), at least 2 m, rounded
    up to a step of ``2 * sqrt(2) ** k`` so that a neighbouring tile of the same survey
    read or left out does not move it."""
    ix = np.floor(np.asarray(x, float) / _DENSITY_CELL).astype(np.int64)
    iy = np.floor(np.asarray(y, float) / _DENSITY_CELL).astype(np.int64)
    cells = np.unique((ix - ix.min()) * (int(iy.max() - iy.min()) + 1) + (iy - iy.min()))
    density = x.size / (cells.size * _DENSITY_CELL ** 2)
    raw = max(2.0, math.sqrt(16.0 / density))
    k = math.ceil(round(2.0 * math.log2(raw / 2.0), 9))
    return 2.0 * math.sqrt(2.0) ** k


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


class FootprintPairs:
    """The (shot, point) pairs of a run of shots, sorted by shot.

    Attributes
    ----------
    n_shots : int
        Shots in the run (local ids 0..n_shots-1).
    shot : ndarray int64
        Local shot id of each pair (non-decreasing; may be passed as None: derived
        from ``indptr`` on first use).
    point : ndarray int64
        Index of the airborne point in the cloud (it may be passed as a pair
        ``(rows, local)`` meaning ``rows[local]``, resolved on first use).
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

    def __init__(self, n_shots: int, shot: np.ndarray | None,
                 point: np.ndarray | tuple[np.ndarray, np.ndarray], z: np.ndarray,
                 weight: np.ndarray, indptr: np.ndarray, height_sorted: bool = False) -> None:
        self.n_shots = int(n_shots)
        self._shot = shot
        self.z, self.weight, self.indptr = z, weight, indptr
        self.height_sorted = bool(height_sorted)
        self._point = point
        self._cw: np.ndarray | None = None
        self._blocks: _Prefix | None = None

    def __repr__(self) -> str:
        return f"FootprintPairs(n_shots={self.n_shots}, n_pairs={self.z.size})"

    @property
    def shot(self) -> np.ndarray:
        """Local shot id of each pair."""
        if self._shot is None:
            self._shot = np.repeat(np.arange(self.n_shots, dtype=np.int64), self.counts)
        return self._shot

    @property
    def point(self) -> np.ndarray:
        """Index of each pair's point in the cloud."""
        if isinstance(self._point, tuple):
            rows, local = self._point
            self._point = rows[local]
        assert not isinstance(self._point, tuple)
        return self._point

    def point_of(self, pair: np.ndarray) -> np.ndarray:
        """``point[pair]``, without resolving all of ``point``."""
        if isinstance(self._point, tuple):
            rows, local = self._point
            return rows[local[pair]]
        return self._point[pair]

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

    def prefix(self, n_queries: int) -> _Prefix:
        """Prefix sums of ``weight`` for about ``n_queries`` look-ups (see :class:`_Prefix`)."""
        if self._cw is None and n_queries * _Prefix.BLOCK * 4 < self.weight.size:
            if self._blocks is None:
                self._blocks = _Prefix(self.weight)
            return self._blocks
        return _Prefix(self.weight, self.cumulative_weight)

    def sorted_by_height(self) -> FootprintPairs:
        """These pairs with each shot's pairs sorted by (height, point)."""
        if self.height_sorted:
            return self
        order = np.lexsort((self.point, self.z, self.shot))
        return FootprintPairs(self.n_shots, self.shot[order], self.point[order],
                              self.z[order], self.weight[order], self.indptr, True)


class _Prefix:
    """Inclusive prefix sums ``P(i) = sum(w[:i + 1])`` (``P(-1) = 0``) and searches in them.

    With ``cw`` (a full ``cumsum``) they are read from it; otherwise from block sums
    (``BLOCK`` pairs each) and a short running sum inside one block per look-up, which is
    cheaper when there are few look-ups.  ``P`` is non-decreasing either way.
    """

    BLOCK = 16

    def __init__(self, w: np.ndarray, cw: np.ndarray | None = None) -> None:
        self.w, self.cw = w, cw
        if cw is None:
            n = w.size
            bs = np.add.reduceat(w, np.arange(0, n, self.BLOCK)) if n else np.empty(0)
            self.off = np.zeros(bs.size + 1)
            np.cumsum(bs, out=self.off[1:])

    def _window(self, b: np.ndarray) -> np.ndarray:
        """Rows ``P(b L + j)``, ``j < L``, for blocks ``b`` (0 beyond the end)."""
        L = self.BLOCK
        idx = b[:, None] * L + np.arange(L)
        out = self.w[np.minimum(idx, self.w.size - 1)]
        out[idx >= self.w.size] = 0.0
        np.cumsum(out, axis=1, out=out)
        out += self.off[b][:, None]
        return out

    def at(self, i: np.ndarray) -> np.ndarray:
        """``P(i)`` for indices ``i >= -1``."""
        i = np.asarray(i, dtype=np.int64)
        if self.cw is not None:
            return np.where(i >= 0, self.cw[np.maximum(i, 0)], 0.0)
        ok = i >= 0
        b = np.maximum(i, 0) // self.BLOCK
        vals = self._window(b)[np.arange(i.size), np.maximum(i, 0) - b * self.BLOCK]
        return np.where(ok, vals, 0.0)

    def search(self, t: np.ndarray, right: bool) -> np.ndarray:
        """First ``i`` with ``P(i) > t`` (``right``) or ``P(i) >= t``; ``len(w)`` if none."""
        t = np.asarray(t, dtype=np.float64)
        side: Literal["left", "right"] = "right" if right else "left"
        if self.cw is not None:
            return np.searchsorted(self.cw, t, side=side)
        n = self.w.size
        if n == 0:
            return np.zeros(t.shape, np.int64)
        flat = t.ravel()
        b = np.minimum(np.searchsorted(self.off[1:], flat, side=side), self.off.size - 2)
        win = self._window(b)
        hit = win > flat[:, None] if right else win >= flat[:, None]
        found = hit.any(axis=1)
        i = np.where(found, b * self.BLOCK + np.argmax(hit, axis=1), (b + 1) * self.BLOCK)
        return np.minimum(i, n).reshape(t.shape)


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


def _argsort_ranks(rank: np.ndarray) -> np.ndarray:
    """Stable ``argsort`` of non-negative integers (an LSD radix sort below 2**32)."""
    if rank.size and int(rank.max()) < 2**32:
        p1 = np.argsort((rank & 0xFFFF).astype(np.uint16), kind="stable")
        p2 = np.argsort((rank[p1] >> 16).astype(np.uint16), kind="stable")
        return p1[p2]
    return np.argsort(rank, kind="stable")


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
    if _coo_tocsr is not None:
        bp = np.empty(k + 1, shot.dtype)
        bj = np.empty(total, pt.dtype)
        bx = np.empty(total, np.float64)
        try:
            _coo_tocsr(k, m, total, shot, pt, w, bp, bj, bx)
            return bp.astype(np.int64, copy=False), bj, bx
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
        order = _argsort_ranks(cid)  # stable: points of a cell in cloud order
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
    def pairs(self, sx: np.ndarray, sy: np.ndarray, radius: float,
              line: tuple[float, float, float, float] | None = None) -> FootprintPairs:
        """Points within ``radius`` (metres) of each shot centre ``(sx, sy)``.

        Pairs are sorted by shot, then by height (ties in cloud order).  The shots
        should be a short run along the track (tens to a few hundred metres); runs on
        a straight line, in order along it, are answered fastest.

        Parameters
        ----------
        sx, sy : ndarray
            Shot centres, metres, in the cloud's CRS.
        radius : float
            Footprint radius, metres.
        line : (x0, y0, x1, y1), optional
            The track segment the shots lie on (cloud CRS, metres).  Distances are then
            measured in the segment's own frame, so a shot's pairs and weights do not
            depend on which other shots are queried with it.
        """
        sx = np.asarray(sx, dtype=np.float64)
        sy = np.asarray(sy, dtype=np.float64)
        k = sx.size
        if k == 0 or self.x.size == 0:
            return _empty_pairs(k)
        lx, ly = sx - self._ox, sy - self._oy
        if line is not None:
            ax, ay = line[0] - self._ox, line[1] - self._oy
            dx, dy = line[2] - line[0], line[3] - line[1]
        else:
            ax, ay = float(lx[0]), float(ly[0])
            dx, dy = lx[-1] - lx[0], ly[-1] - ly[0]
        norm = float(math.hypot(dx, dy))
        ux, uy = (dx / norm, dy / norm) if norm > 0 else (1.0, 0.0)
        u_shot = (lx - ax) * ux + (ly - ay) * uy
        v_shot = -(lx - ax) * uy + (ly - ay) * ux
        if float(np.max(np.abs(v_shot))) <= _LINE_TOL and bool(np.all(np.diff(u_shot) >= 0)):
            return self._pairs_line(lx, ly, (ax, ay), u_shot, ux, uy, radius)
        if line is not None:
            return self.pairs(sx, sy, radius)
        return self._pairs_general(lx, ly, radius)

    def _pairs_line(self, lx: np.ndarray, ly: np.ndarray, origin: tuple[float, float],
                    u_shot: np.ndarray, ux: float, uy: float, radius: float) -> FootprintPairs:
        k = lx.size
        pos = self._cells_near(float(lx[0]), float(ly[0]), float(lx[-1]), float(ly[-1]), radius)
        px, py = self._gx[pos] - origin[0], self._gy[pos] - origin[1]
        u = px * ux + py * uy
        v = py * ux - px * uy
        c2 = radius * radius - v * v
        keep = (c2 >= 0) & (u >= u_shot[0] - radius) & (u <= u_shot[-1] + radius)
        pos, u, c2 = pos[keep], u[keep], c2[keep]
        m = pos.size
        if m == 0:
            return _empty_pairs(k)
        order = _argsort_ranks(self._grank[pos])  # by (height, cloud order)
        pos, u, c2 = pos[order], u[order], c2[order]
        c = np.sqrt(c2)
        # shot k holds the point when |u_k - u| <= sqrt(R^2 - v^2)
        lo = _sorted_index(u_shot, u - c, right=False)
        cnt = _sorted_index(u_shot, u + c, right=True) - lo
        total = int(cnt.sum())
        if total == 0:
            return _empty_pairs(k)
        # pairs point by point (heights ascending), each point's run of shots
        pt = np.repeat(np.arange(m, dtype=np.int64), cnt)
        shot = np.arange(total, dtype=np.int64)
        shot -= np.repeat(np.cumsum(cnt) - cnt - lo, cnt)
        # weight exp(-2 (du^2 + v^2) / R^2) with du, v scaled by sqrt(2) / R
        scale = math.sqrt(2.0) / radius
        e = np.take(u_shot * scale, shot, mode="clip")  # indices are valid: no checks
        e -= np.repeat(u * scale, cnt)
        e *= e
        np.subtract(np.repeat((c2 - radius * radius) * (scale * scale), cnt), e, out=e)
        w = np.exp(e, out=e)
        # to shot order, keeping the height order within each shot (a counting sort)
        indptr, pt, w = _by_shot(k, m, shot, pt, w)
        z = np.take(self._gz[pos], pt, mode="clip")
        return FootprintPairs(k, None, (self._grow[pos], pt), z, w, indptr, True)

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
