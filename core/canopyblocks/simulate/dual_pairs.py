"""Simulated visible / near-infrared waveform pairs over sloped forest (seed 004, DESIGN 4.8).

A synthetic scene per footprint: a planar ground of a given slope and a canopy layer
covering a given share of the footprint (crowns in random 2 m cells). The same scene is
seen in two bands that differ only in reflectance: leaves are dark in the visible and
bright in the near infrared, soil reflects both alike (defaults: leaf 0.05 / 0.45, soil
0.15 / 0.25). Under a crown the canopy intercepts ``interception`` of the light and the
ground returns the rest; in gaps the ground returns everything.

Each band's waveform is the footprint-weighted (Gaussian, ``sigma`` m) sum of the
surface returns binned by elevation, convolved with a Gaussian pulse, plus Gaussian
noise. Truth per footprint: the ground elevation at the footprint centre and the
highest and lowest ground elevations inside the 1/e^2 footprint.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import InputError
from ..reference.dual_reference import NOISE_FREE_FLOOR, PAPER_NOISE
from ..reference.waveform_binning import bin_returns

__all__ = ["DualSimParams", "DualPairs", "simulate_dual_pairs", "dual_cover_study",
           "lowest_mode_ground", "NOISE_FREE_FLOOR", "PAPER_NOISE"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DualSimParams:
    """Scene and instrument of the dual-wavelength simulation (metres unless stated).

    Attributes
    ----------
    slope : float
        Ground slope, degrees.
    cover : float
        Share of the footprint area under crowns, 0..1.
    canopy_base, canopy_top : float
        Crown layer heights above ground.
    sigma : float
        Footprint Gaussian sigma (GEDI 5.5 m).
    pulse_sigma : float
        Pulse sigma in range (m); default from a 4 ns FWHM pulse.
    bin_size : float
        Waveform sample spacing in elevation.
    leaf, soil : (float, float)
        Reflectance (visible, near infrared).
    interception : float
        Share of the light a crown cell intercepts.
    noise : float
        Noise sd as a share of the near-infrared waveform's peak (the dual-wavelength
        paper's 5 % by default; 0 = noise free).
    grid : float
        Spacing of the scene's surface samples.
    """

    slope: float = 30.0
    cover: float = 0.5
    canopy_base: float = 8.0
    canopy_top: float = 20.0
    sigma: float = 5.5
    pulse_sigma: float = 4e-9 * 299_792_458.0 / 2 / 2.3548
    bin_size: float = 0.15
    leaf: tuple[float, float] = (0.05, 0.45)
    soil: tuple[float, float] = (0.15, 0.25)
    interception: float = 0.7
    noise: float = 0.05
    grid: float = 0.25

    def __post_init__(self) -> None:
        if not (0.0 <= self.slope < 80.0):
            raise InputError(f"slope must be 0..80 degrees, got {self.slope!r}")
        if not (0.0 <= self.cover <= 1.0):
            raise InputError(f"cover must be a share 0..1, got {self.cover!r}")
        if not (0.0 <= self.canopy_base < self.canopy_top):
            raise InputError("canopy_base must be >= 0 and below canopy_top")
        for name in ("sigma", "pulse_sigma", "bin_size", "grid"):
            if not getattr(self, name) > 0:
                raise InputError(f"{name} must be positive, got {getattr(self, name)!r}")
        if not (0.0 < self.interception < 1.0):
            raise InputError(f"interception must be in (0, 1), got {self.interception!r}")
        if self.noise < 0:
            raise InputError(f"noise must be >= 0, got {self.noise!r}")


@dataclass(frozen=True)
class DualPairs:
    """``n`` simulated pairs; sample ``k`` of shot ``i`` lies at ``top[i] - k * bin_size``.

    ``visible``/``nir`` (n, m), per-band noise mean and sd (n,), and truth per shot:
    ``ground_centre``, ``ground_high``, ``ground_low`` (m) and ``cover`` (0..1).
    """

    top: np.ndarray
    bin_size: float
    visible: np.ndarray
    nir: np.ndarray
    noise_mean: tuple[np.ndarray, np.ndarray]
    noise_sd: tuple[np.ndarray, np.ndarray]
    ground_centre: np.ndarray
    ground_high: np.ndarray
    ground_low: np.ndarray
    cover: np.ndarray

    def position_to_elevation(self, pos: np.ndarray) -> np.ndarray:
        """Elevation (m) at fractional sample positions (one per shot)."""
        return self.top - np.asarray(pos, float) * self.bin_size


def simulate_dual_pairs(n: int, params: DualSimParams | None = None, *, seed: int = 0
                        ) -> DualPairs:
    """Simulate ``n`` footprints' visible and near-infrared waveforms (deterministic)."""
    p = params or DualSimParams()
    if not (isinstance(n, (int, np.integer)) and 1 <= n <= 100_000):
        raise InputError(f"n must be 1..100000 footprints, got {n!r}")
    rng = np.random.default_rng(seed)
    r = 3.0 * p.sigma
    g = np.arange(-r, r + 1e-9, p.grid)
    gx, gy = np.meshgrid(g, g)
    keep = gx ** 2 + gy ** 2 <= r * r
    gx, gy = gx[keep], gy[keep]
    weight = np.exp(-(gx ** 2 + gy ** 2) / (2 * p.sigma ** 2)) * p.grid ** 2
    tan = np.tan(np.radians(p.slope))
    ground = tan * gx  # footprint centre at elevation 0; the slope rises towards +x
    in_fp = gx ** 2 + gy ** 2 <= (2 * p.sigma) ** 2
    top = p.canopy_top + tan * r + 3 * p.pulse_sigma + 2.0
    bottom = -tan * r - 3 * p.pulse_sigma - 2.0
    m = int(np.ceil((top - bottom) / p.bin_size)) + 1
    elevation = top - np.arange(m) * p.bin_size
    # crowns: random 2 m cells, the same cell pattern for both bands
    cell = (np.floor((gx + r) / 2.0).astype(np.int64) * 10_000
            + np.floor((gy + r) / 2.0).astype(np.int64))
    _, cell_id = np.unique(cell, return_inverse=True)
    n_cells = int(cell_id.max()) + 1
    covered = rng.random((n, n_cells)) < p.cover
    crown_h = p.canopy_base + (p.canopy_top - p.canopy_base) * rng.random((n, gx.size))
    under = covered[:, cell_id]  # (n, points)
    canopy_z = ground[None, :] + crown_h
    bands = []
    shot = np.repeat(np.arange(n), gx.size)
    tops = np.full(n, top + 0.5 * p.bin_size)  # bin k is centred on elevation[k]
    zz = np.concatenate([np.broadcast_to(ground, (n, gx.size)).ravel(), canopy_z.ravel()])
    ss = np.concatenate([shot, shot])
    for band in (0, 1):
        g_int = weight[None, :] * p.soil[band] * np.where(under, 1 - p.interception, 1.0)
        c_int = weight[None, :] * p.leaf[band] * p.interception * under
        bands.append(bin_returns(ss, zz, np.concatenate([g_int.ravel(), c_int.ravel()]), tops,
                                 p.bin_size, m, p.pulse_sigma))
    vis, nir = bands
    peak = nir.max(axis=1)
    sd = p.noise * peak
    means = []
    sds = []
    out = []
    for wf, scale in ((vis, 1.0), (nir, 1.0)):
        nm = np.zeros(n)
        if p.noise > 0:
            wf = wf + rng.normal(0.0, 1.0, wf.shape) * sd[:, None] * scale
        out.append(wf)
        means.append(nm)
        # noise-free: a floor of NOISE_FREE_FLOOR (0.25 %) of the band's peak stands for
        # the receiver's floor
        sds.append(sd if p.noise > 0 else NOISE_FREE_FLOOR * wf.max(axis=1))
    g_in = ground[in_fp]
    return DualPairs(np.full(n, elevation[0]), p.bin_size, out[0], out[1],
                     (means[0], means[1]), (sds[0], sds[1]), np.zeros(n),
                     np.full(n, g_in.max()), np.full(n, g_in.min()),
                     covered[:, cell_id][:, in_fp].mean(axis=1))


