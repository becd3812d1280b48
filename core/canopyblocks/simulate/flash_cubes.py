"""Simulated ESFL flash-array data cubes over airborne lidar (seed 003, DESIGN 4.7).

No real ESFL data are public, so cubes are made from an airborne cloud the way seed 003
describes the instrument: footprints of 8.4 m (Gaussian illumination, 1/e^2 diameter)
imaged on 12 x 12 pixels of 0.7 m, 0.75 m range bins, range gates of 41 bins merged to
span the scene, a 4 ns pulse. A pixel's waveform is the illumination-weighted height
histogram of the points in its ground cell (each pixel's points share its illuminated
energy, so point density does not count), convolved with the pulse; every pixel and bin
gets sensor noise, illuminated or not, so marginal pixels have low signal to noise.

Truth per footprint (within the 1/e^2 footprint): the illumination-weighted mean
elevation of the ground points (class 2) and the highest point.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from ..errors import InputError, NoUsableDataError
from ..readers.las import LasPoints
from ..reference.footprint_index import CloudIndex
from ..reference.footprint_returns import footprint_index
from ..reference.waveform_binning import bin_returns
from .tracks import SimTrack, shots_along

__all__ = ["FlashSimParams", "FlashSimulation", "simulate_flash_cubes", "threshold_study"]

log = logging.getLogger(__name__)

_C = 299_792_458.0


@dataclass(frozen=True)
class FlashSimParams:
    """ESFL-like instrument (metres unless stated; seed 003 values by default).

    Attributes
    ----------
    footprint : float
        1/e^2 diameter of the illumination (8.4 m).
    pixels : int
        Pixels per side of a footprint's subset (12).
    pixel_size : float
        Ground size of a pixel (0.7 m).
    bin_size : float
        Range bin (0.75 m).
    gate_bins : int
        Bins per range gate (41); gates are merged to span each footprint.
    pulse_ns : float
        Pulse duration (FWHM, ns).
    spacing : float
        Footprint spacing along the track (8.4 m: footprints side by side; the paper's
        pulses were 1.7 m apart, 51.4 m/s at 30 Hz).
    noise_sd : float
        Sensor noise sd per pixel and bin, as a share of the mean brightest-pixel peak.
    gate_cycle : bool
        False: every footprint records all the range gates its scene needs (as if the
        gates were taken in one place). True: as the paper flew, successive pulses record
        one gate each in turn (pulse i gate ``i mod G``, G the most gates any footprint of
        the line needs, stacked down from each footprint's highest point), so a cube holds
        ``gate_bins`` bins and waveforms are whole only once the grid merges pulses.
    """

    footprint: float = 8.4
    pixels: int = 12
    pixel_size: float = 0.7
    bin_size: float = 0.75
    gate_bins: int = 41
    pulse_ns: float = 4.0
    spacing: float = 8.4
    noise_sd: float = 0.05
    gate_cycle: bool = False

    def __post_init__(self) -> None:
        for name in ("footprint", "pixel_size", "bin_size", "pulse_ns", "spacing"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a positive number, got {v!r}")
        if not (isinstance(self.pixels, int) and 2 <= self.pixels <= 64):
            raise InputError(f"pixels must be an integer 2..64, got {self.pixels!r}")
        if not (isinstance(self.gate_bins, int) and self.gate_bins >= 4):
            raise InputError(f"gate_bins must be an integer >= 4, got {self.gate_bins!r}")
        if not (math.isfinite(self.noise_sd) and self.noise_sd >= 0):
            raise InputError(f"noise_sd must be >= 0, got {self.noise_sd!r}")

    @property
    def pulse_sigma(self) -> float:
        """Pulse sigma in range (m)."""
        return self.pulse_ns * 1e-9 * _C / 2 / 2.3548


@dataclass(frozen=True)
class FlashSimulation:
    """Cubes (footprints, rows, cols, bins): bin k is centred on ``top - k * bin_size``
    (m, per footprint); the footprint centres (m, the cloud's CRS), the unit vector
    ``along`` of the track (x, y) and the truth table."""

    cubes: np.ndarray
    top: np.ndarray
    bin_size: float
    x: np.ndarray
    y: np.ndarray
    truth: pd.DataFrame
    noise_sd: float
    along: tuple[float, float] = (1.0, 0.0)
    pixel_size: float = 0.7

    def as_cubes(self) -> Any:
        """The cubes with their geometry, as the flash-lidar chain reads them."""
        from ..waveforms.esfl import EsflCubes

        return EsflCubes(self.cubes, np.asarray(self.top, float), self.bin_size,
                         np.asarray(self.x, float), np.asarray(self.y, float), self.along,
                         self.pixel_size)


def simulate_flash_cubes(points: LasPoints, track: SimTrack,
                         params: FlashSimParams | None = None, *, seed: int = 0,
                         max_footprints: int = 5000) -> FlashSimulation:
    """Simulate one cube per footprint along ``track`` (deterministic for ``seed``)."""
    p = params or FlashSimParams()
    sx, sy, _ = shots_along(track, p.spacing)
    if sx.size > max_footprints:
        raise InputError(f"{sx.size} footprints exceed max_footprints={max_footprints}; use a "
                         "shorter track or a larger spacing")
    index, ids = footprint_index(points)   # noise points (7, 18) are no surface
    half = p.pixels * p.pixel_size / 2
    pairs = index.pairs(sx, sy, half * math.sqrt(2.0))
    shot, pt = pairs.shot, pairs.point
    if pt.size == 0:
        raise NoUsableDataError("no airborne point lies under the simulated footprints; "
                                "check the track against the tiles")
    # track frame: u along, v across
    v_xy = np.asarray(track.vertices)
    dx, dy = v_xy[-1] - v_xy[0]
    nrm = math.hypot(dx, dy)
    ux, uy = dx / nrm, dy / nrm
    px = index.x[pt] - sx[shot]
    py = index.y[pt] - sy[shot]
    u = px * ux + py * uy
    v = -px * uy + py * ux
    col = np.floor((u + half) / p.pixel_size).astype(np.int64)
    row = np.floor((v + half) / p.pixel_size).astype(np.int64)
    inside = (col >= 0) & (col < p.pixels) & (row >= 0) & (row < p.pixels)
    shot, pt, col, row = shot[inside], pt[inside], col[inside], row[inside]
    z = index.z[pt]
    n = sx.size
    # illumination at the pixel centre, shared by the pixel's points
    cu = (col + 0.5) * p.pixel_size - half
    cv = (row + 0.5) * p.pixel_size - half
    radius = p.footprint / 2
    illum = np.exp(-2.0 * (cu * cu + cv * cv) / radius ** 2)
    pix = (shot * p.pixels + row) * p.pixels + col
    per_pixel = np.bincount(pix, minlength=n * p.pixels * p.pixels)
    w = illum / per_pixel[pix]
    # vertical window per footprint: whole range gates from above its highest point
    zmax = np.full(n, -np.inf)
    zmin = np.full(n, np.inf)
    np.maximum.at(zmax, shot, z)
    np.minimum.at(zmin, shot, z)
    has = np.isfinite(zmax)
    pad = 3 * p.pulse_sigma + 2 * p.bin_size
    top = np.where(has, zmax + pad, np.nan)
    extent = np.where(has, zmax - zmin + 2 * pad, 0.0)
    gates = np.maximum(1, np.ceil(extent / (p.gate_bins * p.bin_size))).astype(np.int64)
    m = int(gates.max()) * p.gate_bins
    # bins labelled by their centres: bin k spans top - k * bin_size +- bin_size / 2
    pix_top = np.repeat(np.nan_to_num(top) + 0.5 * p.bin_size, p.pixels * p.pixels)
    cubes = bin_returns(pix, z, w, pix_top, p.bin_size, m, p.pulse_sigma, linear=True
                        ).reshape(n, p.pixels, p.pixels, m)
    peak = cubes.reshape(n, -1).max(axis=1)
    scale = float(np.mean(peak[peak > 0])) if (peak > 0).any() else 1.0
    cubes /= scale
    if p.gate_cycle:
        cubes, top = _cycle_gates(cubes, top, int(gates.max()), p)
    rng = np.random.default_rng(seed)
    if p.noise_sd > 0:
        cubes += rng.normal(0.0, p.noise_sd, cubes.shape)
    truth = _truth(index, points, ids, sx, sy, radius)
    return FlashSimulation(cubes, top, p.bin_size, sx, sy, truth, p.noise_sd,
                           (float(ux), float(uy)), p.pixel_size)


def _cycle_gates(cubes: np.ndarray, top: np.ndarray, n_gates: int, p: FlashSimParams
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Pulse i keeps gate ``i mod n_gates`` of its stack (bins ``g * gate_bins`` on):
    cubes (n, rows, cols, gate_bins) and the centre of their bin 0 (m)."""
    n, rows, cols, m = cubes.shape
    g = np.arange(n) % n_gates
    j = g[:, None] * p.gate_bins + np.arange(p.gate_bins)[None, :]
    sel = np.take_along_axis(cubes.reshape(n, rows * cols, m), j[:, None, :], axis=2)
    return (np.ascontiguousarray(sel.reshape(n, rows, cols, p.gate_bins)),
            top - g * p.gate_bins * p.bin_size)


def _truth(index: CloudIndex, points: LasPoints, ids: np.ndarray, sx: np.ndarray,
           sy: np.ndarray, radius: float) -> pd.DataFrame:
    pairs = index.pairs(sx, sy, radius)
    shot, pt = pairs.shot, pairs.point
    r2 = (index.x[pt] - sx[shot]) ** 2 + (index.y[pt] - sy[shot]) ** 2
    w = np.exp(-2.0 * r2 / radius ** 2)
    ground = points.classification[ids[pt]] == 2
    n = sx.size
    wg = np.bincount(shot[ground], weights=w[ground], minlength=n)
    zg = np.bincount(shot[ground], weights=(w * index.z[pt])[ground], minlength=n)
    top = np.full(n, -np.inf)
    np.maximum.at(top, shot, index.z[pt])
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.where(wg > 0, zg / wg, np.nan)
    top = np.where(np.isfinite(top), top, np.nan)
    return pd.DataFrame({"x": sx, "y": sy, "truth_ground": g, "truth_top": top,
                         "truth_height": top - g})


def threshold_study(sim: FlashSimulation | list[FlashSimulation], points: LasPoints,
                    fractions: tuple[float, ...] = (0.1, 0.25, 0.5, 0.6, 0.7, 0.8, 0.9),
                    params: Any = None) -> pd.DataFrame:
    """The flash-lidar paper's experiment (its table II): accuracy of terrain and canopy
    height against the energy fraction that defines the footprint's pixels, through the
    paper's chain (:mod:`canopyblocks.waveforms.esfl`), against the airborne ``points``
    under the pixels each waveform merges. One row per fraction (see
    :func:`canopyblocks.simulate.esfl_study.esfl_threshold_table`); ``sim`` is one flight
    line or several."""
    from .esfl_study import esfl_threshold_table

    sims = sim if isinstance(sim, list) else [sim]
    return esfl_threshold_table([s.as_cubes() for s in sims], points, fractions, params)
