"""Footprint-matched reference per photon block (DESIGN 2.7): the block's estimate's
statistic, of the airborne returns its footprints see.

Footprints every ``spacing`` metres along each ``(track, length)``'s track line (the
polyline of :func:`~canopyblocks.reference.corridor.track_polyline`, footprints at
``s = (k + 0.5) * spacing``) belong to the block whose ``[s_start, s_end)`` holds them;
each is evaluated by :class:`~canopyblocks.reference.footprint.FootprintCloud` (weights,
ground plane, heights above it: the notes of :mod:`~canopyblocks.reference.footprint`).
Only footprints flagged ``ok`` enter a block's values.

Statistics (:data:`REFERENCE_STATISTICS`, the ``--reference-statistic`` option):

``pooled`` (the default: like with like)
    A block's estimate is a statistic of all its photons pooled (the ``atl08`` estimators:
    Hmax = the 98th percentile of the canopy photons' heights above the ground surface,
    H90 the 90th), so its reference is the same statistic of the airborne returns pooled
    over the block's footprints: each return's height above its footprint's ground plane,
    weighted by its footprint weight over the footprint's total (every shot draws its
    photons from its own normalised profile, so every footprint counts once), the returns
    more than ``canopy_threshold`` above the plane only (the classifier's: canopy photons
    are those more than ``Atl08Params.ground_buffer`` = 0.6 m above its ground surface;
    ``None`` for estimators whose top is a percentile of all kept photons, ground
    included), and the same percentiles (inverse weighted CDF: the smallest height whose
    cumulative weight reaches k %).  ``ref_hmax`` is that ``top_level`` percentile (0 when
    no footprint of the block sees a canopy return, as the estimate's Hmax of a block
    without canopy photons), ``ref_h90`` the 90th; ``ref_top = ref_ground + ref_hmax``
    and ``ref_top90 = ref_ground + ref_h90``, as the estimate's ``top = ground + hmax``.
    It grows with the block's length as the estimate does.
``footprint-mean``
    The mean over the block's footprints of each footprint's RH (all returns, ground
    included, :data:`~canopyblocks.reference.footprint_params.RH_LEVELS`): ``ref_top`` =
    mean of ``ground + RH{top_level}``, ``ref_top90`` = mean of ``ground + RH90``.  A
    different quantity: it does not grow with the block's length.
``footprint-max``
    The same with the maximum over the footprints.

``ref_ground`` is always the mean of the footprints' weighted class-2 ground; ``ref_cover``,
``slope`` the mean, ``aspect`` the circular mean over the ok footprints.
"""

from __future__ import annotations

import math
from typing import Literal

import geopandas as gpd
import numpy as np
import pandas as pd

from ..errors import InputError
from ..options import REFERENCE_STATISTICS
from ..progress import Progress, as_progress
from ..readers.las import LasPoints
from .corridor import positions_at, track_polyline
from .footprint import (
    FootprintCloud,
    ReturnPairs,
    _empty_result,
    _max_shots,
    _weighted_percentiles,
)
from .footprint_params import (
    FOOTPRINT_REFERENCE_COLUMNS,
    REFERENCE_FLAG_OK,
    REFERENCE_FLAG_OUTSIDE,
    RH_LEVELS,
    FootprintReferenceParams,
)

__all__ = ["block_footprint_reference", "pooled_percentiles", "estimate_statistic",
           "BlockStatistic", "REFERENCE_STATISTICS", "CANOPY_THRESHOLD", "H90_LEVEL"]

BlockStatistic = Literal["pooled", "footprint-mean", "footprint-max"]
#: Spellings of earlier releases (Python only) -> the statistic's name.
_OLD_NAMES = {"mean": "footprint-mean", "max": "footprint-max"}


def _canopy_threshold() -> float:
    from ..blocks.atl08_classify import Atl08Params
    return float(Atl08Params().ground_buffer)


