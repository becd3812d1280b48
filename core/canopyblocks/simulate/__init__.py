"""Simulate photon-counting lidar (ICESat-2, MABEL) from airborne lidar (seed 002).

Footprint centres every ``shot_spacing`` along a track over an airborne point cloud;
each footprint's points, weighted ``exp(-2 r^2 / R^2)`` and broadened by the PSF, form
the photon height PDF; photons per shot are Poisson; truth (ground, top, RH metrics,
canopy cover) is kept per footprint and per photon.  See DESIGN.md section 3 and the
module docstrings (``truth.py`` for the truth definitions).

Typical use::

    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons

    pts = read_las("tile.laz")
    track = line_through(pts.bounds, azimuth=0.0, inset=6.5)
    sim = simulate_photons(pts, track, SimParams(diameter=13, photon_rate="boreal"), seed=1)
    photons = sim.photon_track()          # PhotonTrack for the block engine
"""

from __future__ import annotations

from ..blocks.step_classify import classify_seed002, seed002_labels
from ..reference.footprint_index import CloudIndex, FootprintPairs, footprint_weights
from .analysis import (
    COVER_COLUMNS,
    TABLE_COLUMNS,
    Seed002Result,
    cover_table,
    photon_residuals,
    residual_stats,
    seed002_experiment,
)
from .engine import (
    PHOTON_TRUTH_COLUMNS,
    TRUTH_COLUMNS,
    Simulation,
    cloud_index,
    simulate_photons,
)
from .params import INSTRUMENTS, POISSON_MEANS, SimParams, TruthParams
from .tracks import SimTrack, line_through, polyline_from_points, shots_along
from .truth import RH_LEVELS, footprint_truth

__all__ = [
    "SimParams",
    "TruthParams",
    "POISSON_MEANS",
    "INSTRUMENTS",
    "SimTrack",
    "line_through",
    "polyline_from_points",
    "shots_along",
    "CloudIndex",
    "cloud_index",
    "FootprintPairs",
    "footprint_weights",
    "footprint_truth",
    "RH_LEVELS",
    "Simulation",
    "simulate_photons",
    "TRUTH_COLUMNS",
    "PHOTON_TRUTH_COLUMNS",
    "classify_seed002",
    "seed002_labels",
    "photon_residuals",
    "residual_stats",
    "cover_table",
    "seed002_experiment",
    "Seed002Result",
    "TABLE_COLUMNS",
    "COVER_COLUMNS",
    "write_simulation_atl03",
    "write_simulation_mabel",
    "write_photon_table",
    "plot_cover_residuals",
]


def __getattr__(name: str) -> object:
    # writers and plots import h5py/matplotlib helpers: load them on first use
    if name in ("write_simulation_atl03", "write_simulation_mabel", "write_photon_table"):
        from . import writers

        return getattr(writers, name)
    if name == "plot_cover_residuals":
        from .plots import plot_cover_residuals

        return plot_cover_residuals
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