def dual_cover_study(covers: tuple[float, ...] = (0.1, 0.3, 0.5, 0.7, 0.9), *,
                     slope: float = 30.0, n: int = 100, noise: float = PAPER_NOISE,
                     seed: int = 0, method: str = "paper", canopy_base: float = 8.0
                     ) -> pd.DataFrame:
    """Ground error against canopy cover (the dual-wavelength paper's figure 8: 100
    waveforms per cover on a 30 degree slope with 5 % noise): dual-wavelength centre and
    the lowest-mode ground of the near-infrared waveform (L2A-style, setting a1).

    Returns one row per cover: ``cover``, ``n``, ``found`` (share), ``dual_bias``,
    ``dual_sd``, ``dual_rmse``, ``mode_bias``, ``mode_sd``, ``mode_rmse`` (m, estimate
    minus the ground elevation at the footprint centre), and ``height_bias``,
    ``height_rmse`` (m, the dual-wavelength tree height, first return to ground start,
    minus the trees' height ``canopy_top`` of the scene; NaN at cover 0, which has no
    trees). ``canopy_base``: the crowns' lowest height above the ground (m; low crowns
    blur the ground return as understory does).
    """
    from ..waveforms.dual_wavelength import DualParams, dual_wavelength_ground

    rows = []
    for i, cover in enumerate(covers):
        d = simulate_dual_pairs(n, DualSimParams(slope=slope, cover=cover, noise=noise,
                                                 canopy_base=canopy_base), seed=seed + i)
        g = dual_wavelength_ground(d.visible, d.nir, noise_mean=d.noise_mean,
                                   noise_sd=d.noise_sd, params=DualParams(method=method))
        err = d.position_to_elevation(g.centre) - d.ground_centre
        mode_err = lowest_mode_ground(d) - d.ground_centre
        row: dict[str, float] = {"cover": cover, "n": n, "found": float(g.found.mean())}
        for name, e in (("dual", err), ("mode", mode_err)):
            e = e[np.isfinite(e)]
            row[f"{name}_bias"] = float(e.mean()) if e.size else float("nan")
            row[f"{name}_sd"] = float(e.std(ddof=1)) if e.size > 1 else float("nan")
            row[f"{name}_rmse"] = float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")
        he = g.tree_height(d.bin_size) - DualSimParams().canopy_top
        he = he[np.isfinite(he)] if cover > 0 else he[:0]
        row["height_bias"] = float(he.mean()) if he.size else float("nan")
        row["height_rmse"] = float(np.sqrt(np.mean(he ** 2))) if he.size else float("nan")
        rows.append(row)
    return pd.DataFrame(rows)


def lowest_mode_ground(d: DualPairs) -> np.ndarray:
    """Lowest-mode ground elevation (m) of the near-infrared waveforms, through the GEDI
    L2A-style processing (NaN where it finds no signal)."""
    from ..waveforms.batch import WaveformBatch
    from ..waveforms.process import process_waveforms

    n, m = d.nir.shape
    z = np.zeros(n)
    batch = WaveformBatch(
        beam="NIR", shot_number=np.arange(n, dtype=np.uint64), time=z.copy(),
        waveforms=d.nir.astype(np.float32), n_samples=np.full(n, m, np.int64),
        elev_bin0=d.top.astype(float), elev_lastbin=d.top - (m - 1) * d.bin_size,
        lat_bin0=z.copy(), lat_lastbin=z.copy(), lon_bin0=z.copy(), lon_lastbin=z.copy(),
        noise_mean=np.asarray(d.noise_mean[1], float) + z,
        noise_sd=np.maximum(np.asarray(d.noise_sd[1], float) + z, 1e-12),
        stale=np.zeros(n, bool), degraded=np.zeros(n, bool))
    out = process_waveforms(batch)
    return out["ground"].to_numpy(float)
