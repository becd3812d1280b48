"""Warnings about point clouds that read fine but are not what height validation needs.

A height-normalised cloud (ground at z = 0, e.g. lidR's ``normalize_height`` output) has
heights above ground, not elevations: its DTM is 0 everywhere and a validation against
photon elevations would report the terrain height as bias.  It is detected from the ground
points (ASPRS class 2, or the lowest points when unclassified) and warned about; a tile truly
at sea level may trigger it, so it is a warning, not a refusal.

Heights that cannot be on Earth are refused (:class:`HeightTally`): a tile whose terrain
lies at 100 km (a wrong z offset or scale) or below -500 m (nothing on land is lower:
the Dead Sea shore is at -430 m; ellipsoidal and orthometric heights differ by at most
about 110 m).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import CanopyBlocksWarning, NoUsableDataError

__all__ = ["NormalisedCloudWarning", "looks_normalised", "warn_if_normalised",
           "PLAUSIBLE_HEIGHTS", "HeightTally", "refuse_all_noise"]

PLAUSIBLE_HEIGHTS = (-500.0, 9000.0)
"""Lowest and highest terrain height (m, any vertical datum) a survey on Earth can have:
below the Dead Sea shore (-430 m) less the largest geoid undulation, above Everest
(8849 m)."""

_NOISE = (7, 18)


@dataclass
class HeightTally:
    """Counts of points outside :data:`PLAUSIBLE_HEIGHTS`, accumulated chunk by chunk.

    Ground points (ASPRS class 2) stand for the terrain; when a file has none, every
    point that is not classed noise (7, 18) does.  Noise points are not counted.
    """

    n_ground: int = 0
    n_ground_out: int = 0
    n_other: int = 0
    n_other_out: int = 0
    zmin: float = math.inf
    zmax: float = -math.inf

    def add(self, z: np.ndarray, classification: np.ndarray) -> None:
        """Count one chunk: heights ``z`` (m) and their classes."""
        self._count(np.asarray(z), classification, PLAUSIBLE_HEIGHTS[0],
                    PLAUSIBLE_HEIGHTS[1], 1.0, 0.0)

    def add_scaled(self, zi: np.ndarray, classification: np.ndarray, scale: float,
                   offset: float) -> None:
        """Count one chunk of integer LAS heights (``z = zi * scale + offset``, scale > 0)."""
        lo = math.ceil((PLAUSIBLE_HEIGHTS[0] - offset) / scale)
        hi = math.floor((PLAUSIBLE_HEIGHTS[1] - offset) / scale)
        # the integer test equals the float one; extremes converted only for the message
        self._count(np.asarray(zi), classification, lo, hi, scale, offset)

    def _count(self, v: np.ndarray, classification: np.ndarray, lo: float, hi: float,
               scale: float, offset: float) -> None:
        """Tally values ``v`` (heights ``v * scale + offset``) outside ``[lo, hi]``."""
        c = np.asarray(classification)
        keep = ~np.isin(c, _NOISE)
        out = ((v < lo) | (v > hi)) & keep
        ground = c == 2
        self.n_ground += int(np.count_nonzero(ground))
        self.n_ground_out += int(np.count_nonzero(out & ground))
        self.n_other += int(np.count_nonzero(keep & ~ground))
        self.n_other_out += int(np.count_nonzero(out & ~ground))
        if keep.any():
            vk = v[keep]
            self.zmin = min(self.zmin, float(vk.min()) * scale + offset)
            self.zmax = max(self.zmax, float(vk.max()) * scale + offset)

    def check(self, what: str) -> None:
        """Refuse terrain off the Earth; warn about a minority of points off it.

        Raises
        ------
        NoUsableDataError
            Most of the terrain points (ground, else all non-noise points) lie outside
            :data:`PLAUSIBLE_HEIGHTS`; the message names ``what`` and the heights found.
        """
        lo, hi = PLAUSIBLE_HEIGHTS
        n, n_out = ((self.n_ground, self.n_ground_out) if self.n_ground
                    else (self.n_other, self.n_other_out))
        found = f"z from {self.zmin:.2f} to {self.zmax:.2f} m"
        if n and 2 * n_out > n:
            kind = "ground points" if self.n_ground else "points"
            raise NoUsableDataError(
                f"{what}: {n_out:,} of its {n:,} {kind} lie outside the heights a survey on "
                f"Earth can have ({lo:g} to {hi:g} m; {found}): the heights are not metres "
                "above a datum; check the file's z scale, z offset and vertical unit (e.g. "
                "with pdal info --metadata)")
        total_out = self.n_ground_out + self.n_other_out
        if total_out:
            warnings.warn(
                f"{what}: {total_out:,} point(s) not classed noise lie outside the heights a "
                f"survey on Earth can have ({lo:g} to {hi:g} m; {found}); they are used as "
                "they are: class them noise (7 or 18) if they are errors",
                CanopyBlocksWarning, stacklevel=3)


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


def refuse_all_noise(classification: np.ndarray, what: str,
                     excluded: tuple[int, ...] = _NOISE) -> None:
    """Refuse a cloud whose every point is of an excluded class (noise, 7 and 18).

    A simulation (or a raster) leaves these points out, so nothing would be left; the
    message says so instead of blaming the track's position.

    Raises
    ------
    NoUsableDataError
        Naming ``what`` and the classes.
    """
    c = np.asarray(classification)
    if c.size and bool(np.isin(c, np.asarray(excluded)).all()):
        raise NoUsableDataError(
            f"{what}: every one of the {c.size:,} points read is classed noise (ASPRS class "
            f"{' or '.join(map(str, excluded))}), which is left out: nothing is left to "
            "work on; reclassify the tile (e.g. PDAL filters.outlier only on real outliers)")
