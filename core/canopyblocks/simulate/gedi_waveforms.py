"""GEDI-like waveforms simulated from airborne lidar, with truth (DESIGN 4.9).

Footprint centres along a track (every ``spacing`` m) or given; the points under each
footprint weighted by a Gaussian footprint (sigma 5.5 m) and by point density
(:mod:`~canopyblocks.reference.footprint_returns`); ground and canopy returns scaled by their reflectances;
binned on GEDI's 1 ns (0.15 m) samples and convolved with the transmitted pulse
(Gaussian, FWHM 15.6 ns); a gain to digitiser counts, Gaussian noise of the L1B noise
level, and the digitiser's smoothing (the samples' spread is then smaller than the
reported pre-filter ``noise_stddev_corrected``, as in real L1B).

Two ground truths per footprint, because they differ where it matters:

* ``truth_ground``: the weighted mean elevation of the class-2 points (what the ground is);
* ``truth_ground_lowest_mode``: the lowest mode of the noise-free waveform as the L2A-style
  processing (setting a1) finds it (what a waveform can see: its lowest mode merges every
  surface within about a pulse width of the ground, so low returns just above the class-2
  points -- shrubs, low branches, dense in conifer stands -- lift it above the class-2
  mean: measured +0.53 m (sd 0.15, 52 footprints 10 m apart along the README's track over
  the bundled BC conifer tiles lasR_bcts_1/2), +0.07 m on the Florida tile, +1.4 m
  (sd 1.6) on the steep Quebec tile).

RH25-RH100 of the noise-free waveform, as the processing locates the signal in it (energy
where the noise-free waveform rises above the noise thresholds): ``truth_rh*`` above
``truth_ground``, ``truth_rh*_lowest_mode`` above ``truth_ground_lowest_mode`` (what the
processing's RH, measured from its own lowest mode, should reproduce);
``truth_rh*_all_energy`` counts every return, however faint, above ``truth_ground``. And
two covers: ``truth_cover`` (the footprint-weighted share of returns more than 2 m above
the ground) and ``truth_cover_waveform`` (the noise-free waveform's, as the processing
reads it). The noise-free waveform and its reading are those of the footprint reference
(:mod:`~canopyblocks.reference.waveform_reference`, one function), so
``truth_ground_lowest_mode``, ``truth_rh*_lowest_mode`` and ``truth_cover_waveform`` are
what ``validate``/``run`` compare the footprints with. Everything is vectorised over
footprints; a seed makes it deterministic.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.ndimage import gaussian_filter1d

from ..errors import InputError, NoUsableDataError
from ..readers.las import LasPoints
from ..reference.footprint_index import CloudIndex
from ..reference.footprint_returns import footprint_returns
from ..reference.waveform_reference import (
    SAMPLE_M,
    WaveformFormParams,
    noise_free_waveforms,
    pulse_sigma_m,
    read_noise_free,
)
from ..waveforms.batch import WaveformBatch
from .tracks import SimTrack, shots_along

__all__ = ["GediSimParams", "GediSimulation", "simulate_gedi", "TRUTH_RH"]

#: Height above the ground (m) above which a return counts as canopy in ``truth_cover``:
#: the footprint-matched reference's ``cover_threshold`` (FootprintParams).
_COVER_THRESHOLD = 2.0

log = logging.getLogger(__name__)

#: RH percentiles of the truth.
TRUTH_RH: tuple[int, ...] = (25, 50, 75, 90, 95, 98, 100)
#: Most footprints one simulation makes (memory: a few kB of waveform each).
MAX_FOOTPRINTS = 200_000


@dataclass(frozen=True)
class GediSimParams:
    """Parameters of the GEDI waveform simulation (metres, counts, nanoseconds).

    Attributes
    ----------
    sigma : float
        Footprint sigma (m); GEDI 5.5 (about 22-25 m diameter).
    pulse_fwhm_ns : float
        Transmitted pulse width (ns); GEDI about 15.6.
    spacing : float
        Footprint spacing along the track (m); GEDI 60.
    density_cell : float
        Cell (m) of the point-density weight (DESIGN 4.9: 1.5).
    rho_ratio : float
        Canopy / ground reflectance ``rho_v / rho_g``: canopy returns carry this much more
        energy per unit area than ground returns (the ratio GEDI L2B's cover formula
        assumes, DESIGN 4.5); default 1.5.
    peak_counts : float
        Peak amplitude (counts above the noise mean) of a bare-ground return.
    noise_mean, noise_sd : float
        Noise level (counts), pre-filter sd as L1B reports it.
    digitiser_sigma : float
        Smoothing (samples) applied after the noise (the L1B sample spread is about 0.58
        of ``noise_stddev_corrected`` on real shots; sigma 1 gives 0.53).
    margin : float
        Metres of waveform above the highest and below the lowest point.
    """

    # the formation's own defaults (one place: the footprint reference's)
    sigma: float = WaveformFormParams.sigma
    pulse_fwhm_ns: float = WaveformFormParams.pulse_fwhm_ns
    spacing: float = 60.0
    density_cell: float = WaveformFormParams.density_cell
    rho_ratio: float = WaveformFormParams.rho_ratio
    peak_counts: float = WaveformFormParams.peak_counts
    noise_mean: float = WaveformFormParams.noise_mean
    noise_sd: float = WaveformFormParams.noise_sd
    digitiser_sigma: float = 1.0
    margin: float = WaveformFormParams.margin
    beam: str = "BEAM0101"
    extra_truth: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        for name in ("sigma", "pulse_fwhm_ns", "spacing", "rho_ratio", "peak_counts",
                     "margin"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a positive number; got {v!r}")
        for name in ("noise_sd", "digitiser_sigma", "density_cell"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise InputError(f"{name} must be a number >= 0; got {v!r}")
        if not self.beam.startswith("BEAM"):
            raise InputError(f"beam must be a GEDI beam name like BEAM0101; got {self.beam!r}")

    @property
    def formation(self) -> WaveformFormParams:
        """How the waveforms are formed and their noise-free truth read: the parameters
        of the footprint reference (:mod:`~canopyblocks.reference.waveform_reference`)."""
        return WaveformFormParams(sigma=self.sigma, pulse_fwhm_ns=self.pulse_fwhm_ns,
                                  density_cell=self.density_cell, rho_ratio=self.rho_ratio,
                                  peak_counts=self.peak_counts, noise_mean=self.noise_mean,
                                  noise_sd=self.noise_sd, margin=self.margin)

    @property
    def pulse_sigma_m(self) -> float:
        """Pulse sigma in range (m)."""
        return pulse_sigma_m(self.pulse_fwhm_ns)


@dataclass(frozen=True)
class GediSimulation:
    """Simulated waveforms (one beam) and their truth.

    Attributes
    ----------
    batch : WaveformBatch
        The L1B-like waveforms (elevations in the tiles' vertical datum, lon/lat WGS84).
    truth : DataFrame
        Per footprint: ``shot_number``, ``x``, ``y`` (tiles' CRS), ``truth_ground``
        (class-2 weighted mean), ``truth_ground_lowest_mode`` (noise-free waveform),
        ``truth_rh25`` .. ``truth_rh100`` and ``truth_rh*_lowest_mode`` (m, above each),
        ``truth_rh*_all_energy``, ``truth_cover``, ``truth_cover_waveform``, ``n_points``
        (see the module notes).
    crs : str
        The tiles' CRS (WKT).
    vertical_datum : str
    """

    batch: WaveformBatch
    truth: pd.DataFrame
    crs: str
    vertical_datum: str


def _truth_rh(wf: np.ndarray, top: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """RH (m above ``ground``) of noise-free waveforms: where the cumulative energy from
    the bottom first reaches k %."""
    n, m = wf.shape
    rev = wf[:, ::-1]
    cum = np.cumsum(rev, axis=1)
    total = cum[:, -1]
    out = np.full((n, len(TRUTH_RH)), np.nan)
    elev_rev = top[:, None] - SAMPLE_M * (m - 1 - np.arange(m))[None, :]
    for j, k in enumerate(TRUTH_RH):
        target = total * (k / 100.0) if k < 100 else total * (1 - 1e-6)
        idx = np.argmax(cum >= target[:, None], axis=1)
        out[:, j] = elev_rev[np.arange(n), idx] - ground
    out[total <= 0] = np.nan
    return out


def _noise_free_truth(clean: np.ndarray, top: np.ndarray, form: WaveformFormParams,
                      lon: np.ndarray, lat: np.ndarray, ground: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The noise-free waveforms read as the footprint reference reads them
    (:func:`~canopyblocks.reference.waveform_reference.read_noise_free`, the same
    function): RH measured from the class-2 ``ground`` (n, k), the lowest mode (n,), RH
    measured from that lowest mode (n, k) and the waveform's cover (n,)."""
    res = read_noise_free(clean, top, form, lon, lat)
    g = res["ground"].to_numpy(float)
    above_mode = np.column_stack([res[f"rh{k}"].to_numpy(float) for k in TRUTH_RH])
    return above_mode + (g - ground)[:, None], g, above_mode, res["cover"].to_numpy(float)


def simulate_gedi(points: LasPoints, track: SimTrack | None = None, *,
                  centres: tuple[np.ndarray, np.ndarray] | None = None,
                  params: GediSimParams | None = None, seed: int = 0,
                  index: tuple[CloudIndex, np.ndarray] | None = None) -> GediSimulation:
    """Simulate GEDI L1B-like waveforms over airborne points.

    Parameters
    ----------
    points : LasPoints
        Airborne tiles (metric CRS, metres; class 2 = ground).
    track : SimTrack, optional
        Footprints every ``params.spacing`` m along it.
    centres : (x, y), optional
        Footprint centres instead of a track (the points' CRS).
    params : GediSimParams, optional
    seed : int
        Noise seed; same inputs and seed give identical waveforms.
    index : optional
        :func:`~canopyblocks.reference.footprint_returns.footprint_index` of ``points``, to reuse across calls.

    Raises
    ------
    InputError
        Neither or both of ``track`` and ``centres``; a negative seed.
    NoUsableDataError
        No point under any footprint, or no ground point under any.
    """
    p = params or GediSimParams()
    if (track is None) == (centres is None):
        raise InputError("give either a track or footprint centres")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be an integer >= 0; got {seed!r}")
    if track is not None:
        if track.length / p.spacing > MAX_FOOTPRINTS:
            raise InputError(f"a shot spacing of {p.spacing:g} m puts "
                             f"{track.length / p.spacing:.3g} footprints on the "
                             f"{track.length:.0f} m track; at most {MAX_FOOTPRINTS:,} "
                             "(GEDI's spacing is 60 m)")
        sx, sy, _ = shots_along(track, p.spacing)
    else:
        sx, sy = (np.asarray(c, dtype=np.float64) for c in centres)  # type: ignore[union-attr]
    n = sx.size
    if n == 0:
        raise NoUsableDataError("no footprint centre on the track")
    ret = footprint_returns(points, sx, sy, p.sigma, density_cell=p.density_cell,
                            index=index)
    counts = np.bincount(ret.shot, minlength=n)
    wg = ret.per_shot(ret.weight, ret.ground)
    if not (wg > 0).any():
        raise NoUsableDataError("no class-2 (ground) point under the footprints: classify "
                                "the tiles' ground first (e.g. canopyblocks rasters --smrf)")
    zg = ret.per_shot(ret.weight * ret.z, ret.ground)
    wt = ret.per_shot(ret.weight)
    with np.errstate(invalid="ignore", divide="ignore"):
        truth_ground = np.where(wg > 0, zg / wg, np.nan)
        # cover as the footprint-matched reference of ``run`` states it (DESIGN 2.7): the
        # weighted share of the returns more than 2 m above the ground (here the
        # footprint's mean ground; the reference uses a ground plane, the same on flat
        # ground), so that ``simulate`` and ``run`` report one statistic
        hag = ret.z - truth_ground[ret.shot]
        wv = ret.per_shot(ret.weight, np.isfinite(hag) & (hag > _COVER_THRESHOLD))
        cover = np.where(wt > 0, wv / wt, np.nan)
    clean, top, m = noise_free_waveforms(ret, p.formation)
    rh_all = _truth_rh(clean, np.nan_to_num(top), truth_ground)
    rng = np.random.default_rng(int(seed))
    noisy = clean + rng.normal(0.0, p.noise_sd, clean.shape)
    if p.digitiser_sigma > 0:
        noisy = gaussian_filter1d(noisy, p.digitiser_sigma, axis=1, mode="nearest")
    noisy = noisy + p.noise_mean
    usable = np.isfinite(top) & (counts > 0)
    wf = np.where(usable[:, None], noisy, p.noise_mean).astype(np.float32)
    lon, lat = _lonlat(sx, sy, points)
    elev0 = np.where(usable, top, np.nan)
    elev1 = elev0 - SAMPLE_M * (m - 1)
    shot_numbers = (np.uint64(10**17) + np.arange(n, dtype=np.uint64) * np.uint64(100)
                    + np.uint64(int(seed) % 97))
    batch = WaveformBatch(
        beam=p.beam, shot_number=shot_numbers, time=np.arange(n, dtype=np.float64) / 242.0,
        waveforms=wf, n_samples=np.where(usable, m, 0).astype(np.int64),
        elev_bin0=elev0, elev_lastbin=elev1, lat_bin0=lat, lat_lastbin=lat.copy(),
        lon_bin0=lon, lon_lastbin=lon.copy(), noise_mean=np.full(n, p.noise_mean),
        noise_sd=np.full(n, p.noise_sd), stale=np.zeros(n, bool), degraded=np.zeros(n, bool),
        power="full", source="simulated")
    rh, mode, rh_mode, wcover = _noise_free_truth(clean, np.where(usable, top, np.nan),
                                                  p.formation, lon, lat, truth_ground)
    truth = pd.DataFrame({"shot_number": shot_numbers.astype(np.int64), "x": sx, "y": sy,
                          "truth_ground": truth_ground, "truth_ground_lowest_mode": mode,
                          "truth_cover": cover, "truth_cover_waveform": wcover,
                          "n_points": counts})
    for j, k in enumerate(TRUTH_RH):
        truth[f"truth_rh{k}"] = rh[:, j]
    for j, k in enumerate(TRUTH_RH):
        truth[f"truth_rh{k}_lowest_mode"] = rh_mode[:, j]
    for j, k in enumerate(TRUTH_RH):
        truth[f"truth_rh{k}_all_energy"] = rh_all[:, j]
    return GediSimulation(batch, truth, str(points.crs.to_wkt()), points.vertical_datum)


def _lonlat(x: np.ndarray, y: np.ndarray, points: LasPoints) -> tuple[np.ndarray, np.ndarray]:
    import pyproj

    crs = pyproj.CRS(points.crs)
    if crs.is_compound:
        crs = crs.sub_crs_list[0]
    tr = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = tr.transform(x, y)
    return np.asarray(lon, float), np.asarray(lat, float)
