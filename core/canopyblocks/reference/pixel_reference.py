"""Airborne reference for flash-lidar waveforms: what the selected pixels see.

A flash-lidar waveform is the merge of square pixels (``pixel_size`` m, sides along and
across the track). Per waveform (a group of pixels), from the airborne points alone:

``ref_ground``
    Mean, over the group's pixel centres, of the terrain surface: linear interpolation
    (a TIN) of the class-2 points.
``ref_top``
    Highest point (any class but noise, 7 and 18) inside the group's pixels.
``ref_height``
    ``ref_top - ref_ground``.
``ref_height_p99``
    99th percentile of the elevations of those points (nearest rank below) minus
    ``ref_ground``: a top a waveform's energy can show.
``ref_height_chm``
    Canopy height as the flash-lidar paper's reference had it: a 1 m canopy height
    model of maximum elevations (highest point per 1 m cell of the CRS grid minus the
    terrain at the cell's centre; 0 where a cell has no point), read at each pixel
    centre and averaged over the group's pixels: the mean canopy surface the waveform
    sees, where ``ref_height`` is its single highest point.
``ref_points``
    Points inside the group's pixels.

Elevations in the points' vertical datum (m); positions in their CRS (m).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pandas as pd
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import cKDTree

from ..errors import InputError, NoUsableDataError
from ..readers.las import LasPoints

__all__ = ["pixel_reference"]

_NOISE = (7, 18)
_GROUND_REACH = 20.0   # m: class-2 points this close to a pixel make the terrain TIN


def pixel_reference(points: LasPoints, pixel_x: npt.ArrayLike, pixel_y: npt.ArrayLike,
                    group: npt.ArrayLike, n_groups: int, pixel_size: float,
                    along: tuple[float, float]) -> pd.DataFrame:
    """Reference ground, top and height per group of pixels (module docstring).

    Parameters
    ----------
    points : LasPoints
        Airborne points (class 2 = ground), metric CRS.
    pixel_x, pixel_y : array (p,)
        Pixel centres (m, the points' CRS).
    group : int array (p,)
        Waveform of each pixel, 0..n_groups-1.
    n_groups : int
    pixel_size : float
        Pixel side (m).
    along : (float, float)
        Unit vector of the track (the pixels' sides are along and across it).

    Returns
    -------
    DataFrame
        ``n_groups`` rows: ``ref_ground``, ``ref_top``, ``ref_height``, ``ref_points``.
    """
    px = np.asarray(pixel_x, float)
    py = np.asarray(pixel_y, float)
    g = np.asarray(group, np.int64)
    if not (px.shape == py.shape == g.shape and px.ndim == 1):
        raise InputError("pixel_x, pixel_y and group must be 1-D arrays of one length")
    if not pixel_size > 0:
        raise InputError(f"pixel_size must be > 0 m; got {pixel_size!r}")
    ax, ay = along
    x = np.asarray(points.x, float)
    y = np.asarray(points.y, float)
    z = np.asarray(points.z, float)
    cls = np.asarray(points.classification)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & ~np.isin(cls, _NOISE)
    # points and pixel centres in the track frame, where a pixel is a square; only the
    # points in the pixels' box there (plus the terrain margin) are looked at
    pu, pv = px * ax + py * ay, -px * ay + py * ax
    margin = _GROUND_REACH + pixel_size
    au, av = x * ax + y * ay, -x * ay + y * ax
    if px.size:
        ok &= (au >= pu.min() - margin) & (au <= pu.max() + margin)
        ok &= (av >= pv.min() - margin) & (av <= pv.max() + margin)
    tree = cKDTree(np.column_stack([pu, pv]))
    xu, xv = au[ok], av[ok]
    dist, nearest = tree.query(np.column_stack([xu, xv]), p=np.inf,
                               distance_upper_bound=pixel_size / 2)
    hit = np.isfinite(dist)
    pix = nearest[hit]
    zin = z[ok][hit]
    top = np.full(n_groups, -np.inf)
    np.maximum.at(top, g[pix], zin)
    count = np.bincount(g[pix], minlength=n_groups)
    # terrain: a TIN of the class-2 points near the pixels
    gd = ok & (cls == 2)
    gx, gy, gz = x[gd], y[gd], z[gd]
    near, _ = tree.query(np.column_stack([au[gd], av[gd]]),
                         p=np.inf, distance_upper_bound=_GROUND_REACH)
    keep = np.isfinite(near)
    if keep.sum() < 3:
        raise NoUsableDataError("fewer than 3 ground (class 2) points near the flash-lidar "
                                "pixels: no reference terrain; classify the tiles' ground")
    tin = LinearNDInterpolator(np.column_stack([gx[keep], gy[keep]]), gz[keep])
    zg = tin(px, py)
    fin = np.isfinite(zg)
    s = np.bincount(g[fin], weights=zg[fin], minlength=n_groups)
    c = np.bincount(g[fin], minlength=n_groups)
    with np.errstate(invalid="ignore", divide="ignore"):
        ground = np.where(c > 0, s / c, np.nan)
    top = np.where(np.isfinite(top), top, np.nan)
    chm = _chm_at_pixels(x[ok], y[ok], z[ok], px, py, tin)
    fc = np.isfinite(chm)
    with np.errstate(invalid="ignore", divide="ignore"):
        chm_mean = (np.bincount(g[fc], weights=chm[fc], minlength=n_groups)
                    / np.bincount(g[fc], minlength=n_groups))
    # 99th percentile per group: sort by (group, z), take the rank floor(0.99 (count - 1))
    order = np.lexsort((zin, g[pix]))
    zs = zin[order]
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    rank = start + np.floor(0.99 * np.maximum(count - 1, 0)).astype(np.int64)
    p99 = np.where(count > 0, zs[np.minimum(rank, max(zs.size - 1, 0))] if zs.size
                   else np.nan, np.nan)
    return pd.DataFrame({"ref_ground": ground, "ref_top": top, "ref_height": top - ground,
                         "ref_height_p99": p99 - ground, "ref_height_chm": chm_mean,
                         "ref_points": count})


def _chm_at_pixels(x: np.ndarray, y: np.ndarray, z: np.ndarray, px: np.ndarray,
                   py: np.ndarray, tin: LinearNDInterpolator) -> np.ndarray:
    """The 1 m maximum-elevation canopy height model (m) at the pixel centres: the
    highest point of the 1 m cell holding the centre minus the terrain (``tin``) at the
    cell's centre; 0 for a cell without points (open ground); NaN off the terrain."""
    ix, iy = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    qx, qy = np.floor(px).astype(np.int64), np.floor(py).astype(np.int64)
    x0 = min(int(ix.min()), int(qx.min())) if ix.size else int(qx.min())
    y0 = min(int(iy.min()), int(qy.min())) if iy.size else int(qy.min())
    span = max(int(iy.max()) if iy.size else 0, int(qy.max())) - y0 + 1
    key = (ix - x0) * span + (iy - y0)
    cells, inv = np.unique(key, return_inverse=True)
    zmax = np.full(cells.size, -np.inf)
    np.maximum.at(zmax, inv.ravel(), z)
    qkey = (qx - x0) * span + (qy - y0)
    pos = np.clip(np.searchsorted(cells, qkey), 0, max(cells.size - 1, 0))
    hit = (cells[pos] == qkey) if cells.size else np.zeros(qkey.size, bool)
    terrain = tin(qx + 0.5, qy + 0.5)
    return np.where(hit, np.maximum(zmax[pos] - terrain, 0.0), 0.0) + 0.0 * terrain
