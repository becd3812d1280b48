"""The numba loops behind :mod:`.kernels` (imported only through it: needs numba).

Each loop does, in one pass, what its numpy twin does in several, with the same floating
point operations in the same order, so the results are the same bits (integers where
counting; IEEE operations without fused multiply-adds or reassociation: no fastmath).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["box_counts", "surface_pass", "run_percentiles", "feature_sums"]


@njit(cache=True, nogil=True)
def _interp_at(x: float, j: int, nodes: np.ndarray, surf: np.ndarray) -> float:
    """``np.interp(x, nodes, surf)`` for ``nodes[j] <= x < nodes[j + 1]`` (or j the last
    node), with numpy's formula and its special cases."""
    m = nodes.size
    if j < 0:
        return surf[0]
    if j >= m - 1:
        return surf[m - 1]
    if nodes[j] == x:
        return surf[j]
    slope = (surf[j + 1] - surf[j]) / (nodes[j + 1] - nodes[j])
    v = slope * (x - nodes[j]) + surf[j]
    if np.isnan(v):
        v = slope * (x - nodes[j + 1]) + surf[j + 1]
        if np.isnan(v) and surf[j] == surf[j + 1]:
            v = surf[j]
    return v


@njit(cache=True, nogil=True)
def surface_pass(ss: np.ndarray, zz: np.ndarray, bins: np.ndarray, nodes: np.ndarray,
                 surf: np.ndarray, cur: np.ndarray, use_cur: bool, band: float,
                 above_weight: float, last: bool, near_within: float,
                 weighs: np.ndarray, sums: np.ndarray, near: np.ndarray) -> int:
    """One surface pass over the photons ``cur`` (all with ``use_cur`` False; s sorted):
    per photon whether its biweight is > 0 (``weighs``), the nodes' five binned sums
    (``sums``, 5 x nodes, zero on entry) and, with ``near_within`` >= 0, the positions
    of the photons within that of the surface (``near``; their number is returned)."""
    n = cur.size if use_cur else ss.size
    m = nodes.size
    j = -1
    k = 0
    for t in range(n):
        i = cur[t] if use_cur else t
        x = ss[i]
        if j < 0 or x < nodes[j]:
            j = np.searchsorted(nodes, x, side="right") - 1
        while j + 1 < m and nodes[j + 1] <= x:
            j += 1
        r = zz[i] - _interp_at(x, j, nodes, surf)
        if near_within >= 0.0 and abs(r) < near_within:
            near[k] = t
            k += 1
        u = r / band
        w = u * u
        w = 1.0 - w
        w = w * w
        if not abs(u) < 1.0:
            w = 0.0
        if not last and r > 0:
            w *= above_weight
        if w > 0:
            weighs[t] = True
            b = bins[i]
            ds = x - nodes[b]
            wds = w * ds
            wz = w * zz[i]
            sums[0, b] += w
            sums[1, b] += wds
            sums[2, b] += wz
            sums[3, b] += wds * ds
            sums[4, b] += wz * ds
    return k


@njit(cache=True, nogil=True)
def box_counts(ss: np.ndarray, zs: np.ndarray, starts: np.ndarray, ends: np.ndarray,
               lo: np.ndarray, hi: np.ndarray, ds: float, dz: float, sub: int,
               max_cells: int, out: np.ndarray) -> tuple[int, int, int]:
    """The density filter's box counts (see ``density_filter._box_counts``): per segment
    k, the photons ``lo[k]:hi[k]`` on a grid of cells ``ds`` x ``dz`` with origin at their
    lowest s and z; each of the photons ``starts[k]:ends[k]`` gets the number of photons
    in the (2 sub + 1)^2 cells around its own. A running histogram of rows over the
    columns within ``sub`` of the photon's (the columns rise with s): each photon enters
    and leaves it once. Returns (-1, 0, 0), or the first segment whose grid exceeds
    ``max_cells`` with its columns and rows (nothing counted then)."""
    nseg = starts.size
    for k in range(nseg):  # the grid sizes first, as the numpy code checks them
        s0 = ss[lo[k]]
        zmin = np.inf
        for i in range(lo[k], hi[k]):
            zmin = min(zmin, zs[i])
        cmax = 0
        rmax = 0
        for i in range(lo[k], hi[k]):
            c = int(np.int32(np.floor((ss[i] - s0) / ds)))
            r = int(np.int32(np.floor((zs[i] - zmin) / dz)))
            cmax = c if c > cmax else cmax
            rmax = r if r > rmax else rmax
        if (cmax + 1) * (rmax + 1) > max_cells:
            return k, cmax + 1, rmax + 1
    width = int((hi - lo).max()) if nseg else 0
    ci = np.empty(width, np.int64)
    ri = np.empty(width, np.int64)
    hist = np.zeros(1, np.int64)
    for k in range(nseg):
        a, b = lo[k], hi[k]
        s0 = ss[a]
        zmin = np.inf
        for i in range(a, b):
            zmin = min(zmin, zs[i])
        nr = 0
        for i in range(a, b):
            ci[i - a] = np.int32(np.floor((ss[i] - s0) / ds))
            ri[i - a] = np.int32(np.floor((zs[i] - zmin) / dz))
            nr = max(nr, ri[i - a] + 1)
        if hist.size < nr:
            hist = np.zeros(nr, np.int64)
        else:
            hist[:nr] = 0
        add = 0  # next entry to enter the histogram
        rem = 0  # next entry to leave it
        n = b - a
        for i in range(starts[k], ends[k]):
            e = i - a
            c = ci[e]
            while add < n and ci[add] <= c + sub:
                hist[ri[add]] += 1
                add += 1
            while rem < n and ci[rem] < c - sub:
                hist[ri[rem]] -= 1
                rem += 1
            r = ri[e]
            cnt = 0
            for q in range(max(r - sub, 0), min(r + sub + 1, nr)):
                cnt += hist[q]
            out[i] = cnt
    return -1, 0, 0