#: Metres above the ground from which a return is canopy: the ATL08-style classifier's
#: (``Atl08Params.ground_buffer``; photons higher above its surface are canopy).
CANOPY_THRESHOLD: float = _canopy_threshold()
#: Percentile of the canopy heights giving H90.
H90_LEVEL = 90


def estimate_statistic(label: str | None) -> tuple[float | None, int]:
    """``(canopy_threshold, top_level)`` of the block estimators named by ``label`` (the
    block table's ``estimators`` column, e.g. ``noise=atl08,ground=atl08,top=atl08``):
    the classifier's canopy threshold and 98 for the ``atl08`` top; no threshold (all
    returns) and the percentile for ``pNN``; no threshold and 98 for the paper's window.
    No label (a table from elsewhere): the default estimators' (``atl08``)."""
    from ..blocks.atl08_blocks import HMAX_PERCENTILE

    top = "atl08"
    for part in str(label or "").split(","):
        key, _, value = part.partition("=")
        if key.strip() == "top" and value:
            top = value.strip()
    if top == "atl08":
        return CANOPY_THRESHOLD, int(HMAX_PERCENTILE)
    if top.startswith("p") and top[1:].isdigit():
        return None, int(top[1:])
    return None, int(HMAX_PERCENTILE)


def pooled_percentiles(block: np.ndarray, height: np.ndarray, weight: np.ndarray,
                       n_blocks: int, levels: tuple[int, ...]) -> np.ndarray:
    """Weighted percentiles of ``height`` pooled per ``block`` (inverse weighted CDF).

    Returns ``(len(levels), n_blocks)``; NaN for blocks without a value.
    """
    order = np.lexsort((height, block))
    b = block[order]
    return _weighted_percentiles(b, height[order], weight[order],
                                 np.bincount(b, minlength=n_blocks), levels)


def _check(statistic: str, top_level: int, canopy_threshold: float | None,
           spacing: float) -> str:
    stat = _OLD_NAMES.get(statistic, statistic)
    if stat not in REFERENCE_STATISTICS:
        raise InputError(f"statistic={statistic!r}; use one of {', '.join(REFERENCE_STATISTICS)}")
    if stat != "pooled" and top_level not in RH_LEVELS:
        raise InputError(f"top_level={top_level!r}; use one of {RH_LEVELS}")
    if not (isinstance(top_level, (int, np.integer)) and 0 < top_level <= 100):
        raise InputError(f"top_level={top_level!r}; use a percentile in (0, 100]")
    if canopy_threshold is not None and not (math.isfinite(canopy_threshold)
                                             and canopy_threshold >= 0):
        raise InputError(f"canopy_threshold must be >= 0 m or None, got {canopy_threshold!r}")
    if not (math.isfinite(spacing) and spacing > 0):
        raise InputError(f"spacing must be a positive number of metres, got {spacing!r}")
    return stat


