"""Everything about one processed shot that a waveform plot draws (DESIGN 4.3).

:func:`canopyblocks.waveforms.process.shot_details` fills it; the plotting helpers in
:mod:`canopyblocks.outputs.waveform_plot` draw it. Plain arrays and floats only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ShotDetails"]


@dataclass(frozen=True)
class ShotDetails:
    """One shot, processed.

    Attributes
    ----------
    beam : str
    shot_number : int
        Exact (from uint64).
    setting : str
        The L2A setting group used (``"a1"`` .. ``"a6"``).
    elevation : ndarray, shape (n,)
        Elevation (m) of each raw sample, highest first.
    raw : ndarray, shape (n,)
        Raw waveform (counts).
    smoothed_elevation, smoothed : ndarray, shape (k,)
        The smoothed waveform used for the signal extent and RH (counts), on its own
        (possibly sub-sample) elevation grid (m).
    noise_mean, noise_sd : float
        Noise statistics (counts).
    front_threshold, back_threshold : float
        The signal-start and signal-end thresholds (counts).
    top, bottom, ground : float
        Elevations (m) of the signal top (toploc), signal bottom (botloc) and the
        lowest mode (ground); NaN when there is no signal.
    modes : ndarray
        Elevations (m) of all modes, highest first.
    rh : dict of int to float
        RH percentile -> height above ground (m).
    flag : str
        The footprint flag (``"ok"``, ``"no_signal"``, ...).
    gaussians : ndarray, shape (g, 3), optional
        Fitted Gaussians (amplitude counts, centre elevation m, sigma m) when decomposed.
    """

    beam: str
    shot_number: int
    setting: str
    elevation: np.ndarray
    raw: np.ndarray
    smoothed_elevation: np.ndarray
    smoothed: np.ndarray
    noise_mean: float
    noise_sd: float
    front_threshold: float
    back_threshold: float
    top: float
    bottom: float
    ground: float
    modes: np.ndarray
    rh: dict[int, float] = field(default_factory=dict)
    flag: str = "ok"
    gaussians: np.ndarray | None = None
