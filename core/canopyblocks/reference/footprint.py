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
Photon blocks: :mod:`~canopyblocks.reference.footprint_blocks`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import InputError, NoUsableDataError
from ..progress import Progress, as_progress
from ..readers.las import LasPoints
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
    "ReturnPairs",
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
                 line: tuple[float, float, float, float] | None = None,
                 pairs_out: list[ReturnPairs] | None = None) -> dict[str, np.ndarray]:
        """Reference values of the footprints ``(sx, sy)`` (one compact chunk).

        ``pairs_out``: a list that also gets this chunk's returns of the footprints with a
        ground plane (:class:`ReturnPairs`), for statistics pooled over several footprints.
        """
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
        if pairs_out is not None:
            with np.errstate(invalid="ignore", divide="ignore"):
                pairs_out.append(ReturnPairs(shot, hag, w / wsum[shot]))
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


@dataclass(frozen=True)
class ReturnPairs:
    """The (footprint, return) pairs of a chunk of footprints, sorted by (footprint,
    height): ``shot`` the footprint (index in the chunk), ``height`` the return's height
    above its footprint's ground plane (m), ``weight`` its footprint weight over the
    footprint's total (each footprint's weights sum to 1, as each shot's photons are
    drawn from its own normalised profile)."""

    shot: np.ndarray
    height: np.ndarray
    weight: np.ndarray


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




def __getattr__(name: str) -> object:
    """Names that moved to another module keep working here (see canopyblocks._aliases)."""
    from .._aliases import moved_name

    return moved_name(__name__, name)
