"""The airborne points formed into the waveform a full-waveform sensor would record, and
read as its footprints are (DESIGN 4.10): the like-with-like reference of GEDI footprints.

One definition, shared by the GEDI simulator's truth (``truth_ground_lowest_mode``,
``truth_rh*_lowest_mode``, ``truth_cover_waveform``) and by the footprint validation's
reference (``validate_footprints(..., reference="waveform")``, the default), so the two
are the same quantity by construction. Per footprint centre ``(x, y)`` (metres, the
points' CRS; heights in the points' vertical datum):

Weights
    The points within ``3 sigma`` of the centre (noise classes 7 and 18 dropped), each
    weighted by the Gaussian beam ``exp(-r^2 / (2 sigma^2))`` (GEDI: sigma 5.5 m, the 22 m
    footprint's 1/e^2 radius being 2 sigma) and divided by the points of its 1.5 m cell
    within that footprint (a denser survey patch does not count more):
    :func:`~canopyblocks.reference.footprint_returns.footprint_returns`.
Energy
    A class-2 return carries its weight, any other return ``rho_ratio`` (1.5) times it
    (canopy is brighter than ground per unit area: the ratio GEDI L2B assumes).
Waveform
    The energies binned on the sensor's samples (0.15 m, from ``margin`` above the highest
    point down), convolved with the transmitted pulse (Gaussian, FWHM 15.6 ns) and scaled
    so a bare-ground footprint would peak ``peak_counts`` (250) counts above a noise mean
    of ``noise_mean`` (230): no noise added.
Reading
    The GEDI L2A algorithm of :func:`~canopyblocks.waveforms.process.process_waveforms`
    (setting ``setting``, a1) with the noise level ``noise_sd`` (4 counts), exactly as the
    footprints are read: ``ref_ground`` is the lowest mode; ``ref_rh{k}`` the height above
    it where the energy between the signal bottom and top (where the waveform rises above
    the noise thresholds), accumulated from the bottom, reaches k %; ``ref_cover`` the
    waveform's canopy cover (canopy energy over ground energy, with ``rho_ratio``).

The noise level and amplitude are the GEDI simulator's: a simulated file is compared with
its own noise-free self. A real granule's shots have their own signal-to-noise ratio; a
weaker shot loses more faint canopy top to the thresholds than this reference does.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import InputError
from ..readers.las import LasPoints
from .footprint_index import CloudIndex
from .footprint_returns import FootprintReturns, footprint_returns
from .waveform_binning import bin_returns

__all__ = ["WaveformFormParams", "noise_free_waveforms", "read_noise_free",
           "waveform_reference", "pulse_sigma_m", "SAMPLE_M", "WAVEFORM_RH"]

#: Light travels 0.1499 m (there and back) per nanosecond sample.
SAMPLE_M = 0.299792458 / 2.0
#: RH percentiles of the waveform reference (those of the footprint table).
WAVEFORM_RH: tuple[int, ...] = (25, 50, 75, 90, 95, 98, 100)


def pulse_sigma_m(pulse_fwhm_ns: float) -> float:
    """Pulse sigma in range (metres) of a pulse ``pulse_fwhm_ns`` nanoseconds wide (FWHM)."""
    return pulse_fwhm_ns / (2.0 * np.sqrt(2.0 * np.log(2.0))) * SAMPLE_M


@dataclass(frozen=True)
class WaveformFormParams:
    """How airborne points are formed into a waveform and read (GEDI's by default).

    Attributes
    ----------
    sigma : float
        Gaussian footprint sigma, metres (GEDI 5.5: a 22 m diameter is 4 sigma).
    pulse_fwhm_ns : float
        Transmitted pulse width, nanoseconds (GEDI 15.6).
    density_cell : float
        Cell of the point-density weight, metres (0 disables it).
    rho_ratio : float
        Energy of a non-ground return over that of a ground return of the same weight.
    peak_counts : float
        Peak (counts above the noise mean) of a bare-ground footprint.
    noise_mean, noise_sd : float
        Noise mean and standard deviation, counts (the thresholds of the reading).
    margin : float
        Metres of waveform above the highest and below the lowest point.
    setting : str
        L2A setting group of the reading (a1..a6).
    """

    sigma: float = 5.5
    pulse_fwhm_ns: float = 15.6
    density_cell: float = 1.5
    rho_ratio: float = 1.5
    peak_counts: float = 250.0
    noise_mean: float = 230.0
    noise_sd: float = 4.0
    margin: float = 25.0
    setting: str = "a1"

    def __post_init__(self) -> None:
        for name in ("sigma", "pulse_fwhm_ns", "rho_ratio", "peak_counts", "noise_sd",
                     "margin"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a positive number; got {v!r}")
        if not (isinstance(self.density_cell, (int, float)) and self.density_cell >= 0):
            raise InputError(f"density_cell must be >= 0 m; got {self.density_cell!r}")

    @property
    def pulse_sigma_m(self) -> float:
        """Pulse sigma in range, metres."""
        return pulse_sigma_m(self.pulse_fwhm_ns)

    @classmethod
    def for_diameter(cls, diameter: float, **kw: object) -> WaveformFormParams:
        """The GEDI formation with a footprint of ``diameter`` metres (sigma = diameter / 4)."""
        return cls(sigma=float(diameter) / 4.0, **kw)  # type: ignore[arg-type]


def noise_free_waveforms(ret: FootprintReturns, form: WaveformFormParams
                         ) -> tuple[np.ndarray, np.ndarray, int]:
    """Noise-free waveforms (counts above the noise mean), window tops (m), samples.

    Sample ``j`` of footprint ``i`` lies at ``top[i] - j * SAMPLE_M``; ``top`` is NaN for a
    footprint without points (its row is zero).
    """
    n = ret.n
    shot, z = ret.shot, ret.z
    energy = ret.weight * np.where(ret.ground, 1.0, form.rho_ratio)
    zmax = np.full(n, -np.inf)
    zmin = np.full(n, np.inf)
    np.maximum.at(zmax, shot, z)
    np.minimum.at(zmin, shot, z)
    has = np.isfinite(zmax)
    top = np.where(has, zmax + form.margin, np.nan)
    span = np.where(has, zmax - zmin, 0.0)
    m = int(np.ceil((float(span.max()) + 2 * form.margin) / SAMPLE_M)) + 1
    # bins centred on the sample elevations: sample j lies at top - j * SAMPLE_M
    wf = bin_returns(shot, z, energy, np.nan_to_num(top) + 0.5 * SAMPLE_M, SAMPLE_M, m,
                     form.pulse_sigma_m, n_shots=n)
    # gain: a bare-ground footprint (all weight on ground) would peak at peak_counts
    total = np.bincount(shot, weights=energy, minlength=n)
    unit = bin_returns(np.zeros(1, np.int64), np.zeros(1), np.ones(1),
                       np.array([form.margin + 0.5 * SAMPLE_M]), SAMPLE_M, m,
                       form.pulse_sigma_m).max()
    with np.errstate(invalid="ignore", divide="ignore"):
        gain = np.where(total > 0, form.peak_counts / (unit * total), 0.0)
    return wf * gain[:, None], top, m


def read_noise_free(clean: np.ndarray, top: np.ndarray, form: WaveformFormParams,
                    lon: np.ndarray, lat: np.ndarray) -> pd.DataFrame:
    """Noise-free waveforms read by the L2A algorithm with the noise level of ``form``.

    Parameters
    ----------
    clean : ndarray (n, m)
        Counts above the noise mean (:func:`noise_free_waveforms`).
    top : ndarray (n,)
        Elevation of sample 0, metres (NaN: no points, no waveform).
    form : WaveformFormParams
    lon, lat : ndarray (n,)
        Footprint centres, degrees WGS84 (the geometry of the reading only).

    Returns
    -------
    DataFrame
        ``ground`` (the lowest mode, m), ``rh25`` .. ``rh100`` (m above it), ``cover``
        (0..1) and ``flag`` (the reading's, ``no_signal`` without points) per footprint.
    """
    from ..waveforms.batch import WaveformBatch
    from ..waveforms.process import process_waveforms
    from ..waveforms.settings import WaveformParams

    n, m = clean.shape
    usable = np.isfinite(top)
    wf = np.where(usable[:, None], clean + form.noise_mean, form.noise_mean)
    elev0 = np.where(usable, top, np.nan)
    batch = WaveformBatch(
        beam="BEAM0101", shot_number=np.arange(n, dtype=np.uint64),
        time=np.zeros(n), waveforms=wf.astype(np.float32),
        n_samples=np.where(usable, m, 0).astype(np.int64), elev_bin0=elev0,
        elev_lastbin=elev0 - SAMPLE_M * (m - 1), lat_bin0=np.asarray(lat, float),
        lat_lastbin=np.asarray(lat, float), lon_bin0=np.asarray(lon, float),
        lon_lastbin=np.asarray(lon, float), noise_mean=np.full(n, form.noise_mean),
        noise_sd=np.full(n, form.noise_sd), stale=np.zeros(n, bool),
        degraded=np.zeros(n, bool), power="full", source="reference")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = process_waveforms(batch, WaveformParams(setting=form.setting,  # type: ignore[arg-type]
                                                      terrain_filter=False,
                                                      rho_ratio=form.rho_ratio))
    out = pd.DataFrame({"ground": res["ground"].to_numpy(float)})
    for k in WAVEFORM_RH:
        out[f"rh{k}"] = res[f"rh{k}"].to_numpy(float)
    out["cover"] = res["cover"].to_numpy(float)
    out["flag"] = np.where(usable, res["flag"].astype(str).to_numpy(object), "no_signal")
    return out


def waveform_reference(points: LasPoints, x: np.ndarray, y: np.ndarray,
                       lon: np.ndarray, lat: np.ndarray,
                       form: WaveformFormParams | None = None, *,
                       index: tuple[CloudIndex, np.ndarray] | None = None) -> pd.DataFrame:
    """The waveform-formed reference at footprint centres (see the module notes).

    Parameters
    ----------
    points : LasPoints
        Airborne points (metric CRS, metres; class 2 = ground).
    x, y : ndarray
        Footprint centres, metres, in the points' CRS.
    lon, lat : ndarray
        The same centres in degrees WGS84.
    form : WaveformFormParams, optional
        Default GEDI's.
    index : optional
        :func:`~canopyblocks.reference.footprint_returns.footprint_index` of ``points``.

    Returns
    -------
    DataFrame
        One row per centre: ``ref_ground``, ``ref_rh25`` .. ``ref_rh100``, ``ref_cover``,
        ``ref_waveform_flag`` (``ok``, or why the reading found no ground) and
        ``ref_n_returns`` (points within 3 sigma). NaN values where the flag is not ``ok``.
    """
    form = form or WaveformFormParams()
    sx = np.asarray(x, dtype=np.float64).ravel()
    sy = np.asarray(y, dtype=np.float64).ravel()
    n = sx.size
    fin = np.isfinite(sx) & np.isfinite(sy)
    out = pd.DataFrame({"ref_ground": np.full(n, np.nan),
                        **{f"ref_rh{k}": np.full(n, np.nan) for k in WAVEFORM_RH},
                        "ref_cover": np.full(n, np.nan),
                        "ref_waveform_flag": np.full(n, "no_signal", dtype=object),
                        "ref_n_returns": np.zeros(n, np.int64)})
    ids = np.flatnonzero(fin)
    if ids.size == 0:
        return out
    from ..errors import NoUsableDataError
    try:
        ret = footprint_returns(points, sx[ids], sy[ids], form.sigma,
                                density_cell=form.density_cell, index=index)
    except NoUsableDataError:
        return out
    clean, top, _ = noise_free_waveforms(ret, form)
    read = read_noise_free(clean, top, form, np.asarray(lon, float).ravel()[ids],
                           np.asarray(lat, float).ravel()[ids])
    ok = read["flag"].to_numpy(object) == "ok"
    for c in ("ground", *(f"rh{k}" for k in WAVEFORM_RH), "cover"):
        col = out[f"ref_{c}"].to_numpy(float).copy()
        col[ids] = np.where(ok, read[c].to_numpy(float), np.nan)
        out[f"ref_{c}"] = col
    flag = out["ref_waveform_flag"].to_numpy(object).copy()
    flag[ids] = read["flag"].to_numpy(object)
    out["ref_waveform_flag"] = flag
    cnt = out["ref_n_returns"].to_numpy(np.int64).copy()
    cnt[ids] = np.bincount(ret.shot, minlength=ids.size)
    out["ref_n_returns"] = cnt
    return out

