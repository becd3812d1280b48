"""Footprint-matched reference from airborne lidar points (DESIGN 2.7, 4.9, 4.10).

Per footprint centre ``(x, y)`` (metres, in the points' CRS) the airborne points are
weighted the way the sensor sees the surface, and reduced to the quantities a waveform
or photon product reports.  Definitions (heights in metres, in the points' vertical
datum; angles in degrees):

Weights
    ``w = exp(-2 r^2 / R^2)``, ``r`` the horizontal distance to the centre and ``R =
    diameter / 2`` the 1/e^2 radius (GEDI: sigma 5.5 m -> R = 11 m, diameter 22 m;
    ICESat-2: diameter 13 m early in the mission, 17 m later).  With ``weighting=
    "gaussian_density"`` each weight is also divided by the number of points in the
    point's 1.5 m cell (cells ``[i c, (i + 1) c)`` of the points' CRS, all kept points
    counted, whatever footprint they fall in), so the survey's point density does not
    count (DESIGN 4.9).
Radius cut
    Points with ``r <= cut * R`` count (``cut`` = 1.0 by default: exactly the set the
    photon simulator draws from, DESIGN 3.1, so simulated truth and this reference agree;
    :meth:`FootprintReferenceParams.gedi` uses 1.5, i.e. 3 sigma, 98.9 % of a Gaussian
    beam's energy, because a real GEDI waveform holds the energy beyond R too).
Ground plane
    A plane fitted by weighted least squares to the class-2 points; ``ref_slope`` =
    ``atan(|grad|)``, ``ref_aspect`` = the downhill direction clockwise from north in
    [0, 360) (the Horn/GDAL convention of :mod:`~canopyblocks.reference.terrain`); NaN
    aspect where the plane is exactly level.
``ref_ground``
    Weighted mean elevation of the class-2 points.
Heights above ground
    Each point's elevation minus the ground plane under it (not a single mean: on a
    10 degree slope a 22 m footprint spans almost 4 m of terrain).
``ref_rh{50,75,90,95,98,100}`` (GEDI definition)
    Weighted percentiles of the heights above ground of ALL returns, ground included,
    as GEDI RH is taken from the whole waveform's energy including the ground return:
    the smallest height whose cumulative weight (from the lowest point up) reaches
    k % of the footprint's weight (inverse CDF, no interpolation).  ``ref_rh100`` is the
    highest point above the plane.
``ref_canopy_rh*`` (simulator-truth definition, DESIGN 3.4)
    The same over the points more than ``canopy_floor`` (0.5 m) above the plane only;
    0 when there is no such point.
``ref_top``
    Elevation of the highest point in the footprint (every point within the cut has a
    weight > 0), as the simulator's truth.
``ref_cover``
    Weighted share of all returns more than ``cover_threshold`` (2 m) above the plane
    (canopy returns over all returns, DESIGN 3.4 with the footprint weights; GEDI's
    cover is the canopy share of the energy).  ``ref_cover_first``: the same over first
    returns only (the usual airborne cover estimate).
``ref_n_points``, ``ref_n_ground``
    Points and class-2 points within the cut.
``ref_coverage``
    Share of a lattice of sample positions inside the cut circle (spacing = the
    occupancy cell, >= 2 m; :func:`~.footprint_index.occupancy_cell`) that fall in cells
    holding airborne points, cells at fixed multiples of it: independent of what was read.
``ref_flag``
    ``ok``; ``outside`` when ``ref_coverage < min_coverage`` (the footprint reaches
    beyond the tiles, or over a data gap); ``no_ground`` when fewer than
    ``min_ground_points`` class-2 points (or collinear ones) make the plane.  Values of
    ``outside`` footprints are still computed where there are points; ``no_ground``
    footprints get NaN heights, cover, slope and aspect.

Implementation: the points go into one :class:`~canopyblocks.reference.footprint_index.
CloudIndex`; footprints are answered in spatially compact chunks (cells of 2 cut radii;
footprints on a straight track run by run), every chunk vectorised over its (footprint,
point) pairs: weighted sums by ``bincount``, percentiles by one sort by (footprint,
height above ground) and a search in the per-footprint normalised cumulative weights.
"""

from __future__ import annotations

import logging
import math
from typing import Literal

