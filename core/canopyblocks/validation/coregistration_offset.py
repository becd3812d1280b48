"""A co-registration offset (:class:`CoregOffset`): the shift that aligns a track
with the reference, and how well it is known.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .coregistration_checks import Coverage


@dataclass(frozen=True)
class CoregOffset:
    """The offset found for one track (or for all tracks together).

    All distances in metres; the shift to ADD to reported positions and heights.
    ``*_sd`` are standard deviations: the larger of the bootstrap over stretches of track
    and the linearised one, combined with the DTM's resolution floor (cell / sqrt(12)).
    ``rmse_before`` and ``rmse_after`` are the RMSE of the ground residuals (target minus
    DTM) of the targets inside the raster, before and after applying the whole shift
    (the same targets). ``determined`` False: the offset is
    not significant on held-out stretches (or not constrained); ``reason`` says why, and
    it must not be applied. ``detectable_*``: the minimum detectable offset (m) along and
    across the track over this terrain (three standard deviations);
    ``heldout_*``: the held-out test (signed-rank score, its critical value, held-out ground
    RMSE at no shift and at the offsets fitted without them); ``coverage``: blocks and
    stretches of the track on valid raster cells.
    """

    name: str
    east: float
    north: float
    along_track: float
    cross_track: float
    vertical: float
    east_sd: float
    north_sd: float
    along_track_sd: float
    cross_track_sd: float
    vertical_sd: float
    rmse_before: float
    rmse_after: float
    bias_before: float
    bias_after: float
    n_ground: int
    n_top: int
    used_top: bool
    determined: bool
    reason: str
    crs_wkt: str
    along_grid: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    cross_grid: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    cost: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 0)))
    direction: tuple[float, float] = (0.0, 1.0)
    detectable_along: float = float("nan")
    detectable_cross: float = float("nan")
    coverage: Coverage | None = None
    heldout_t: float = float("nan")
    heldout_critical: float = float("nan")
    heldout_rmse_before: float = float("nan")
    heldout_rmse_after: float = float("nan")
    n_segments: int = 0

    @property
    def status(self) -> str:
        """``"ok"`` or ``"undetermined"``."""
        return "ok" if self.determined else "undetermined"

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary (no cost surface)."""
        def num(v: float) -> float | None:
            return None if not np.isfinite(v) else round(float(v), 4)

        return {
            "east": num(self.east), "north": num(self.north),
            "along_track": num(self.along_track), "cross_track": num(self.cross_track),
            "vertical": num(self.vertical),
            "uncertainty": {"east": num(self.east_sd), "north": num(self.north_sd),
                            "along_track": num(self.along_track_sd),
                            "cross_track": num(self.cross_track_sd),
                            "vertical": num(self.vertical_sd)},
            "rmse_before": num(self.rmse_before), "rmse_after": num(self.rmse_after),
            "bias_before": num(self.bias_before), "bias_after": num(self.bias_after),
            "n_ground": int(self.n_ground), "n_top": int(self.n_top),
            "used_top": bool(self.used_top), "determined": bool(self.determined),
            "status": self.status, "reason": self.reason,
            "minimum_detectable": {"along_track": num(self.detectable_along),
                                   "cross_track": num(self.detectable_cross)},
            "held_out": {"score": num(self.heldout_t),
                         "critical_score": num(self.heldout_critical),
                         "rmse_before": num(self.heldout_rmse_before),
                         "rmse_after": num(self.heldout_rmse_after),
                         "stretches": int(self.n_segments)},
            "coverage": None if self.coverage is None else {
                "blocks": self.coverage.blocks,
                "blocks_on_rasters": self.coverage.blocks_covered,
                "share": round(self.coverage.share, 4)},
            "along_track_direction": [round(self.direction[0], 6), round(self.direction[1], 6)],
        }
