"""``signal_conf_ph`` for simulated photons, from the photons alone (DESIGN.md 3.3).

ATL03 grades each photon's signal confidence from the photon cloud (a histogram
against the measured background), never from any truth. The simulator does the same
with the project's density filter (:mod:`canopyblocks.blocks.density_filter`): each
photon's neighbours in a box of +-10 m along the track and +-1.5 m in height are
compared with the Poisson quantiles of what the background, estimated from the photons
of each 200 m segment, would put there. ATL03's land codes are used: 4 (high) above the
0.999 quantile, 3 (medium) above the 0.99, 2 (low) above the 0.9, 0 (noise) otherwise.
Where a segment's photons span less than 60 m of height (no measurable background, e.g.
a simulation without noise) every photon is graded 4.
"""

from __future__ import annotations

import numpy as np

from ..blocks.density_filter import DensityParams, density_filter

__all__ = ["signal_confidence", "CONFIDENCE_QUANTILES"]

#: ATL03 land confidence code -> Poisson quantile of the background count it must beat.
CONFIDENCE_QUANTILES: tuple[tuple[int, float], ...] = ((2, 0.9), (3, 0.99), (4, 0.999))


def signal_confidence(s: np.ndarray, h: np.ndarray) -> np.ndarray:
    """ATL03-style land ``signal_conf_ph`` (0, 2, 3, 4) of photons from their positions.

    Parameters
    ----------
    s, h : ndarray
        Along-track distance and height of the photons, metres, any order.

    Returns
    -------
    ndarray int8
        One code per photon, in the input order.
    """
    s = np.asarray(s, dtype=np.float64)
    h = np.asarray(h, dtype=np.float64)
    conf = np.zeros(s.size, np.int8)
    if s.size == 0:
        return conf
    for code, q in CONFIDENCE_QUANTILES:  # thresholds rise: each level refines the last
        keep = density_filter(s, h, DensityParams(quantile=q)).keep
        conf[keep] = code
    return conf
