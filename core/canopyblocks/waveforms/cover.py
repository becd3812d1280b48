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
                          bottom: IntArray, span: IntArray,
                          subsample_spacing: FloatArray, rho_ratio: float,
                          height: float) -> tuple[FloatArray, FloatArray]:
    """Cover and penetration (fractions 0..1) per shot; NaN where there is no ground.

    Parameters
    ----------
    from_bottom, total : ndarray
        From :func:`canopyblocks.waveforms.rh.signal_energy` (bottom first: column
        ``j`` is sub-sample ``bottom + 1 - j``).
    ground : ndarray of int64, shape (n,)
        Ground sub-sample of the whole waveform (-1 where none).
    bottom, span : ndarray of int64, shape (n,)
        Signal bottom (sub-sample of the whole waveform) and ``bottom - top``.
    subsample_spacing : ndarray, shape (n,)
        Vertical distance between sub-samples (m, positive).
    rho_ratio : float
        ``rho_v / rho_g``.
    height : float
        Penetration height above the ground (m).
    """
    n, w = from_bottom.shape
    cover = np.full(n, np.nan)
    penetration = np.full(n, np.nan)
    ok = (ground >= 0) & (total > 0)
    if not ok.any():
        return cover, penetration
    rows = np.nonzero(ok)[0]
    g = ground[ok]
    b = bottom[ok]
    tot = total[ok]
    col = b + 1 - g                      # the ground's column; the one below is col - 1
    at_ground = from_bottom[rows, col]
    below = from_bottom[rows, col - 1]
    r_g = np.clip(at_ground + below, 0.0, tot)
    r_v = tot - r_g
    denom = r_v + rho_ratio * r_g
    cover[rows] = np.where(denom > 0, r_v / np.where(denom > 0, denom, 1.0), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        steps = height / subsample_spacing[ok]
        start = np.ceil(g - steps - 1e-9)
    top = b - span[ok]
    above_top = ~(start >= top)           # everything from the top down: the total
    start_col = np.where(above_top, 1, b + 1 - np.where(above_top, b, start).astype(np.int64))
    at_start = np.where(above_top, tot, from_bottom[rows, start_col])
    penetration[rows] = np.clip(at_start / tot, 0.0, 1.0)
    return cover, penetration