@njit(cache=True, nogil=True)
def feature_sums(s: np.ndarray, a: np.ndarray, b: np.ndarray, cls: np.ndarray,
                 height: np.ndarray, bgr: np.ndarray, geo: np.ndarray, has_geo: bool,
                 top: np.ndarray, step: float, by_class: np.ndarray, bg: np.ndarray,
                 g1: np.ndarray, g2: np.ndarray, above: np.ndarray, near: np.ndarray,
                 geo_sum: np.ndarray, geo_n: np.ndarray, grad: np.ndarray,
                 grad_n: np.ndarray) -> None:
    """``uncertainty_features._sums_numpy`` for photons in along-track order (``s``
    non-decreasing; intervals ``[a, b)`` sorted; classes 0 noise .. 3 top, -1 none): one
    walk over the photons, each sum added to in the photons' order as numpy's
    ``np.bincount`` does (outputs zero on entry)."""
    n = a.size
    j = -1
    cr, ck, ch = -1, 0, 0.0   # the (block, step) being read and its highest photon
    pr, pk, ph = -1, 0, 0.0   # the one before
    for i in range(s.size):
        x = s[i]
        while j + 1 < n and a[j + 1] <= x:
            j += 1
        c = cls[i]
        if c < 0 or j < 0 or not np.isfinite(x) or not x < b[j]:
            continue
        by_class[j, c] += 1
        bg[j] += bgr[i]
        hv = height[i]
        if c == 1:
            g1[j] += hv
            g2[j] += hv * hv
        elif c == 0:
            if hv > top[j] and hv <= top[j] + 10.0:
                above[j] += 1
            if abs(hv) <= 3.0:
                near[j] += 1
        if has_geo:
            g = geo[i]
            if np.isfinite(g) and g > 0:
                geo_sum[j] += g
                geo_n[j] += 1
        if c >= 1:
            h = 0.0 if c == 1 else hv
            if not np.isfinite(h):
                continue
            k = int(np.int64(np.floor((x - a[j]) / step)))
            if j == cr and k == ck:
                ch = max(ch, h)
                continue
            if cr >= 0:  # the step before is complete
                if pr == cr and ck == pk + 1:
                    d = (ch - ph) / step
                    grad[cr] += d * d
                    grad_n[cr] += 1
                pr, pk, ph = cr, ck, ch
            cr, ck, ch = j, k, h
    if cr >= 0 and pr == cr and ck == pk + 1:
        d = (ch - ph) / step
        grad[cr] += d * d
        grad_n[cr] += 1


@njit(cache=True, nogil=True)
def run_percentiles(group: np.ndarray, values: np.ndarray, qs: np.ndarray,
                    out: np.ndarray) -> None:
    """``grouped.percentiles_by_group`` for groups in runs (``group`` non-decreasing): each
    run's values sorted on their own, every percentile of ``qs`` picked with numpy's linear
    formula (``out``: groups x qs, NaN on entry; the groups without values stay NaN)."""
    n = group.size
    i = 0
    while i < n:
        g = group[i]
        j = i + 1
        while j < n and group[j] == g:
            j += 1
        v = np.sort(values[i:j])
        c = j - i
        for m in range(qs.size):
            pos = qs[m] / 100.0 * (c - 1)
            lo = int(np.floor(pos))
            hi = min(lo + 1, c - 1)
            frac = pos - lo
            a = v[lo]
            out[g, m] = a + (v[hi] - a) * frac
        i = j
