"""The misfit of a track against a reference raster at candidate horizontal shifts.

For each candidate shift (along ``a``, cross ``c``, metres) the raster is sampled
bilinearly at the shifted target positions (one vectorised lookup for a chunk of
candidates) and the residuals ``r = z - raster(p + shift)`` formed. The vertical shift is
solved in closed form at each candidate as minus the robust location of the residuals
(histogram mode, then a narrow mean shift); the misfit of a target is a truncated
quadratic ``min(((r - m) / scale)^2, T^2)`` (a target off the raster costs ``T^2``).

The costs are kept per *segment* (a stretch of the track, the unit of the held-out test
and of the bootstrap): ``cost[k, j]`` is the weighted sum of the misfits of segment
``j``'s targets at candidate ``k``, each kind of target (ground, top) weighted so that
``cost[k].sum()`` is the weighted mean misfit of that kind over the whole track.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..progress import Progress
from ..reference.raster_sampling import RasterSurface

__all__ = ["Kind", "residuals", "robust_location", "rho", "segment_costs"]

_CHUNK_ELEMENTS = 4_000_000  # candidate x target residuals held at once
_MODE_BINS = 400
_MEAN_SHIFT_ITERATIONS = 8


@dataclass
class Kind:
    """One kind of target (ground or top) against its raster.

    ``x``/``y`` (m) in the raster's CRS, ``z`` (m) in its datum, ``segment`` the
    segment index of each target, ``scale`` (m) of the misfit, ``weight`` of the kind.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    segment: np.ndarray
    surface: RasterSurface
    scale: float
    weight: float = 1.0


def residuals(kind: Kind, a: tuple[float, float], c: tuple[float, float],
              da: np.ndarray, dc: np.ndarray) -> np.ndarray:
    """``z - raster(p + shift)`` (candidates x targets), NaN off the raster."""
    sx = da * a[0] + dc * c[0]
    sy = da * a[1] + dc * c[1]
    vals = kind.surface.bilinear(kind.x[None, :] + sx[:, None], kind.y[None, :] + sy[:, None])
    return kind.z[None, :] - vals


def robust_location(r: np.ndarray, scale: float) -> np.ndarray:
    """Per row of ``r`` (candidates x targets; NaN ignored): mode, then mean shift."""
    k, _ = r.shape
    fin = np.isfinite(r)
    has = fin.any(axis=1)
    rowmin = np.where(has, np.nanmin(np.where(fin, r, np.inf), axis=1), 0.0)
    width = scale
    b = np.floor((r - rowmin[:, None]) / width)
    b = np.where(fin, np.clip(b, 0, _MODE_BINS - 1), 0).astype(np.int64)
    counts = np.bincount((np.arange(k)[:, None] * _MODE_BINS + b)[fin],
                         minlength=k * _MODE_BINS).reshape(k, _MODE_BINS)
    # smooth the histogram by 3 bins so a cluster split over two bins is found
    sm = counts.astype(float)
    sm[:, 1:] += counts[:, :-1]
    sm[:, :-1] += counts[:, 1:]
    m = rowmin + (np.argmax(sm, axis=1) + 0.5) * width
    # mean shift with a narrow Gaussian kernel: converges on the mode, so a one-sided
    # tail (understory photons above the ground, canopy below a DSM maximum) does not
    # pull the location the way a mean would
    bw = 0.5 * scale
    rr = np.where(fin, r, 0.0)
    for _ in range(_MEAN_SHIFT_ITERATIONS):
        u = (rr - m[:, None]) / bw
        w = np.where(fin & (np.abs(u) < 4.0), np.exp(-0.5 * u * u), 0.0)
        sw = w.sum(axis=1)
        m = np.where(sw > 0, (w * rr).sum(axis=1) / np.maximum(sw, 1e-300), m)
    return np.where(has, m, np.nan)


def rho(r: np.ndarray, m: np.ndarray, scale: float, trunc: float) -> np.ndarray:
    """Truncated quadratic per element; NaN residuals cost the truncation."""
    u = (r - m[:, None]) / scale
    with np.errstate(invalid="ignore"):
        out = np.minimum(u * u, trunc * trunc)
    return np.where(np.isfinite(out), out, trunc * trunc)


def segment_costs(kinds: list[Kind], a: tuple[float, float], c: tuple[float, float],
                  da: np.ndarray, dc: np.ndarray, n_segments: int, trunc: float,
                  progress: Progress | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Cost per candidate and segment, and the first kind's location per candidate.

    Parameters
    ----------
    kinds : list of Kind
        The first is the one whose location gives the vertical shift (the ground).
    a, c : (float, float)
        Unit vectors (east, north) of the along- and cross-track directions.
    da, dc : ndarray
        Candidate shifts (m) along and across the track (flattened grid).
    n_segments : int
    trunc : float
        Truncation of the misfit, in scales.

    Returns
    -------
    cost : ndarray (candidates, n_segments)
    location : ndarray (candidates,)
        Robust location (m) of the first kind's residuals (minus the vertical shift).
    """
    n_el = max(sum(len(k.z) for k in kinds), 1)
    chunk = max(1, _CHUNK_ELEMENTS // n_el)
    cost = np.zeros((len(da), n_segments))
    loc = np.full(len(da), np.nan)
    for i0 in range(0, len(da), chunk):
        if progress is not None:
            progress.update(i0 / len(da), "searching offsets")
        sl = slice(i0, i0 + chunk)
        k = len(da[sl])
        for j, kind in enumerate(kinds):
            if len(kind.z) == 0:
                continue
            r = residuals(kind, a, c, da[sl], dc[sl])
            m = robust_location(r, kind.scale)
            per = rho(r, m, kind.scale, trunc) * (kind.weight / len(kind.z))
            idx = np.arange(k)[:, None] * n_segments + kind.segment[None, :]
            cost[sl] += np.bincount(idx.ravel(), per.ravel(),
                                    minlength=k * n_segments).reshape(k, n_segments)
            if j == 0:
                loc[sl] = m
    return cost, loc
