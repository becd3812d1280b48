"""Airborne points formed into the visible/near-infrared waveform pair a dual-wavelength
sensor would record, and read as its footprints are (DESIGN 4.11): the like-with-like
reference of dual-wavelength footprints.

One formation shared by the simulator (``simulate --sensor dual`` adds noise to it) and the
validation's reference (which reads it without noise), so the two describe one quantity.
Per footprint centre ``(x, y)`` (metres, the points' CRS):

Weights
    As GEDI's (:mod:`.waveform_reference`): the points within 3 sigma, the Gaussian beam
    (sigma 5.5 m) and 1 / (points in their 1.5 m cell within the footprint).
Energy
    Per band, the weight times the surface's reflectance: ground (class 2) ``soil``
    (0.15 visible, 0.25 near infrared), anything else ``leaf`` (0.05, 0.45).
Waveforms
    Both bands binned on ``bin_size`` (0.15 m) samples from ``4 pulse_sigma + 1`` m above
    the highest point down, convolved with the 4 ns pulse; no noise.
Reading
    The dual-wavelength ground finder of
    :func:`~canopyblocks.waveforms.dual_wavelength.dual_wavelength_ground` with the noise
    level the simulator draws (sd = ``noise`` x the pair's near-infrared peak, both bands;
    0: a floor of 0.25 % of each band's peak) and its parameters, on the pair rounded to
    the 32-bit floats a sensor file stores (the noise-free pair's reading moves by metres
    with that rounding): ``ref_ground`` = its ground centre,
    ``ref_top`` = the first sample above the noise threshold, ``ref_height`` = the paper's
    tree height (that first sample to the ground start).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import InputError, NoUsableDataError
from ..readers.las import LasPoints
from .footprint_returns import FootprintReturns, footprint_returns
from .waveform_binning import bin_returns

__all__ = ["DualFormParams", "dual_bands", "dual_noise_sd", "dual_reference",
           "NOISE_FREE_FLOOR", "PAPER_NOISE"]

#: Noise-free pairs: the noise sd stands in as this share of each band's peak.
NOISE_FREE_FLOOR = 0.0025
#: The dual-wavelength paper's noise: sd 5 % of the near-infrared peak.
PAPER_NOISE = 0.05


@dataclass(frozen=True)
class DualFormParams:
    """How airborne points are formed into visible/near-infrared pairs.

    Attributes
    ----------
    sigma : float
        Gaussian footprint sigma, metres.
    bin_size : float
        Sample height, metres.
    pulse_sigma : float
        Pulse sigma in range, metres (4 ns FWHM).
    leaf, soil : (float, float)
        Reflectance (visible, near infrared) of non-ground and ground returns.
    noise : float
        Noise sd as a share of each pair's near-infrared peak (0: noise free).
    density_cell : float
        Cell of the point-density weight, metres.
    """

    sigma: float = 5.5
    bin_size: float = 0.15
    pulse_sigma: float = 4e-9 * 299_792_458.0 / 2 / 2.3548
    leaf: tuple[float, float] = (0.05, 0.45)
    soil: tuple[float, float] = (0.15, 0.25)
    noise: float = PAPER_NOISE
    density_cell: float = 1.5

    def __post_init__(self) -> None:
        for name in ("sigma", "bin_size", "pulse_sigma", "density_cell"):
            if not getattr(self, name) > 0:
                raise InputError(f"{name} must be positive, got {getattr(self, name)!r}")
        if self.noise < 0:
            raise InputError(f"noise must be >= 0, got {self.noise!r}")


def dual_bands(ret: FootprintReturns, form: DualFormParams
               ) -> tuple[np.ndarray, int, list[np.ndarray]]:
    """Noise-free bands of every footprint: window tops (m, NaN without points), samples
    per waveform, and ``[visible, nir]`` (n, m) (sample ``j`` at ``top - j bin``)."""
    n, shot, z, w, ground = ret.n, ret.shot, ret.z, ret.weight, ret.ground
    zmax = np.full(n, -np.inf)
    zmin = np.full(n, np.inf)
    np.maximum.at(zmax, shot, z)
    np.minimum.at(zmin, shot, z)
    pad = 4 * form.pulse_sigma + 1.0
    top = np.where(np.isfinite(zmax), zmax + pad, np.nan)
    m = int(np.ceil(np.nanmax(zmax - zmin) + 2 * pad) / form.bin_size) + 1
    tops = np.nan_to_num(top) + 0.5 * form.bin_size
    bands = [bin_returns(shot, z, w * np.where(ground, form.soil[b], form.leaf[b]), tops,
                         form.bin_size, m, form.pulse_sigma, n_shots=n) for b in (0, 1)]
    return top, m, bands


def dual_noise_sd(bands: list[np.ndarray], noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-band noise sd the simulator draws (and the reading's thresholds assume)."""
    peak = bands[1].max(axis=1)
    if noise > 0:
        sd = noise * peak
        return sd, sd
    return NOISE_FREE_FLOOR * bands[0].max(axis=1), NOISE_FREE_FLOOR * peak