def block_footprint_reference(blocks: gpd.GeoDataFrame | pd.DataFrame,
                              points: LasPoints | FootprintCloud,
                              params: FootprintReferenceParams | None = None, *,
                              spacing: float = 0.7, statistic: str = "pooled",
                              top_level: int = 98,
                              canopy_threshold: float | None = CANOPY_THRESHOLD,
                              slope_threshold: float = 2.0,
                              progress: Progress | None = None) -> pd.DataFrame:
    """Footprint-matched reference per photon block (DESIGN 2.7; module notes).

    Parameters
    ----------
    blocks : GeoDataFrame
        Block table (``track, length, block, s_start, s_end, x, y``), centres in the
        points' CRS (metres).
    points : LasPoints or FootprintCloud
    params : FootprintReferenceParams, optional
        Default ICESat-2, 13 m, points within R (the photon simulator's set).
    spacing : float
        Footprint spacing along the track, metres (ICESat-2: 0.7 m).
    statistic : {"pooled", "footprint-mean", "footprint-max"}
        How the footprints' returns make the block's heights (module notes).
    top_level : int
        Percentile giving the top (98: like the estimate's Hmax; ``footprint-*``: one of
        the RH levels, 100 for the highest point).
    canopy_threshold : float or None
        ``pooled``: metres above the ground plane from which a return counts (the
        classifier's 0.6 m); None: every return, ground included.
    slope_threshold : float
        Degrees below which the block's aspect class is ``flat``.

    Returns
    -------
    DataFrame
        Index of ``blocks``: ``track, length, block``, ``ref_ground``, ``ref_top``,
        ``ref_top90``, ``ref_hmax = ref_top - ref_ground``, ``ref_h90 = ref_top90 -
        ref_ground``, ``ref_rh98`` (the top percentile's height above the ground),
        ``ref_cover``, ``slope``, ``aspect``, ``aspect_class``, ``slope_class``,
        ``n_footprints``, ``coverage`` (share of the block's footprints flagged ok),
        ``ref_flag`` (``outside`` when any footprint of the block is outside the points,
        ``nodata`` when none is ok, else ``ok``) and ``ref_statistic`` (the statistic).
    """
    from ..arguments import check_frame, check_instance
    check_frame(blocks, "block_footprint_reference: blocks", "a block table (DataFrame)")
    check_instance(points, (LasPoints, FootprintCloud), "block_footprint_reference: points",
                   "airborne points (read_las)")
    from .terrain import aspect_class, slope_class

    prog = as_progress(progress)
    stat = _check(statistic, top_level, canopy_threshold, spacing)
    need = ("track", "length", "block", "s_start", "s_end", "x", "y")
    missing = [c for c in need if c not in blocks.columns]
    if missing:
        raise InputError(f"the block table lacks column(s) {', '.join(missing)}")
    cloud = points if isinstance(points, FootprintCloud) else FootprintCloud(
        points, params or FootprintReferenceParams())
    bcrs = getattr(blocks, "crs", None)
    if bcrs is not None and not cloud.crs.equals(bcrs, ignore_axis_order=True):
        raise InputError(
            f"the blocks' CRS {bcrs.to_string()} differs from the points' "
            f"{cloud.crs.to_string()}; reproject the block table first")
    nb = len(blocks)
    acc = _Accumulator(nb, stat, int(top_level), canopy_threshold)
    s_start = blocks["s_start"].to_numpy(float)
    s_end = blocks["s_end"].to_numpy(float)
    keys = blocks[["track", "length"]].reset_index(drop=True)
    groups = list(keys.groupby(["track", "length"], sort=False).groups.values())
    cap = _max_shots(cloud)
    for gi, g_idx in enumerate(groups):
        rows = np.asarray(g_idx, dtype=np.int64)
        s_nodes, xy_nodes = track_polyline(blocks.iloc[rows])
        s, owner = _footprints_of(rows, s_start, s_end, spacing)
        gprog = prog.sub(gi / len(groups), (gi + 1) / len(groups))
        bounds = _batches(owner, cap)
        for a, b in zip(bounds[:-1], bounds[1:]):  # loop over batches of whole blocks
            pairs: list[ReturnPairs] = []
            res = _evaluate_along(cloud, s[a:b], positions_at(s_nodes, xy_nodes, s[a:b]),
                                  s_nodes, xy_nodes, gprog.sub(a / s.size, b / s.size),
                                  pairs_out=pairs if stat == "pooled" else None)
            acc.add(owner[a:b], res, pairs)
    out = pd.DataFrame({c: blocks[c].to_numpy() for c in ("track", "length", "block")},
                       index=blocks.index)
    v = acc.values
    out["ref_ground"] = v["ref_ground"]
    out["ref_top"] = v["ref_ground"] + v["hmax"]
    out["ref_top90"] = v["ref_ground"] + v["h90"]
    out["ref_hmax"] = out["ref_top"] - out["ref_ground"]
    out["ref_h90"] = out["ref_top90"] - out["ref_ground"]
    out["ref_rh98"] = v["rh98"]
    out["ref_cover"] = v["ref_cover"]
    out["slope"] = v["slope"]
    out["aspect"] = v["aspect"]
    out["aspect_class"] = aspect_class(v["aspect"], v["slope"], slope_threshold) if nb else []
    out["slope_class"] = slope_class(v["slope"]) if nb else []
    out["n_footprints"] = acc.n_fp
    out["coverage"] = np.nan_to_num(acc.ok / np.maximum(acc.n_fp, 1), nan=0.0)
    flag = np.full(nb, "ok", dtype=object)
    flag[~np.isfinite(v["ref_ground"])] = "nodata"
    flag[acc.outside] = "outside"
    out["ref_flag"] = flag
    out["ref_statistic"] = stat
    prog.update(1.0, f"footprint reference for {nb:,} blocks")
    return out