import geopandas as gpd
import numpy as np
import pandas as pd

from ..errors import InputError, NoUsableDataError
from ..progress import Progress, as_progress
from ..readers.las import LasPoints
from .corridor import positions_at, track_polyline
from .footprint_index import CloudIndex, occupancy_cell
from .footprint_params import (
    FOOTPRINT_REFERENCE_COLUMNS,
    REFERENCE_FLAG_NO_GROUND,
    REFERENCE_FLAG_OK,
    REFERENCE_FLAG_OUTSIDE,
    RH_LEVELS,
    FootprintReferenceParams,
)

__all__ = [
    "FootprintReferenceParams",
    "FootprintCloud",
    "footprint_reference",
    "block_footprint_reference",
    "density_weights",
    "RH_LEVELS",
    "REFERENCE_FLAG_OK",
    "REFERENCE_FLAG_OUTSIDE",
    "REFERENCE_FLAG_NO_GROUND",
    "FOOTPRINT_REFERENCE_COLUMNS",
]

log = logging.getLogger(__name__)


_CHUNK_PAIRS = 3_000_000  # pairs per chunk of footprints (bounded memory)
_EPS_Q = 1e-12


def density_weights(x: np.ndarray, y: np.ndarray, cell: float) -> np.ndarray:
    """``1 / (points in the point's cell)`` on a grid of ``cell`` metres anchored at 0."""
    ix = np.floor(np.asarray(x, float) / cell).astype(np.int64)
    iy = np.floor(np.asarray(y, float) / cell).astype(np.int64)
    key = (ix - ix.min()) * (int(iy.max() - iy.min()) + 1) + (iy - iy.min()) if ix.size \
        else ix
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    return 1.0 / counts[inv].astype(np.float64)