def dual_reference(points: LasPoints, x: np.ndarray, y: np.ndarray,
                   form: DualFormParams | None = None, params: object = None, *,
                   stored: type = np.float32) -> pd.DataFrame:
    """The noise-free pair of each footprint read by the dual-wavelength ground finder.

    Parameters
    ----------
    points : LasPoints
        Airborne points (metric CRS; class 2 = ground).
    x, y : ndarray
        Footprint centres, metres, in the points' CRS.
    form : DualFormParams, optional
        Default: the simulator's.
    params : DualParams, optional
        The ground finder's parameters (default: the paper's method); give the ones the
        footprints were read with.
    stored : numpy float type
        The pair is rounded to this type before it is read, as the sensor file stores it
        (``simulate --sensor dual`` writes float32; np.float64 leaves it unrounded).

    Returns
    -------
    DataFrame
        ``ref_ground``, ``ref_top`` (m), ``ref_height`` (m), ``ref_waveform_flag``
        (``ok``, ``no_ground`` or ``no_signal``) per centre; NaN where not ``ok``.
    """
    from ..waveforms.dual_wavelength import dual_wavelength_ground

    form = form or DualFormParams()
    sx = np.asarray(x, float).ravel()
    sy = np.asarray(y, float).ravel()
    n = sx.size
    out = pd.DataFrame({"ref_ground": np.full(n, np.nan), "ref_top": np.full(n, np.nan),
                        "ref_height": np.full(n, np.nan),
                        "ref_waveform_flag": np.full(n, "no_signal", dtype=object)})
    ids = np.flatnonzero(np.isfinite(sx) & np.isfinite(sy))
    if ids.size == 0:
        return out
    try:
        ret = footprint_returns(points, sx[ids], sy[ids], form.sigma,
                                density_cell=form.density_cell)
    except NoUsableDataError:
        return out
    top, _, bands = dual_bands(ret, form)
    zeros = np.zeros(ids.size)
    sd = dual_noise_sd(bands, form.noise)   # as the simulator writes it, before rounding
    read = [np.asarray(b, stored).astype(float) for b in bands]
    g = dual_wavelength_ground(read[0], read[1], noise_mean=(zeros, zeros.copy()),
                               noise_sd=sd,
                               params=params)  # type: ignore[arg-type]
    first = g.first if g.first is not None else np.full(ids.size, np.nan)
    ok = np.isfinite(top) & g.found & np.isfinite(first)
    flag = np.where(np.isfinite(top) & np.isfinite(first), "no_ground", "no_signal")
    flag = np.where(ok, "ok", flag).astype(object)

    def put(col: str, v: np.ndarray) -> None:
        a = out[col].to_numpy(float).copy()
        a[ids] = np.where(ok, v, np.nan)
        out[col] = a

    put("ref_ground", top - np.asarray(g.centre, float) * form.bin_size)
    put("ref_top", top - np.asarray(first, float) * form.bin_size)
    put("ref_height", g.tree_height(form.bin_size))
    f = out["ref_waveform_flag"].to_numpy(object).copy()
    f[ids] = flag
    out["ref_waveform_flag"] = f
    return out
