"""Canopy cover and penetration of many waveforms (DESIGN 4.5, seed 003).

From the energy between signal top and bottom (mode-search smoothing minus the noise
mean, as for RH):

- ground energy ``R_g``: the ground return mirrored about its peak, i.e. twice the
  energy below the ground sub-sample plus the ground sub-sample itself;
- canopy energy ``R_v = total - R_g`` (``R_g`` capped at the total);
- ``cover = R_v / (R_v + rho_ratio * R_g)``, ``rho_ratio = rho_v / rho_g`` (L2B 1.5);
- ``penetration``: share of the energy returned from below ``ground + height`` (m;
  seed 003: 2 m, including everything below the ground).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["cover_and_penetration"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def cover_and_penetration(from_bottom: FloatArray, total: FloatArray, ground: IntArray,
                          subsample_spacing: FloatArray, rho_ratio: float,
                          height: float) -> tuple[FloatArray, FloatArray]:
    """Cover and penetration (fractions 0..1) per shot; NaN where there is no ground.

    Parameters
    ----------
    from_bottom, total : ndarray
        From :func:`canopyblocks.waveforms.rh.signal_energy`.
    ground : ndarray of int64, shape (n,)
        Ground sub-sample (-1 where none).
    subsample_spacing : ndarray, shape (n,)
        Vertical distance between sub-samples (m, positive).
    rho_ratio : float
        ``rho_v / rho_g``.
    height : float
        Penetration height above the ground (m).
    """
    n, k = from_bottom.shape
    cover = np.full(n, np.nan)
    penetration = np.full(n, np.nan)
    ok = (ground >= 0) & (total > 0)
    if not ok.any():
        return cover, penetration
    rows = np.nonzero(ok)[0]
    g = ground[ok]
    tot = total[ok]
    at_ground = from_bottom[rows, g]
    below = from_bottom[rows, np.minimum(g + 1, k - 1)]
    below = np.where(g + 1 <= k - 1, below, 0.0)
    r_g = np.clip(at_ground + below, 0.0, tot)
    r_v = tot - r_g
    denom = r_v + rho_ratio * r_g
    cover[rows] = np.where(denom > 0, r_v / np.where(denom > 0, denom, 1.0), np.nan)
    steps = height / subsample_spacing[ok]
    start = np.clip(np.ceil(g - steps - 1e-9).astype(np.int64), 0, k - 1)
    penetration[rows] = np.clip(from_bottom[rows, start] / tot, 0.0, 1.0)
    return cover, penetration