class FootprintCloud:
    """The airborne points prepared once for footprint queries (index, classes, weights).

    Parameters
    ----------
    points : LasPoints
        Airborne points (x, y metres in a metric CRS).
    params : FootprintReferenceParams
    """

    def __init__(self, points: LasPoints, params: FootprintReferenceParams) -> None:
        keep = np.isfinite(points.x) & np.isfinite(points.y) & np.isfinite(points.z)
        if params.exclude_classes:
            keep &= ~np.isin(points.classification, np.asarray(params.exclude_classes))
        ids = np.flatnonzero(keep)
        if ids.size == 0:
            raise NoUsableDataError("no airborne point left (all non-finite or noise classes)")
        self.params = params
        self.crs = points.crs
        self.index = CloudIndex(points.x[ids], points.y[ids], points.z[ids])
        self.ground = points.classification[ids] == params.ground_class
        self.first = points.return_number[ids] <= 1
        self.base_weight = (density_weights(self.index.x, self.index.y, params.density_cell)
                            if params.weighting == "gaussian_density" else None)
        # occupancy grid for the coverage of each footprint: cells at fixed multiples of
        # the cell (points' CRS), so a footprint's coverage is independent of what was read
        x, y = self.index.x, self.index.y
        self.occ_cell = c = occupancy_cell(x, y)
        ix, iy = np.floor(x / c).astype(np.int64), np.floor(y / c).astype(np.int64)
        self.occ_i0, self.occ_j0 = int(ix.min()), int(iy.min())
        self.occ_nx = int(ix.max()) - self.occ_i0 + 1
        self.occ_ny = int(iy.max()) - self.occ_j0 + 1
        occ = np.zeros(self.occ_nx * self.occ_ny, dtype=bool)
        occ[(iy - self.occ_j0) * self.occ_nx + (ix - self.occ_i0)] = True
        self.occupied = occ
        r = params.cut_radius
        m = int(r // c)
        gi, gj = np.meshgrid(np.arange(-m, m + 1), np.arange(-m, m + 1))
        inside = (gi * c) ** 2 + (gj * c) ** 2 <= r * r
        self.stencil = np.column_stack([gi[inside] * c, gj[inside] * c])

    def coverage(self, sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
        """Share of each footprint's sample lattice that falls on occupied cells (0..1)."""
        px = sx[:, None] + self.stencil[None, :, 0]
        py = sy[:, None] + self.stencil[None, :, 1]
        c = self.occ_cell
        ix = np.floor(px / c).astype(np.int64) - self.occ_i0
        iy = np.floor(py / c).astype(np.int64) - self.occ_j0
        valid = (ix >= 0) & (ix < self.occ_nx) & (iy >= 0) & (iy < self.occ_ny)
        hit = np.zeros(px.shape, dtype=bool)
        hit[valid] = self.occupied[iy[valid] * self.occ_nx + ix[valid]]
        return hit.mean(axis=1)

    # ------------------------------------------------------------------ one chunk
    def evaluate(self, sx: np.ndarray, sy: np.ndarray,
                 line: tuple[float, float, float, float] | None = None
                 ) -> dict[str, np.ndarray]:
        """Reference values of the footprints ``(sx, sy)`` (one compact chunk)."""
        p = self.params
        k = sx.size
        R, rc = p.radius, p.cut_radius
        out = _empty_result(k)
        out["ref_coverage"] = self.coverage(sx, sy)
        pairs = self.index.pairs(sx, sy, rc, line=line)
        counts = pairs.counts
        if pairs.z.size == 0:
            out["ref_flag"][:] = REFERENCE_FLAG_OUTSIDE
            return out
        shot, pt = pairs.shot, pairs.point
        dx = self.index.x[pt] - sx[shot]
        dy = self.index.y[pt] - sy[shot]
        z = pairs.z
        r2 = dx * dx + dy * dy
        inside = r2 <= rc * rc  # the index's own test, repeated in these coordinates
        if not inside.all():
            shot, pt, dx, dy, z, r2 = (a[inside] for a in (shot, pt, dx, dy, z, r2))
            counts = np.bincount(shot, minlength=k)
        w = np.exp(r2 * (-2.0 / (R * R)))
        if self.base_weight is not None:
            w *= self.base_weight[pt]
        has = counts > 0
        out["ref_n_points"] = counts.astype(np.int64)
        out["ref_top"][has] = np.maximum.reduceat(z, _starts(counts)[has])
        # ---- weighted ground plane through the class-2 points
        g = self.ground[pt]
        gs, gw = shot[g], w[g]
        n_g = np.bincount(gs, minlength=k)
        out["ref_n_ground"] = n_g.astype(np.int64)
        sw = np.bincount(gs, gw, minlength=k)
        with np.errstate(invalid="ignore", divide="ignore"):
            mx = np.bincount(gs, gw * dx[g], minlength=k) / sw
            my = np.bincount(gs, gw * dy[g], minlength=k) / sw
            mz = np.bincount(gs, gw * z[g], minlength=k) / sw
        ex, ey, ez = dx[g] - mx[gs], dy[g] - my[gs], z[g] - mz[gs]
        sxx = np.bincount(gs, gw * ex * ex, minlength=k)
        syy = np.bincount(gs, gw * ey * ey, minlength=k)
        sxy = np.bincount(gs, gw * ex * ey, minlength=k)
        sxz = np.bincount(gs, gw * ex * ez, minlength=k)
        syz = np.bincount(gs, gw * ey * ez, minlength=k)
        det = sxx * syy - sxy * sxy
        good = (n_g >= p.min_ground_points) & (sw > 0) & (det > 1e-9 * (sxx + syy) ** 2)
        safe = np.where(good, det, 1.0)
        bx = np.where(good, (sxz * syy - syz * sxy) / safe, np.nan)  # dz/dx (east)
        by = np.where(good, (syz * sxx - sxz * sxy) / safe, np.nan)  # dz/dy (north)
        out["ref_ground"] = np.where(good, mz, np.nan)
        out["ref_slope"] = np.degrees(np.arctan(np.hypot(bx, by)))
        aspect = np.degrees(np.arctan2(-bx, -by)) % 360.0
        aspect[(bx == 0) & (by == 0)] = np.nan
        out["ref_aspect"] = aspect
        # ---- heights above the plane; pairs of footprints without a plane dropped
        live = good[shot]
        shot, dx, dy, z, w, pt = (a[live] for a in (shot, dx, dy, z, w, pt))
        hag = z - (mz[shot] + bx[shot] * (dx - mx[shot]) + by[shot] * (dy - my[shot]))
        order = np.lexsort((hag, shot))
        shot, hag, w, pt = shot[order], hag[order], w[order], pt[order]
        cnt = np.bincount(shot, minlength=k)
        wsum = np.bincount(shot, w, minlength=k)
        canopy = hag > p.cover_threshold
        with np.errstate(invalid="ignore", divide="ignore"):
            out["ref_cover"] = np.where(good, np.bincount(shot, w * canopy, minlength=k)
                                        / wsum, np.nan)
            first = self.first[pt]
            wf = np.bincount(shot, w * first, minlength=k)
            out["ref_cover_first"] = np.where(
                good & (wf > 0), np.bincount(shot, w * (first & canopy), minlength=k) / wf,
                np.nan)
        rh = _weighted_percentiles(shot, hag, w, cnt, RH_LEVELS)
        for j, q in enumerate(RH_LEVELS):
            out[f"ref_rh{q}"] = np.where(good, rh[j], np.nan)
        above = hag > p.canopy_floor
        crh = _weighted_percentiles(shot[above], hag[above], w[above],
                                    np.bincount(shot[above], minlength=k), RH_LEVELS)
        for j, q in enumerate(RH_LEVELS):
            out[f"ref_canopy_rh{q}"] = np.where(good, np.nan_to_num(crh[j], nan=0.0), np.nan)
        flag = out["ref_flag"]
        flag[:] = REFERENCE_FLAG_OK
        flag[~good] = REFERENCE_FLAG_NO_GROUND
        flag[out["ref_coverage"] < p.min_coverage] = REFERENCE_FLAG_OUTSIDE
        return out


def _starts(counts: np.ndarray) -> np.ndarray:
    return np.cumsum(counts) - counts


def _empty_result(k: int) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {c: np.full(k, np.nan) for c in FOOTPRINT_REFERENCE_COLUMNS}
    out["ref_n_points"] = np.zeros(k, np.int64)
    out["ref_n_ground"] = np.zeros(k, np.int64)
    out["ref_flag"] = np.full(k, REFERENCE_FLAG_NO_GROUND, dtype=object)
    return out


def _weighted_percentiles(shot: np.ndarray, h: np.ndarray, w: np.ndarray,
                          counts: np.ndarray, levels: tuple[int, ...]) -> np.ndarray:
    """Inverse-CDF weighted percentiles per shot of values sorted by (shot, h).

    Returns ``(len(levels), n_shots)``; NaN for shots without values.  For level q the
    value is the first ``h`` whose cumulative weight within its shot reaches q % of the
    shot's weight (relative tolerance 1e-12).
    """
    k = counts.size
    res = np.full((len(levels), k), np.nan)
    has = counts > 0
    if not has.any():
        return res
    starts = _starts(counts)
    cw = np.cumsum(w)
    before = np.where(starts > 0, cw[np.maximum(starts - 1, 0)], 0.0)
    local = cw - np.repeat(before, counts)
    total = np.ones(k)
    total[has] = local[(starts + counts - 1)[has]]
    frac = local / np.repeat(total, counts)
    key = 2.0 * shot + frac  # increasing: shot, then cumulative fraction in (0, 1]
    ids = np.flatnonzero(has)
    q = np.asarray(levels, float)[:, None] / 100.0 - _EPS_Q
    idx = np.searchsorted(key, 2.0 * ids[None, :] + q, side="left")
    idx = np.clip(idx, starts[ids][None, :], (starts + counts - 1)[ids][None, :])
    res[:, ids] = h[idx]
    return res


def _spatial_chunks(sx: np.ndarray, sy: np.ndarray, cell: float,
                    max_shots: int) -> list[np.ndarray]:
    """Footprint indices grouped by cells of ``cell`` metres (compact chunks)."""
    ix = np.floor((sx - sx.min()) / cell).astype(np.int64)
    iy = np.floor((sy - sy.min()) / cell).astype(np.int64)
    key = iy * (int(ix.max()) + 1) + ix
    order = np.argsort(key, kind="stable")
    ks = key[order]
    cuts = np.flatnonzero(np.diff(ks)) + 1
    chunks = []
    for grp in np.split(order, cuts):
        for a in range(0, grp.size, max_shots):
            chunks.append(grp[a:a + max_shots])
    return chunks


def _max_shots(cloud: FootprintCloud) -> int:
    """Footprints per chunk so that a chunk holds about ``_CHUNK_PAIRS`` pairs."""
    n = cloud.index.x.size
    x, y = cloud.index.x, cloud.index.y
    area = max(float((x.max() - x.min()) * (y.max() - y.min())), 1.0)
    per_fp = max(n / area * math.pi * cloud.params.cut_radius ** 2, 1.0)
    return int(max(1, min(20_000, _CHUNK_PAIRS // per_fp)))


def _refuse_degrees(sx: np.ndarray, sy: np.ndarray, cloud: FootprintCloud) -> None:
    """Refuse centres that are lon/lat degrees given for a cloud in metres: every centre
    within +-180 / +-90, not whole numbers, and none within 1 km of the cloud."""
    fin = np.isfinite(sx) & np.isfinite(sy)
    if not fin.any() or cloud.index.x.size == 0:
        return
    fx, fy = sx[fin], sy[fin]
    if np.abs(fx).max() > 180.0 or np.abs(fy).max() > 90.0 or \
            (np.all(fx == np.round(fx)) and np.all(fy == np.round(fy))):
        return
    x0, x1 = float(cloud.index.x.min()), float(cloud.index.x.max())
    y0, y1 = float(cloud.index.y.min()), float(cloud.index.y.max())
    near = (fx >= x0 - 1000) & (fx <= x1 + 1000) & (fy >= y0 - 1000) & (fy <= y1 + 1000)
    if near.any():
        return
    raise InputError(f"footprint_reference: centres x {fx.min():.6g}..{fx.max():.6g}, y "
                     f"{fy.min():.6g}..{fy.max():.6g} look like lon/lat degrees, but the "
                     f"airborne points are in metres (x {x0:.0f}..{x1:.0f}, y "
                     f"{y0:.0f}..{y1:.0f}); project the centres to the points' CRS")


def footprint_reference(points: LasPoints | FootprintCloud, x: np.ndarray, y: np.ndarray,
                        params: FootprintReferenceParams | None = None, *,
                        progress: Progress | None = None) -> pd.DataFrame:
    """Footprint-matched reference values at footprint centres ``(x, y)``.

    Parameters
    ----------
    points : LasPoints or FootprintCloud
        Airborne points (or a :class:`FootprintCloud` built once from them, to reuse).
    x, y : array-like
        Footprint centres, metres, in the points' CRS.
    params : FootprintReferenceParams, optional
        Diameter, weighting, radius cut, thresholds (default: ICESat-2, 13 m).
    progress : Progress, optional

    Returns
    -------
    DataFrame
        One row per centre, in input order: :data:`FOOTPRINT_REFERENCE_COLUMNS` (see the
        module notes for each definition).  Non-finite centres are flagged ``outside``.
    """
    from ..arguments import check_array, check_instance
    check_instance(
        points,
        (LasPoints, FootprintCloud),
        "footprint_reference: points",
        "airborne points (read_las)",
    )
    check_array(x, "footprint_reference: x")
    check_array(y, "footprint_reference: y")
    prog = as_progress(progress)
    cloud = points if isinstance(points, FootprintCloud) else FootprintCloud(
        points, params or FootprintReferenceParams())
    if params is not None and cloud.params != params:
        raise InputError("the FootprintCloud was built with other parameters than those given")
    sx = np.asarray(x, dtype=np.float64).ravel()
    sy = np.asarray(y, dtype=np.float64).ravel()
    if sx.shape != sy.shape:
        raise InputError(f"x and y must have the same length; got {sx.size} and {sy.size}")
    _refuse_degrees(sx, sy, cloud)
    n = sx.size
    out = _empty_result(n)
    out["ref_flag"][:] = REFERENCE_FLAG_OUTSIDE
    out["ref_coverage"][:] = 0.0
    ok = np.flatnonzero(np.isfinite(sx) & np.isfinite(sy))
    if ok.size:
        chunks = _spatial_chunks(sx[ok], sy[ok], 2.0 * cloud.params.cut_radius,
                                 _max_shots(cloud))
        done = 0
        for rows in chunks:  # loop over compact groups of footprints (one query each)
            idx = ok[rows]
            res = cloud.evaluate(sx[idx], sy[idx])
            for c in FOOTPRINT_REFERENCE_COLUMNS:
                out[c][idx] = res[c]
            done += idx.size
            prog.update(done / ok.size, f"footprint reference {done:,}/{ok.size:,}")
    prog.update(1.0, f"footprint reference: {n:,} footprints")
    return pd.DataFrame({c: out[c] for c in FOOTPRINT_REFERENCE_COLUMNS})


# ---------------------------------------------------------------------- photon blocks
BlockStatistic = Literal["mean", "max"]


def block_footprint_reference(blocks: gpd.GeoDataFrame | pd.DataFrame,
                              points: LasPoints | FootprintCloud,
                              params: FootprintReferenceParams | None = None, *,
                              spacing: float = 0.7, statistic: BlockStatistic = "mean",
                              top_level: int = 98, slope_threshold: float = 2.0,
                              progress: Progress | None = None) -> pd.DataFrame:
    """Footprint-matched reference per photon block (DESIGN 2.7).

    Footprints every ``spacing`` metres along each ``(track, length)``'s track line (the
    polyline of :func:`~canopyblocks.reference.corridor.track_polyline`, footprints at
    ``s = (k + 0.5) * spacing``), assigned to the block whose ``[s_start, s_end)`` holds
    them; per block the footprints flagged ``ok`` are reduced.

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
    statistic : {"mean", "max"}
        Reduction of the footprints' heights (top, top90, rh98); the ground and cover
        are always the mean.
    top_level : int
        RH level taken as the canopy top (98: ``ref_top = ground + RH98``, like with
        like with a photon top that is a high percentile; 100 for the highest point).
    slope_threshold : float
        Degrees below which the block's aspect class is ``flat``.

    Returns
    -------
    DataFrame
        Index of ``blocks``: ``track, length, block``, ``ref_ground`` (mean footprint
        ground), ``ref_top`` (statistic of ground + RH``top_level``), ``ref_top90``
        (statistic of ground + RH90), ``ref_hmax = ref_top - ref_ground``, ``ref_h90 =
        ref_top90 - ref_ground``, ``ref_rh98`` (statistic of RH98), ``ref_cover`` (mean),
        ``slope`` (mean footprint slope), ``aspect`` (circular mean), ``aspect_class``,
        ``slope_class``, ``n_footprints``, ``coverage`` (share of the block's
        footprints flagged ok) and ``ref_flag``: ``outside`` when any footprint of the
        block is outside the points, ``nodata`` when none is ok, else ``ok``.
    """
    from ..arguments import check_frame, check_instance
    check_frame(blocks, "block_footprint_reference: blocks", "a block table (DataFrame)")
    check_instance(
        points,
        (LasPoints, FootprintCloud),
        "block_footprint_reference: points",
        "airborne points (read_las)",
    )
    from .terrain import aspect_class, slope_class

    prog = as_progress(progress)
    if statistic not in ("mean", "max"):
        raise InputError(f"statistic={statistic!r}; use 'mean' or 'max'")
    if top_level not in RH_LEVELS:
        raise InputError(f"top_level={top_level!r}; use one of {RH_LEVELS}")
    if not (math.isfinite(spacing) and spacing > 0):
        raise InputError(f"spacing must be a positive number of metres, got {spacing!r}")
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
    acc = {c: np.full(nb, np.nan) for c in
           ("ref_ground", "ref_top", "ref_top90", "ref_rh98", "ref_cover", "slope", "aspect",
            "coverage")}
    n_fp = np.zeros(nb, np.int64)
    outside = np.zeros(nb, bool)
    s_start = blocks["s_start"].to_numpy(float)
    s_end = blocks["s_end"].to_numpy(float)
    keys = blocks[["track", "length"]].reset_index(drop=True)
    groups = list(keys.groupby(["track", "length"], sort=False).groups.values())
    for gi, g_idx in enumerate(groups):
        rows = np.asarray(g_idx, dtype=np.int64)
        s_nodes, xy_nodes = track_polyline(blocks.iloc[rows])
        lo, hi = float(np.nanmin(s_start[rows])), float(np.nanmax(s_end[rows]))
        k0, k1 = math.floor(lo / spacing - 0.5), math.ceil(hi / spacing - 0.5)
        s = (np.arange(k0, k1 + 1) + 0.5) * spacing
        s = s[(s >= lo) & (s < hi)]
        # which block holds each footprint
        order = rows[np.argsort(s_start[rows], kind="stable")]
        j = np.searchsorted(s_start[order], s, side="right") - 1
        inb = (j >= 0) & (s < s_end[order[np.maximum(j, 0)]])
        s, owner = s[inb], order[j[inb]]
        xy = positions_at(s_nodes, xy_nodes, s)
        res = _evaluate_along(cloud, s, xy, s_nodes, xy_nodes,
                              prog.sub(gi / len(groups), (gi + 1) / len(groups)))
        ok = res["ref_flag"] == REFERENCE_FLAG_OK
        np.add.at(n_fp, owner, 1)
        outside[np.unique(owner[res["ref_flag"] == REFERENCE_FLAG_OUTSIDE])] = True
        o = owner[ok]
        cnt = np.bincount(o, minlength=nb)
        has = cnt > 0
        ground = res["ref_ground"][ok]
        top = ground + res[f"ref_rh{top_level}"][ok]
        top90 = ground + res["ref_rh90"][ok]

        def mean(v: np.ndarray, o: np.ndarray = o, has: np.ndarray = has,
                 cnt: np.ndarray = cnt) -> np.ndarray:
            return np.bincount(o, v, minlength=nb)[has] / cnt[has]

        def stat(v: np.ndarray, o: np.ndarray = o, has: np.ndarray = has) -> np.ndarray:
            if statistic == "mean":
                return mean(v)
            m = np.full(nb, -np.inf)
            np.maximum.at(m, o, v)
            return m[has]

        acc["ref_ground"][has] = mean(ground)
        acc["ref_top"][has] = stat(top)
        acc["ref_top90"][has] = stat(top90)
        acc["ref_rh98"][has] = stat(res["ref_rh98"][ok])
        acc["ref_cover"][has] = mean(res["ref_cover"][ok])
        acc["slope"][has] = mean(res["ref_slope"][ok])
        a = np.radians(res["ref_aspect"][ok])
        fin = np.isfinite(a)
        sin = np.bincount(o[fin], np.sin(a[fin]), minlength=nb)
        cos = np.bincount(o[fin], np.cos(a[fin]), minlength=nb)
        asp = np.degrees(np.arctan2(sin, cos)) % 360.0
        asp[(sin == 0) & (cos == 0)] = np.nan
        acc["aspect"][has] = asp[has]
        tot = np.bincount(owner, minlength=nb)
        sel = tot > 0
        acc["coverage"][sel] = cnt[sel] / tot[sel]
    out = pd.DataFrame({c: blocks[c].to_numpy() for c in ("track", "length", "block")},
                       index=blocks.index)
    out["ref_ground"] = acc["ref_ground"]
    out["ref_top"] = acc["ref_top"]
    out["ref_top90"] = acc["ref_top90"]
    out["ref_hmax"] = acc["ref_top"] - acc["ref_ground"]
    out["ref_h90"] = acc["ref_top90"] - acc["ref_ground"]
    out["ref_rh98"] = acc["ref_rh98"]
    out["ref_cover"] = acc["ref_cover"]
    out["slope"] = acc["slope"]
    out["aspect"] = acc["aspect"]
    out["aspect_class"] = aspect_class(acc["aspect"], acc["slope"], slope_threshold) \
        if nb else []
    out["slope_class"] = slope_class(acc["slope"]) if nb else []
    out["n_footprints"] = n_fp
    out["coverage"] = np.nan_to_num(acc["coverage"], nan=0.0)
    flag = np.full(nb, "ok", dtype=object)
    flag[~np.isfinite(acc["ref_ground"])] = "nodata"
    flag[outside] = "outside"
    out["ref_flag"] = flag
    prog.update(1.0, f"footprint reference for {nb:,} blocks")
    return out


def _evaluate_along(cloud: FootprintCloud, s: np.ndarray, xy: np.ndarray,
                    s_nodes: np.ndarray, xy_nodes: np.ndarray,
                    prog: Progress) -> dict[str, np.ndarray]:
    """Reference values of footprints on a polyline, one straight run per segment."""
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
            res = cloud.evaluate(xy[c0:c1, 0], xy[c0:c1, 1], line=line)
            for c in FOOTPRINT_REFERENCE_COLUMNS:
                out[c][c0:c1] = res[c]
        prog.update(b / n, f"footprint reference {b:,}/{n:,} footprints")
    return out
