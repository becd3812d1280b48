"""Draw photons from footprint PDFs (seed 002 section 2.2), vectorised.

Each footprint's PDF is the mixture ``sum_j w_j N(z_j, PSF) / sum_j w_j``; a photon is
drawn exactly by picking a source point with probability proportional to its weight
(inverse CDF: one uniform number per photon, looked up in the footprint's cumulative
weights) and adding a Gaussian of sigma PSF to its height (no gridding).  The engine
draws all random numbers of a simulation up front, in photon order, so the photons of
a seed do not depend on how the shots are split into chunks.
"""

from __future__ import annotations

import numpy as np

from ..reference.footprint_index import FootprintPairs

__all__ = ["pick_sources", "draw_noise"]


def pick_sources(pairs: FootprintPairs, shot: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Source pair of photons of local shots ``shot`` from uniforms ``u`` in [0, 1).

    Pair ``j`` of a shot is picked when ``u`` falls in its share
    ``[W_{j-1}, W_j) / W`` of the shot's cumulative weight, i.e. with probability
    ``w_j / sum w``.

    Returns
    -------
    ndarray int64
        Index into ``pairs`` of each photon's source point; -1 for a shot without points.
    """
    shot = np.asarray(shot, dtype=np.int64)
    if shot.size == 0:
        return np.empty(0, np.int64)
    if pairs.weight.size == 0:
        return np.full(shot.size, -1, np.int64)
    start, end = pairs.indptr[shot], pairs.indptr[shot + 1]
    ok = end > start
    cw = pairs.prefix(3 * shot.size)
    before, last = cw.at(np.concatenate([start - 1, end - 1])).reshape(2, -1)
    idx = cw.search(before + u * (last - before), right=True)
    idx = np.minimum(np.maximum(idx, start), end - 1)
    return np.where(ok, idx, -1)


def draw_noise(lo: np.ndarray, hi: np.ndarray, rate: float, n_real: int,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniform background photons in ``[lo[k], hi[k]]`` at ``rate`` per shot per metre.

    Shots with a non-finite window get none.

    Returns
    -------
    real, shot : ndarray int64
    h : ndarray float64
        Heights, metres.
    """
    n = lo.size
    width = np.where(np.isfinite(lo) & np.isfinite(hi), hi - lo, 0.0)
    width = np.maximum(width, 0.0)
    counts = rng.poisson(np.broadcast_to(rate * width, (n_real, n)))
    flat = counts.ravel()
    real = np.repeat(np.repeat(np.arange(n_real, dtype=np.int64), n), flat)
    shot = np.repeat(np.tile(np.arange(n, dtype=np.int64), n_real), flat)
    h = lo[shot] + width[shot] * rng.random(shot.size)
    return real, shot, h
