"""Validation statistics per block length, metric and group (DESIGN 2.4, 2.5).

For each metric the photon value ``y`` and reference ``x`` of the blocks with
``use`` (block ``ok`` and reference ``ok``) and both values finite:

* ``n``; ``bias = mean(y - x)``; ``rmse = sqrt(mean((y - x)**2))``; ``mae = mean|y - x|``;
* ``slope``, ``intercept``: ordinary least squares of ``y`` on ``x``;
* ``r2``: the squared Pearson correlation (the OLS r^2).
``slope``/``intercept``/``r2`` are NaN for ``n < 3`` or a constant ``x``; every value is
NaN for ``n == 0``.

Groups: ``all``; ``aspect:<class>`` for each aspect class present; ``slope:<class>``
for each slope class present.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import pandas as pd

from ..errors import InputError
from ..schema import METRICS, STATS_COLUMNS
from .residuals import RESIDUAL_PAIRS

__all__ = ["block_stats", "error_stats", "GROUP_ALL"]

log = logging.getLogger(__name__)

GROUP_ALL = "all"
_CLASS_ORDER = ("N", "NE", "E", "SE", "S", "SW", "W", "NW", "flat",
                "0-5", "5-10", "10-20", "20-30", ">30", "unknown")


def error_stats(photon: np.ndarray, reference: np.ndarray, *,
                allow_empty: bool = False) -> dict[str, float]:
    """n, bias, rmse, mae, slope, intercept, r2 of ``photon`` against ``reference``.

    Pairs with a non-finite value are ignored (NaN-safe).  Empty arrays raise
    :class:`~canopyblocks.errors.InputError` unless ``allow_empty`` (then n = 0 and NaN
    statistics: a group of a table that happens to be empty).
    """
    from ..arguments import check_array
    photon = check_array(photon, "error_stats: photon")
    reference = check_array(reference, "error_stats: reference")
    y = np.asarray(photon, dtype=float)
    x = np.asarray(reference, dtype=float)
    if y.shape != x.shape:
        raise InputError(f"error_stats needs two arrays of one length; got {y.shape} and "
                         f"{x.shape}")
    if y.size == 0 and not allow_empty:
        raise InputError("error_stats got empty arrays: no pair of photon and reference "
                         "values to compare")
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    n = int(x.size)
    out = {"n": n, "bias": np.nan, "rmse": np.nan, "mae": np.nan,
           "slope": np.nan, "intercept": np.nan, "r2": np.nan}
    if n == 0:
        return out
    r = y - x
    out["bias"] = float(np.mean(r))
    out["rmse"] = float(np.sqrt(np.mean(r * r)))
    out["mae"] = float(np.mean(np.abs(r)))
    if n >= 3:
        dx = x - x.mean()
        dy = y - y.mean()
        sxx = float(np.dot(dx, dx))
        syy = float(np.dot(dy, dy))
        if sxx > 0:
            sxy = float(np.dot(dx, dy))
            out["slope"] = sxy / sxx
            out["intercept"] = float(y.mean() - out["slope"] * x.mean())
            out["r2"] = sxy * sxy / (sxx * syy) if syy > 0 else np.nan
    return out


def _sorted_classes(values: Sequence[str]) -> list[str]:
    rank = {c: i for i, c in enumerate(_CLASS_ORDER)}
    return sorted(set(values), key=lambda c: (rank.get(c, len(rank)), c))


def _used_rows(residuals: pd.DataFrame, metrics: Sequence[str], known: Sequence[str],
               only_used: bool) -> pd.DataFrame:
    """The residuals' rows to count (``use`` True when ``only_used``), once every metric is
    one of ``known`` (else the one-line error naming them)."""
    for m in metrics:
        if m not in known:
            raise InputError(f"unknown metric {m!r}; use {', '.join(known)}")
    if only_used and "use" in residuals.columns:
        return residuals[residuals["use"].to_numpy(bool)]
    return residuals


def block_stats(residuals: pd.DataFrame, *, metrics: Sequence[str] = METRICS,
                groups: Sequence[tuple[str, str]] = (("aspect", "aspect_class"),
                                                     ("slope", "slope_class")),
                only_used: bool = True) -> pd.DataFrame:
    """Statistics per block length, metric and group.

    Parameters
    ----------
    residuals : DataFrame
        From :func:`~canopyblocks.validation.residuals.compute_residuals`.
    metrics : sequence of str
        Photon metric names (``ground``, ``top``, ``hmax``, ``h90``).
    groups : sequence of (prefix, column)
        Grouping columns; rows are labelled ``<prefix>:<class>``.  Missing columns
        are skipped.
    only_used : bool
        Use only rows with ``use`` True (block ok and reference ok).

    Returns
    -------
    DataFrame
        Columns ``schema.STATS_COLUMNS``.
    """
    from ..arguments import check_frame
    check_frame(residuals, "block_stats: residuals", "a residuals table (DataFrame)")
    df = _used_rows(residuals, metrics, tuple(RESIDUAL_PAIRS), only_used)
    rows = []
    for length in sorted(pd.unique(residuals["length"])):
        dl = df[df["length"].to_numpy() == length]
        subsets: list[tuple[str, pd.DataFrame]] = [(GROUP_ALL, dl)]
        for prefix, col in groups:
            if col not in dl.columns:
                continue
            for cls in _sorted_classes(dl[col].astype(str).tolist()):
                subsets.append((f"{prefix}:{cls}", dl[dl[col].astype(str) == cls]))
        for m in metrics:
            ref = RESIDUAL_PAIRS[m]
            for name, sub in subsets:
                st = error_stats(sub[m].to_numpy(float), sub[ref].to_numpy(float),
                                 allow_empty=True)
                rows.append({"length": float(length), "metric": m, "group": name, **st})
    out = pd.DataFrame(rows, columns=list(STATS_COLUMNS))
    out["n"] = out["n"].astype(np.int64)
    return out
