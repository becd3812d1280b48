"""Multiscale curvature classification of terrain points (Evans and Hudak 2007).

The flash-lidar paper filters the preliminary terrain elevations of its waveforms (the
lowest Gaussian of each) with MCC: points that stand above a smoothed surface
interpolated through the points are not terrain (a canopy layer taken for the ground).

MCC, as published: three scale domains (``0.5 scale``, ``scale``, ``1.5 scale``) with
curvature thresholds ``t``, ``t + 0.1``, ``t + 0.2`` (m). In each, repeatedly: a thin-plate
spline through the points still classified as terrain is sampled on a raster of the
domain's resolution, the raster smoothed with a 3 x 3 mean, the smoothed surface
interpolated (bilinear) at the points; a point more than the threshold above it is
removed. A domain ends when an iteration removes no more than its share of the points
(1 %, 0.1 %, 0.01 %). Only points above the surface are ever removed.

No maintained Python implementation of MCC exists in the package index (the original is
the C++ program ``mcc-lidar``; PDAL's ``filters.smrf`` and ``filters.csf`` are different
algorithms), so it is implemented here with SciPy's ``RBFInterpolator`` (thin-plate
spline) and ``uniform_filter`` (the 3 x 3 mean). Points exactly on one line (one waveform
per footprint along a straight track) are handled in one dimension along it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.interpolate import RBFInterpolator, RegularGridInterpolator
from scipy.ndimage import uniform_filter

from ..errors import InputError

__all__ = ["MccParams", "mcc_ground", "terrain_surface"]

_DOMAINS = ((0.5, 0.0, 0.01), (1.0, 0.1, 0.001), (1.5, 0.2, 0.0001))
_MAX_ITER = 50
_NEIGHBOURS = 64   # thin-plate spline from this many nearest points beyond 400 points


@dataclass(frozen=True)
class MccParams:
    """MCC parameters (metres).

    Attributes
    ----------
    scale : float
        Scale parameter: about the spacing of the points (5 m on the flash lidar's 5 m
        grid of waveforms).
    curvature : float
        Curvature threshold of the first scale domain (m); the next two add 0.1 and 0.2.
    """

    scale: float = 5.0
    curvature: float = 0.3

    def __post_init__(self) -> None:
        for name in ("scale", "curvature"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"MCC {name} must be a positive number of metres; got {v!r}")


def _frame(x: np.ndarray, y: np.ndarray, res: float) -> tuple[np.ndarray, bool]:
    """Coordinates in the points' principal axes; 1-D when they lie on a line (their
    spread across it under 1 % of ``res``)."""
    xy = np.column_stack([x - x.mean(), y - y.mean()])
    if len(x) < 3:
        return xy[:, :1], True
    _, vec = np.linalg.eigh(np.cov(xy.T))
    st = xy @ vec[:, ::-1]            # major axis first
    flat = float(np.ptp(st[:, 1])) < 0.01 * res
    return (st[:, :1] if flat else st), flat


def _surface(coords: np.ndarray, z: np.ndarray, keep: np.ndarray, res: float
             ) -> np.ndarray:
    """Thin-plate spline through the kept points, sampled at ``res``, 3 x 3 mean,
    interpolated back at every point."""
    c = coords[keep]
    # several points in one place (a spline cannot pass through two heights): average
    key, inv = np.unique(np.round(c / 1e-3).astype(np.int64), axis=0, return_inverse=True)
    inv = inv.ravel()
    cnt = np.bincount(inv)
    cu = np.column_stack([np.bincount(inv, weights=c[:, d]) / cnt for d in range(c.shape[1])])
    zu = np.bincount(inv, weights=z[keep]) / cnt
    if len(zu) < c.shape[1] + 2:    # too few for a spline: their mean
        return np.full(len(z), float(zu.mean()))
    rbf = RBFInterpolator(cu, zu, kernel="thin_plate_spline", degree=1,
                          neighbors=None if len(zu) <= 400 else _NEIGHBOURS)
    lo = coords.min(axis=0)
    hi = coords.max(axis=0)
    axes = [np.arange(lo[d] - res, hi[d] + 2 * res, res) for d in range(coords.shape[1])]
    mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    grid = rbf(mesh.reshape(-1, coords.shape[1])).reshape(mesh.shape[:-1])
    grid = uniform_filter(grid, size=3, mode="nearest")
    return RegularGridInterpolator(axes, grid, method="linear")(coords)


def mcc_ground(x: npt.ArrayLike, y: npt.ArrayLike, z: npt.ArrayLike,
               params: MccParams | None = None) -> npt.NDArray[np.bool_]:
    """Terrain points by multiscale curvature classification.

    Parameters
    ----------
    x, y : array (n,)
        Positions (m, any projected CRS).
    z : array (n,)
        Elevations (m); NaN are never terrain.
    params : MccParams, optional

    Returns
    -------
    ndarray of bool (n,)
        True for the points kept as terrain.
    """
    p = params or MccParams()
    xa = np.asarray(x, float)
    ya = np.asarray(y, float)
    za = np.asarray(z, float)
    if not (xa.ndim == 1 and xa.shape == ya.shape == za.shape):
        raise InputError(f"x, y and z must be 1-D arrays of one length; got shapes "
                         f"{xa.shape}, {ya.shape}, {za.shape}")
    ok = np.isfinite(xa) & np.isfinite(ya) & np.isfinite(za)
    keep = ok.copy()
    if ok.sum() < 4:
        return keep
    coords, _ = _frame(xa[ok], ya[ok], p.scale)
    zk = za[ok]
    k = np.ones(len(zk), bool)
    for factor, add, share in _DOMAINS:
        res = factor * p.scale
        t = p.curvature + add
        for _ in range(_MAX_ITER):
            if k.sum() < 4:
                break
            surf = _surface(coords, zk, k, res)
            drop = k & (zk - surf > t)
            k &= ~drop
            if drop.sum() <= share * len(zk):
                break
    keep[np.flatnonzero(ok)] = k
    return keep


def terrain_surface(x: npt.ArrayLike, y: npt.ArrayLike, z: npt.ArrayLike,
                    ground: npt.ArrayLike, scale: float = 5.0) -> npt.NDArray[np.float64]:
    """Elevation (m) at every point of the surface through the terrain points: the
    thin-plate spline through ``ground`` points (their own elevations where kept).

    Parameters
    ----------
    x, y, z : array (n,)
        Positions and elevations (m).
    ground : bool array (n,)
        Terrain points (e.g. :func:`mcc_ground`).
    scale : float
        Points within ``scale`` of a line are interpolated along it.
    """
    xa, ya, za = (np.asarray(a, float) for a in (x, y, z))
    g = np.asarray(ground, bool) & np.isfinite(za)
    out = np.where(g, za, np.nan)
    ok = np.isfinite(xa) & np.isfinite(ya)
    if g.sum() == 0 or not ok.any():
        return out
    coords, _ = _frame(xa[ok], ya[ok], scale)
    gk = g[ok]
    if gk.sum() < coords.shape[1] + 2:
        out[ok & ~g] = float(za[g].mean())
        return out
    rbf = RBFInterpolator(coords[gk], za[ok][gk], kernel="thin_plate_spline", degree=1,
                          neighbors=None if gk.sum() <= 400 else _NEIGHBOURS)
    miss = ~gk
    if miss.any():
        vals = out[ok]
        vals[miss] = rbf(coords[miss])
        out[ok] = vals
    return out
