"""Parameters and columns of the footprint-matched airborne reference
(:class:`FootprintReferenceParams`, RH levels, reference flags).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from ..errors import InputError

#: RH percentiles of the reference, per cent.
RH_LEVELS: tuple[int, ...] = (50, 75, 90, 95, 98, 100)

REFERENCE_FLAG_OK = "ok"
REFERENCE_FLAG_OUTSIDE = "outside"
REFERENCE_FLAG_NO_GROUND = "no_ground"

Weighting = Literal["gaussian", "gaussian_density"]
Definition = Literal["points", "waveform"]
#: Definitions of a waveform footprint's reference (``FootprintReferenceParams.definition``).
DEFINITIONS: tuple[str, ...] = ("waveform", "points")

#: Columns of :func:`footprint_reference`, in order.
FOOTPRINT_REFERENCE_COLUMNS: tuple[str, ...] = (
    "ref_ground", *(f"ref_rh{q}" for q in RH_LEVELS),
    *(f"ref_canopy_rh{q}" for q in RH_LEVELS), "ref_top", "ref_cover", "ref_cover_first",
    "ref_slope", "ref_aspect", "ref_n_points", "ref_n_ground", "ref_coverage", "ref_flag",
)


MIN_CUT_RADIUS_M = 0.5
"""Smallest cut radius (m) of a footprint: a smaller circle holds no airborne points at
any survey's density (100 points/m2 leave 0.1 m between points)."""


@dataclass(frozen=True)
class FootprintReferenceParams:
    """How the footprint reference weights and reduces the airborne points.

    Attributes
    ----------
    diameter : float
        Footprint diameter 2 R, metres (R = 1/e^2 radius of the Gaussian beam).
    weighting : {"gaussian", "gaussian_density"}
        Footprint weights alone, or divided by the points in each point's cell.
    cut : float
        Points within ``cut * R`` count (1.0 = the photon simulator's set).
    density_cell : float
        Cell size (m) of the point-density weight.
    min_ground_points : int
        Fewer class-2 points in the cut flag the footprint ``no_ground``.
    cover_threshold : float
        Metres above the ground plane from which a return counts as canopy (cover).
    canopy_floor : float
        Metres above the ground plane from which a return counts for ``ref_canopy_rh*``.
    min_coverage : float
        Footprints whose circle is covered by airborne points less than this (0..1) are
        flagged ``outside``.
    ground_class : int
        ASPRS class of ground points.
    exclude_classes : tuple of int
        Classes dropped before anything (noise: 7, 18).
    definition : {"points", "waveform"}
        What a waveform footprint (GEDI) is compared with. ``waveform`` (the default of
        :meth:`gedi`): the points formed into the waveform the sensor would record (a
        Gaussian beam of sigma ``diameter / 4``, the returns' energy, the pulse) and read
        by the same L2A algorithm -- ground = its lowest mode, RH = where the energy
        accumulated from the bottom of its signal reaches k % above it, cover = its
        canopy energy share (:mod:`~canopyblocks.reference.waveform_reference`, the GEDI
        simulator's truth). ``points``: the weighted points themselves (the module
        notes of :mod:`~canopyblocks.reference.footprint`): ground = the weighted mean of
        the class-2 points, RH = weighted percentiles of all returns above their plane.
        Photon blocks always use ``points``.
    """

    diameter: float = 13.0
    weighting: Weighting = "gaussian"
    cut: float = 1.0
    density_cell: float = 1.5
    min_ground_points: int = 10
    cover_threshold: float = 2.0
    canopy_floor: float = 0.5
    min_coverage: float = 0.9
    ground_class: int = 2
    exclude_classes: tuple[int, ...] = (7, 18)
    definition: Definition = "points"

    def __post_init__(self) -> None:
        from ..arguments import check_fields
        check_fields(self)
        for name in ("diameter", "cut", "density_cell"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a positive number of metres, got {v!r}")
        if self.cut * self.diameter / 2.0 < MIN_CUT_RADIUS_M:
            raise InputError(
                f"a footprint of diameter {self.diameter:g} m cut at {self.cut:g} x R (radius "
                f"{self.cut * self.diameter / 2.0:.3g} m) holds no airborne points: give the "
                f"diameter (--diameter) and cut (--cut) so the radius is at least "
                f"{MIN_CUT_RADIUS_M:g} m (ICESat-2 ~13 m, GEDI ~22 m, cut ~1-1.5)")
        if self.weighting not in ("gaussian", "gaussian_density"):
            raise InputError(f"weighting={self.weighting!r}; use 'gaussian' or "
                             "'gaussian_density'")
        if self.definition not in DEFINITIONS:
            raise InputError(f"definition={self.definition!r}; use 'waveform' (the points "
                             "formed into the sensor's waveform) or 'points' (the weighted "
                             "points)")
        if not (isinstance(self.min_ground_points, int) and self.min_ground_points >= 3):
            raise InputError("min_ground_points must be an integer >= 3 (a plane needs 3), "
                             f"got {self.min_ground_points!r}")
        for name in ("cover_threshold", "canopy_floor"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"{name} must be >= 0 m, got {v!r}")
        if not (0.0 <= self.min_coverage <= 1.0):
            raise InputError(f"min_coverage must be in [0, 1], got {self.min_coverage!r}")

    @property
    def radius(self) -> float:
        """R = diameter / 2, metres."""
        return 0.5 * float(self.diameter)

    @property
    def cut_radius(self) -> float:
        """``cut * R``, metres."""
        return float(self.cut) * self.radius

    @classmethod
    def gedi(cls, **kw: object) -> FootprintReferenceParams:
        """GEDI: sigma 5.5 m (R = 11 m, diameter 22 m), points within 1.5 R (3 sigma),
        density weights (DESIGN 4.9), the waveform-formed definition."""
        args: dict[str, object] = {"diameter": 22.0, "cut": 1.5,
                                   "weighting": "gaussian_density", "definition": "waveform"}
        args.update(kw)
        return cls(**args)  # type: ignore[arg-type]

    @classmethod
    def icesat2(cls, diameter: float = 13.0, **kw: object) -> FootprintReferenceParams:
        """ICESat-2: diameter 13 m (17 m late in the mission), points within R, the
        photon simulator's weights (DESIGN 3.1)."""
        return cls(diameter=diameter, **kw)  # type: ignore[arg-type]
