"""Columns sorted by a nearly sorted key, one window at a time.

ATL03 photons are stored in time order; their along-track distance ``s`` is out of order
only locally (photons of neighbouring shots and heights swap by a metre or so).  A global
stable sort then costs a full-length permutation and one full-length copy of every column.
Here the key is cut where everything before the cut is <= everything after it (such cuts
come every few photons in real tracks); the windows between cuts, about ``window`` photons
each, are sorted on their own and every column is permuted in place, window by window, so
scratch memory is a few windows whatever the track's length.  The result is exactly that
of ``np.argsort(key, kind="stable")`` applied to every column: a cut never separates two
photons the stable sort would exchange, and ties keep their order on both sides of it.
A key with no such cut (or with NaN, which orders last) is one window: the global sort.
"""

from __future__ import annotations

from collections.abc import MutableMapping

import numpy as np

from ..photons import stable_order

__all__ = ["order_windows", "sort_columns_in_windows", "DEFAULT_SORT_WINDOW"]

#: Photons per window (about): 512 KiB of float64, sorted in the processor's cache.
DEFAULT_SORT_WINDOW = 1 << 16


def order_windows(key: np.ndarray, window: int = DEFAULT_SORT_WINDOW) -> np.ndarray:
    """Cut positions ``[0, c1, ..., n]`` of ``key`` (1-D): each ``c`` is the first index at or
    after a multiple of ``window`` with ``max(key[:c]) <= min(key[c:])`` (no cut where there
    is none).  Scratch memory: a few arrays of ``window`` values."""
    key = np.asarray(key)
    n = int(key.size)
    if n <= window:
        return np.array([0, n], dtype=np.int64)
    starts = np.arange(0, n, window, dtype=np.int64)
    cmax = np.maximum.reduceat(key, starts)
    cmin = np.minimum.reduceat(key, starts)
    # max of everything before chunk j; min of everything from chunk j on
    before = np.r_[-np.inf, np.maximum.accumulate(cmax)[:-1]]
    from_j = np.r_[np.minimum.accumulate(cmin[::-1])[::-1], np.inf]
    cuts = [0]
    for j in range(1, starts.size):
        a = int(starts[j])
        end = min(n, a + window)
        # look in the first _PROBE values of the chunk (real tracks have a cut every few
        # dozen photons), then in the rest of it
        for lo, hi in ((a, min(end, a + _PROBE)), (min(end, a + _PROBE), end)):
            if lo >= hi:
                continue
            c = _first_cut(key, lo, hi, end, before[j], from_j[j + 1], a)
            if c is not None:
                cuts.append(c)
                break
    cuts.append(n)
    return np.asarray(cuts, dtype=np.int64)


#: Values examined first after each multiple of the window.
_PROBE = 256


def _first_cut(key: np.ndarray, lo: int, hi: int, end: int, before: float, after: float,
               a: int) -> int | None:
    """First ``c`` in ``lo..hi-1`` with ``max(key[:c]) <= min(key[c:])``, knowing
    ``before = max(key[:a])`` and ``after = min(key[end:])`` (``a <= lo``, ``hi <= end``)."""
    head = key[a:hi]
    pre = np.maximum.accumulate(head)
    left = np.maximum(np.r_[-np.inf, pre[:-1]], before)[lo - a:]      # max(key[:c])
    tail_min = min(after, float(key[hi:end].min())) if hi < end else after
    seg = key[lo:hi]
    right = np.minimum(np.minimum.accumulate(seg[::-1])[::-1], tail_min)  # min(key[c:])
    ok = np.flatnonzero(left <= right)
    return lo + int(ok[0]) if ok.size else None


def sort_columns_in_windows(columns: MutableMapping[str, np.ndarray], key: str,
                            window: int = DEFAULT_SORT_WINDOW) -> bool:
    """Sort every array of ``columns`` (equal lengths) by ``columns[key]``, stably, in
    place, window by window (see the module).  Returns False when already in order
    (nothing touched)."""
    s = columns[key]
    if s.size < 2 or bool(np.all(s[1:] >= s[:-1])):
        return False
    cuts = order_windows(s, window)
    for a, b in zip(cuts[:-1].tolist(), cuts[1:].tolist()):
        w = s[a:b]
        if b - a < 2 or bool(np.all(w[1:] >= w[:-1])):
            continue
        local = stable_order(w)
        for name, col in columns.items():
            if name != key:
                col[a:b] = col[a:b][local]
        s[a:b] = w[local]
    return True
