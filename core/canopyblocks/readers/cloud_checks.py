"""Warnings about point clouds that read fine but are not what height validation needs.

A height-normalised cloud (ground at z = 0, e.g. lidR's ``normalize_height`` output) has
heights above ground, not elevations: its DTM is 0 everywhere and a validation against
photon elevations would report the terrain height as bias.  It is detected from the ground
points (ASPRS class 2, or the lowest points when unclassified) and warned about; a tile truly
at sea level may trigger it, so it is a warning, not a refusal.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import CanopyBlocksWarning

__all__ = ["NormalisedCloudWarning", "looks_normalised", "warn_if_normalised"]


class NormalisedCloudWarning(CanopyBlocksWarning):
    """The cloud's ground lies at z = 0: heights above ground, not elevations."""


def looks_normalised(ground_z: np.ndarray) -> tuple[bool, float, float]:
    """Whether ground heights (m) sit at 0: (flag, median, 5-95 % spread)."""
    g = np.asarray(ground_z, float)
    g = g[np.isfinite(g)]
    if g.size < 10:
        return False, float("nan"), float("nan")
    lo, med, hi = np.percentile(g, [5.0, 50.0, 95.0])
    return bool(abs(med) < 0.5 and hi - lo < 1.0 and lo > -1.0), float(med), float(hi - lo)


def warn_if_normalised(z: np.ndarray, classification: np.ndarray | None, what: str) -> bool:
    """Warn (:class:`NormalisedCloudWarning`) when the ground of ``z`` lies at 0 m.

    Parameters
    ----------
    z : ndarray
        Point heights, metres.
    classification : ndarray or None
        ASPRS classes; class 2 is ground.  Without ground points the lowest 5 % are used.
    what : str
        Names the data in the message (e.g. the tile's path).
    """
    z = np.asarray(z, float)
    if classification is not None and np.count_nonzero(np.asarray(classification) == 2) >= 10:
        ground = z[np.asarray(classification) == 2]
    elif z.size >= 10:
        ground = np.sort(z[np.isfinite(z)])[: max(10, z.size // 20)]
    else:
        return False
    flag, med, spread = looks_normalised(ground)
    if flag:
        warnings.warn(
            f"{what} looks height-normalised: its ground lies at z = 0 (median {med:.2f} m, "
            f"5-95 % spread {spread:.2f} m), so its heights are above ground, not elevations; "
            "use the tiles before normalisation (a DTM of zeros makes every ground residual "
            "equal to the terrain height). If the survey is really at sea level, ignore this",
            NormalisedCloudWarning, stacklevel=3)
    return flag