def _footprints_of(rows: np.ndarray, s_start: np.ndarray, s_end: np.ndarray,
                   spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Along-track positions of the footprints of the blocks ``rows`` (sorted) and the
    block (row) holding each."""
    lo, hi = float(np.nanmin(s_start[rows])), float(np.nanmax(s_end[rows]))
    k0, k1 = math.floor(lo / spacing - 0.5), math.ceil(hi / spacing - 0.5)
    s = (np.arange(k0, k1 + 1) + 0.5) * spacing
    s = s[(s >= lo) & (s < hi)]
    order = rows[np.argsort(s_start[rows], kind="stable")]
    j = np.searchsorted(s_start[order], s, side="right") - 1
    inb = (j >= 0) & (s < s_end[order[np.maximum(j, 0)]])
    return s[inb], order[j[inb]]


def _batches(owner: np.ndarray, cap: int) -> np.ndarray:
    """Bounds of consecutive runs of footprints of about ``cap`` footprints that never
    split a block (a block's returns are pooled in one batch)."""
    n = owner.size
    if n == 0:
        return np.array([0, 0])
    starts = np.concatenate([[0], np.flatnonzero(np.diff(owner)) + 1])
    first = np.concatenate([[True], np.diff(starts // max(cap, 1)) > 0])
    return np.concatenate([starts[first], [n]])


class _Accumulator:
    """Per-block values filled batch by batch (each block in exactly one batch)."""

    def __init__(self, nb: int, stat: str, top_level: int,
                 threshold: float | None) -> None:
        self.nb, self.stat, self.top_level, self.threshold = nb, stat, top_level, threshold
        self.values = {c: np.full(nb, np.nan) for c in
                       ("ref_ground", "hmax", "h90", "rh98", "ref_cover", "slope", "aspect")}
        self.n_fp = np.zeros(nb, np.int64)
        self.ok = np.zeros(nb, np.int64)
        self.outside = np.zeros(nb, bool)

    def add(self, owner: np.ndarray, res: dict[str, np.ndarray],
            pairs: list[ReturnPairs]) -> None:
        nb, v = self.nb, self.values
        ok = res["ref_flag"] == REFERENCE_FLAG_OK
        np.add.at(self.n_fp, owner, 1)
        self.outside[np.unique(owner[res["ref_flag"] == REFERENCE_FLAG_OUTSIDE])] = True
        o = owner[ok]
        cnt = np.bincount(o, minlength=nb)
        self.ok += cnt
        has = cnt > 0

        def mean(x: np.ndarray) -> np.ndarray:
            return np.bincount(o, x, minlength=nb)[has] / cnt[has]

        v["ref_ground"][has] = mean(res["ref_ground"][ok])
        v["ref_cover"][has] = mean(res["ref_cover"][ok])
        v["slope"][has] = mean(res["ref_slope"][ok])
        a = np.radians(res["ref_aspect"][ok])
        fin = np.isfinite(a)
        sin = np.bincount(o[fin], np.sin(a[fin]), minlength=nb)
        cos = np.bincount(o[fin], np.cos(a[fin]), minlength=nb)
        asp = np.degrees(np.arctan2(sin, cos)) % 360.0
        asp[(sin == 0) & (cos == 0)] = np.nan
        v["aspect"][has] = asp[has]
        if self.stat == "pooled":
            hmax, h90 = self._pooled(owner, ok, pairs)
            v["rh98"][has] = hmax[has]
        else:  # the mean (maximum) of the footprints' tops, less the mean ground
            ground = res["ref_ground"][ok]
            top = ground + res[f"ref_rh{self.top_level}"][ok]
            hmax = self._per_footprint(o, top) - v["ref_ground"]
            h90 = self._per_footprint(o, ground + res["ref_rh90"][ok]) - v["ref_ground"]
            v["rh98"][has] = self._per_footprint(o, res[f"ref_rh{self.top_level}"][ok])[has]
        v["hmax"][has], v["h90"][has] = hmax[has], h90[has]

    def _per_footprint(self, o: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Mean (or maximum) over the footprints of ``x``, per block."""
        if self.stat == "footprint-max":
            m = np.full(self.nb, -np.inf)
            np.maximum.at(m, o, x)
            return m
        return np.bincount(o, x, minlength=self.nb) / np.maximum(
            np.bincount(o, minlength=self.nb), 1)

    def _pooled(self, owner: np.ndarray, ok: np.ndarray, pairs: list[ReturnPairs]
                ) -> tuple[np.ndarray, np.ndarray]:
        """The percentiles of the returns of the block's ok footprints, pooled."""
        zero = np.zeros(self.nb)
        if not pairs:
            return zero, zero.copy()
        shot = np.concatenate([p.shot for p in pairs])
        h = np.concatenate([p.height for p in pairs])
        w = np.concatenate([p.weight for p in pairs])
        keep = ok[shot] & np.isfinite(w)
        if self.threshold is not None:
            keep &= h > self.threshold
        b = owner[shot[keep]]
        rh = pooled_percentiles(b, h[keep], w[keep], self.nb, (self.top_level, H90_LEVEL))
        # a block whose footprints see no canopy return: 0, as the estimate's
        return np.nan_to_num(rh[0], nan=0.0), np.nan_to_num(rh[1], nan=0.0)


def _evaluate_along(cloud: FootprintCloud, s: np.ndarray, xy: np.ndarray,
                    s_nodes: np.ndarray, xy_nodes: np.ndarray, prog: Progress,
                    pairs_out: list[ReturnPairs] | None = None) -> dict[str, np.ndarray]:
    """Reference values of footprints on a polyline, one straight run per segment;
    ``pairs_out`` gets their returns (footprint indices into ``s``)."""
    n = s.size
    out = _empty_result(n)
    if n == 0:
        return out
    seg = np.clip(np.searchsorted(s_nodes, s, side="right") - 1, 0, s_nodes.size - 2)
    cuts = np.flatnonzero(np.diff(seg)) + 1
    bounds = np.concatenate([[0], cuts, [n]])
    cap = _max_shots(cloud)
    for i in range(bounds.size - 1):  # loop over straight runs (polyline segments)
        a, b = int(bounds[i]), int(bounds[i + 1])
        k = int(seg[a])
        line = (float(xy_nodes[k, 0]), float(xy_nodes[k, 1]), float(xy_nodes[k + 1, 0]),
                float(xy_nodes[k + 1, 1]))
        for c0 in range(a, b, cap):
            c1 = min(c0 + cap, b)
            got: list[ReturnPairs] = []
            res = cloud.evaluate(xy[c0:c1, 0], xy[c0:c1, 1], line=line,
                                 pairs_out=got if pairs_out is not None else None)
            for c in FOOTPRINT_REFERENCE_COLUMNS:
                out[c][c0:c1] = res[c]
            if pairs_out is not None:
                pairs_out.extend(ReturnPairs(p.shot + c0, p.height, p.weight) for p in got)
        prog.update(b / n, f"footprint reference {b:,}/{n:,} footprints")
    return out
