"""Statistics of values grouped by an integer key, vectorised (no loop over groups).

Used by the block estimators and the ATL08-style classifier and segments: percentiles
(numpy's linear method), and "the sorted values of each group" as one array with
group starts and counts.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sorted_groups", "percentile_by_group", "percentiles_by_group"]


def sorted_groups(group: np.ndarray, values: np.ndarray, n_groups: int, *,
                  values_sorted: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The values sorted by (group, value); ``values_sorted``: they are in ascending order
    already (the sort by group alone remains).

    Returns
    -------
    order : ndarray of int64
        Permutation of the inputs (equal values of a group in no set order: they are
        interchangeable).
    sorted_values : ndarray
    starts, counts : ndarray of int64, one per group 0..n_groups-1
    """
    order = _group_value_order(np.asarray(group), np.asarray(values), n_groups,
                               values_sorted)
    counts = np.bincount(group, minlength=n_groups)[:n_groups]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return order, values[order], starts, counts


def _group_value_order(group: np.ndarray, values: np.ndarray, n_groups: int,
                       values_sorted: bool = False) -> np.ndarray:
    """A permutation sorting by (group, value): the values sorted (numpy's unstable
    default sort), then stable radix passes over 16-bit digits of the group (least
    significant first) -- the same sorted values as ``np.lexsort((values, group))`` at a
    quarter of its cost (two merge sorts there)."""
    if group.size < 2 or n_groups > 2**48 or group.dtype.kind not in "iu":
        return np.lexsort((values, group))
    if values_sorted:
        order, g = np.arange(values.size), group
    else:
        order = np.argsort(values)
        g = group[order]
    shift = 0
    while True:
        digit = ((g >> shift) & 0xFFFF).astype(np.uint16)
        p = np.argsort(digit, kind="stable")  # radix sort for 16-bit integers
        order = order[p]
        shift += 16
        if (n_groups - 1) >> shift == 0:
            return order
        g = g[p]


def _pick(zs: np.ndarray, starts: np.ndarray, counts: np.ndarray, q: float) -> np.ndarray:
    out = np.full(counts.size, np.nan)
    has = counts > 0
    pos = q / 100.0 * (counts[has] - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, counts[has] - 1)
    frac = pos - lo
    a = zs[starts[has] + lo]
    b = zs[starts[has] + hi]
    out[has] = a + (b - a) * frac
    return out


def percentile_by_group(group: np.ndarray, values: np.ndarray, q: float,
                        n_groups: int) -> np.ndarray:
    """Per group, the ``q``-th percentile (0-100) of ``values`` (numpy's linear method).

    ``group`` holds integer indices 0..n_groups-1; groups without values give NaN.
    Groups in runs (``group`` non-decreasing, as windows along a sorted track) are sorted
    each on its own by a compiled loop where numba is installed (the same values).
    """
    from .kernels import compiled, enabled

    group = np.asarray(group)
    values = np.asarray(values)
    mod = (compiled() if enabled() and group.dtype.kind in "iu" and group.size
           and values.dtype == np.float64 else None)
    if mod is not None and bool(np.all(group[1:] >= group[:-1])):
        out = np.full((n_groups, 1), np.nan)
        mod.run_percentiles(group.astype(np.int64, copy=False), values,
                            np.array([float(q)]), out)
        return out[:, 0]
    _, zs, starts, counts = sorted_groups(group, values, n_groups)
    return _pick(zs, starts, counts, q)


def percentiles_by_group(group: np.ndarray, values: np.ndarray, qs: list[float] | tuple[float, ...],
                         n_groups: int, *, values_sorted: bool = False) -> np.ndarray:
    """Several percentiles per group from one sort: array of shape (n_groups, len(qs));
    ``values_sorted``: the values are in ascending order already. Groups in runs (as
    :func:`percentile_by_group`) are sorted each on its own by a compiled loop where numba
    is installed (the same values)."""
    from .kernels import compiled, enabled

    if not len(qs):
        return np.empty((n_groups, 0))
    group = np.asarray(group)
    values = np.asarray(values)
    mod = (compiled() if enabled() and group.dtype.kind in "iu" and group.size
           and values.dtype == np.float64 else None)
    if mod is not None and bool(np.all(group[1:] >= group[:-1])):
        out = np.full((n_groups, len(qs)), np.nan)
        mod.run_percentiles(group.astype(np.int64, copy=False), values,
                            np.asarray(qs, np.float64), out)
        return out
    _, zs, starts, counts = sorted_groups(group, values, n_groups,
                                          values_sorted=values_sorted)
    return np.column_stack([_pick(zs, starts, counts, float(q)) for q in qs])
