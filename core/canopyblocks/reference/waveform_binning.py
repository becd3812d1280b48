"""Surface returns to sampled waveforms: the one binning step every waveform simulator uses.

Returns (one per point or surface element) with a shot (or pixel) index, an elevation
and an energy weight are accumulated into elevation bins below each shot's window top,
then convolved with a Gaussian pulse. Vectorised (``np.add.at``), no loop over returns.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

__all__ = ["bin_returns"]


def bin_returns(shot: np.ndarray, z: np.ndarray, weight: np.ndarray, top: np.ndarray,
                bin_size: float, n_bins: int, pulse_sigma: float, *,
                n_shots: int | None = None, linear: bool = False) -> np.ndarray:
    """Waveforms (shots, n_bins): bin 0 starts at ``top[shot]`` (m) and bins go down.

    Parameters
    ----------
    shot : ndarray of int
        Shot (or pixel) index of each return.
    z : ndarray
        Elevation of each return (m).
    weight : ndarray
        Energy of each return.
    top : ndarray
        Window top (m) per shot.
    bin_size : float
        Bin height (m).
    n_bins : int
        Bins per waveform; returns below the window land in the last bin.
    pulse_sigma : float
        Gaussian pulse sigma in range (m); 0 for none.
    n_shots : int, optional
        Number of shots (default ``len(top)``).
    linear : bool
        Share each return between the two bins whose centres bracket it, in proportion
        to its distance from them (what sampling the pulse-convolved signal at the bin
        centres gives when the pulse is narrower than a bin); the energy's centroid is
        then the return's elevation exactly. Default: the whole return in its bin.
    """
    n = len(top) if n_shots is None else int(n_shots)
    wf = np.zeros((n, int(n_bins)))
    pos = (np.asarray(top)[shot] - z) / bin_size
    if linear:
        # bin k is centred on top - (k + 0.5) bin_size
        c = pos - 0.5
        k0 = np.floor(c).astype(np.int64)
        f = c - k0
        lo = np.clip(k0, 0, n_bins - 1)
        hi = np.clip(k0 + 1, 0, n_bins - 1)
        np.add.at(wf, (shot, lo), weight * (1.0 - f))
        np.add.at(wf, (shot, hi), weight * f)
    else:
        b = np.clip(np.floor(pos).astype(np.int64), 0, n_bins - 1)
        np.add.at(wf, (shot, b), weight)
    if pulse_sigma > 0:
        wf = gaussian_filter1d(wf, pulse_sigma / bin_size, axis=1, mode="constant")
    return wf
