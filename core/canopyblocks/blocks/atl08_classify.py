"""An ATL08-style photon classifier (DESIGN 1.11): noise, ground, canopy, top of canopy.

Steps, all vectorised along the track:

1. **Background rate.** From ATL03 ``bckgrd_atlas/bckgrd_rate`` when the track carries it
   (:class:`~canopyblocks.photons.BackgroundRate`, photons/s): expected background photons
   per metre along-track per metre of height = rate x 2 / c / shot spacing (0.7 m for
   ICESat-2). Otherwise it is estimated per 200 m from the photons themselves (the median
   count of height bins over the whole telemetry window, which signal fills only a few of:
   the photons well away from the surface and canopy).
2. **Noise filter** (DRAGANN-like, :func:`.density_filter.density_filter`): a photon is
   signal when its neighbours in a box of +-``filter.along`` x +-``filter.height`` m
   outnumber the ``filter.quantile`` Poisson quantile of what background alone gives there.
3. **Ground** (:func:`.atl08_surface.fit_atl08_surface`): a low percentile per 30 m, then
   passes of a robust fit in narrowing bands, smoothed. Then the photons near it that pass
   a long, flat box (``ground_filter``, on heights relative to the surface's trend: few
   ground photons under a canopy or on a weak beam, on one line) join the signal photons
   as ground candidates and the surface is fitted again from the first one.
4. **Canopy.** Photons above the ground buffer that pass the noise filter or a long, flat
   density test (+-``canopy_filter.along`` x +-``canopy_filter.height`` m at the same rate:
   sparse crowns at one height; a longer, taller box on a sparse track, one with fewer than
   ``sparse_signal`` signal photons a metre, e.g. a weak beam), and that are reachable from
   the ground without
   a vertical gap of more than ``max_gap`` m inside their ``top_window`` window (isolated
   photons high above the canopy are noise).
5. **Top of canopy.** Canopy photons within ``toc_depth`` m of the highest canopy photon
   of their ``top_window`` window.

Classes are ATL08's ``classed_pc_flag`` codes: 0 noise, 1 ground (within
``-ground_below`` .. ``+ground_buffer`` m of the surface), 2 canopy, 3 top of canopy;
photons with a non-finite position or height get -1 (not classified).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import CanopyBlocksWarning, InputError
from ..photons import SPEED_OF_LIGHT, PhotonTrack
from .atl08_surface import SurfaceParams, fit_atl08_surface
from .density_filter import DensityParams, _filter
from .ground_surface import GroundSurface
from .grouped import sorted_groups

__all__ = ["Atl08Params", "Atl08Classes", "classify_photons", "background_density",
           "CLASS_NOISE", "CLASS_GROUND", "CLASS_CANOPY", "CLASS_TOP", "CLASS_NONE",
           "CLASS_COLUMN", "ICESAT2_SHOT_SPACING"]

log = logging.getLogger(__name__)

CLASS_NONE = -1
CLASS_NOISE = 0
CLASS_GROUND = 1
CLASS_CANOPY = 2
CLASS_TOP = 3
CLASS_COLUMN = "classed_pc_flag"
"""ATL08's name for the per-photon class, used for the photon layer's column."""

ICESAT2_SHOT_SPACING = 0.7
"""Metres between ICESat-2 shots along the track (10 kHz at ~7 km/s)."""


def _positive(v: object, what: str) -> float:
    if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v > 0:
        return float(v)
    raise InputError(f"{what} must be a positive number of metres, got {v!r}")


@dataclass(frozen=True)
class Atl08Params:
    """Parameters of :func:`classify_photons` (metres unless stated).

    Attributes
    ----------
    filter : DensityParams
        The noise filter's box and Poisson quantile (+-10 m x +-1.5 m, 0.999).
    canopy_filter : DensityParams
        The long, flat canopy test (+-20 m x +-3 m, quantile 0.99; the gap rule then
        removes what stray noise it lets through).
    sparse_canopy_filter : DensityParams
        The canopy test of a sparse track (+-40 m x +-4 m, quantile 0.99): the box must hold
        enough canopy photons to stand out where there are a quarter as many (weak beams).
    sparse_signal : float
        Photons per metre along the track passing the noise filter below which a track is
        sparse (1.2; on the calibration tiles strong beams gave 2.6-3.6, weak 0.2-1.0).
    surface : SurfaceParams
        The ground surface (:mod:`.atl08_surface`).
    shot_spacing : float
        Metres between shots, to turn a rate per shot into one per metre (0.7).
    ground_buffer : float
        Photons up to this far above the surface are ground (0.6; ATL08's ground photons
        on the real Wyoming clip reach 0.5-0.9 m above its surface).
    ground_below : float
        Photons up to this far below the surface are ground; lower ones are noise (1.0).
    max_gap : float
        Largest vertical gap between canopy photons of a window (10; 5 m lost a third of
        the weak-beam canopy photons at night on the calibration tiles).
    top_window : float
        Along-track window of the gap rule and the top of canopy (15).
    toc_depth : float
        Canopy photons within this distance of their window's highest canopy photon are
        top of canopy (2).
    ground_filter : DensityParams or None
        Photons that also pass this long, flat box (+-20 m x +-1 m, quantile 0.99),
        counted on heights relative to the first surface's trend, are ground candidates
        too, and the surface is fitted again from the first one: a weak beam's few ground
        photons under a canopy rarely fill the noise filter's box by day, nor do ground
        photons under dense low vegetation, but they lie on one line. The canopy still
        needs the noise filter or the canopy test. None: off (one surface). Calibration
        tiles, 6 azimuths x 3 seeds, night / 1.5 / 4.5 MHz: weak beams' block ground
        median |error| 0.18/0.31/0.54 -> 0.14/0.16/0.23 m, RMSE 1.53/1.41/1.84 ->
        1.28/1.21/1.44 m, blocks estimated 93/98/88 -> 95/99/96 %; strong beams' ground
        RMSE at 4.5 MHz 3.79 -> 0.49 m (one track lost its ground), unchanged at night and
        1.5 MHz (0.16 m). Wyoming clip (a weak beam, daytime): ATL08's ground photons classed
        ground 0.836 -> 0.848, its canopy photons classed canopy 0.820 -> 0.841.
    ground_trend : float
        Half-width (m) of the running mean giving that trend (50).
    sparse_bandwidth : float
        Kernel sigma (m) of the second surface on a sparse track (10: a quarter of the
        photons needs twice the smoothing); it runs all of ``surface.bands``.
    refine_bandwidth : float
        Kernel sigma (m) of the second surface otherwise (7; 10 smoothed a 4 m terrain
        step over 23-27 m instead of 11-17 m).
    refine_bands : tuple of float
        Bands (m) of the second surface's passes otherwise (1, 0.6: it starts from the
        first surface, so the wide passes only cost time).
    """

    filter: DensityParams = field(default_factory=lambda: DensityParams(
        along=10.0, height=1.5, quantile=0.999, segment=200.0, edge_correction=True))
    canopy_filter: DensityParams = field(default_factory=lambda: DensityParams(
        along=20.0, height=3.0, quantile=0.99, segment=200.0, edge_correction=True))
    sparse_canopy_filter: DensityParams = field(default_factory=lambda: DensityParams(
        along=40.0, height=4.0, quantile=0.99, segment=200.0, edge_correction=True))
    sparse_signal: float = 1.2
    surface: SurfaceParams = field(default_factory=SurfaceParams)
    shot_spacing: float = ICESAT2_SHOT_SPACING
    ground_buffer: float = 0.6
    ground_below: float = 1.0
    max_gap: float = 10.0
    top_window: float = 15.0
    toc_depth: float = 2.0
    ground_filter: DensityParams | None = field(default_factory=lambda: DensityParams(
        along=20.0, height=1.0, quantile=0.99, segment=200.0, edge_correction=True))
    ground_trend: float = 50.0
    sparse_bandwidth: float = 10.0
    refine_bandwidth: float = 7.0
    refine_bands: tuple[float, ...] = (1.0, 0.6)

    def __post_init__(self) -> None:
        for name, typ in (("filter", DensityParams), ("canopy_filter", DensityParams),
                          ("sparse_canopy_filter", DensityParams), ("surface", SurfaceParams)):
            if not isinstance(getattr(self, name), typ):
                raise InputError(f"ATL08 classifier {name} must be a {typ.__name__}, got "
                                 f"{type(getattr(self, name)).__name__}")
        if self.ground_filter is not None and not isinstance(self.ground_filter,
                                                             DensityParams):
            raise InputError(f"ATL08 classifier ground_filter must be a DensityParams or "
                             f"None, got {type(self.ground_filter).__name__}")
        for name in ("shot_spacing", "ground_buffer", "ground_below", "max_gap", "top_window",
                     "toc_depth", "sparse_signal", "ground_trend", "sparse_bandwidth",
                     "refine_bandwidth"):
            object.__setattr__(self, name, _positive(getattr(self, name),
                                                     f"ATL08 classifier {name}"))


@dataclass(frozen=True, eq=False)
class Atl08Classes:
    """Result of :func:`classify_photons`, per photon in the track's order.

    Attributes
    ----------
    classes : ndarray int8
        -1 not classified, 0 noise, 1 ground, 2 canopy, 3 top of canopy.
    height : ndarray float64
        Height above the ground surface (m); NaN where not classified.
    surface : GroundSurface
        The ground surface (heights in the track's vertical datum at along-track nodes).
    background : ndarray float64
        Background photons per metre along-track per metre of height used per photon.
    rate_source : str
        ``"bckgrd_rate"`` (from the file) or ``"estimated"`` (from the photons).
    """

    classes: np.ndarray
    height: np.ndarray
    surface: GroundSurface
    background: np.ndarray
    rate_source: str

    def counts(self) -> dict[int, int]:
        """Photons per class code."""
        v, c = np.unique(self.classes, return_counts=True)
        return {int(a): int(b) for a, b in zip(v, c)}


def background_density(track: PhotonTrack, shot_spacing: float = ICESAT2_SHOT_SPACING
                       ) -> np.ndarray | None:
    """Background photons per m along-track per m of height at each photon, from the
    track's ATL03 background rate; None when the track has none."""
    if track.background is None:
        return None
    return track.background.at(track.time) * (2.0 / SPEED_OF_LIGHT) / shot_spacing


def _gap_and_top(win: np.ndarray, hrel: np.ndarray, n_win: int, max_gap: float,
                 toc_depth: float) -> tuple[np.ndarray, np.ndarray]:
    """Per photon (above ground, sorted by window then height): reachable from the ground
    without a gap > max_gap, and within toc_depth of its window's highest reachable one."""
    order, hs, starts, counts = sorted_groups(win, hrel, n_win)
    grp = win[order]
    prev = np.empty_like(hs)
    prev[1:] = hs[:-1]
    first = np.zeros(hs.size, bool)
    first[starts[counts > 0]] = True
    prev[first] = 0.0  # the first photon of a window climbs from the ground
    big = (hs - prev) > max_gap
    cum = np.cumsum(big)
    before = np.zeros(n_win, np.int64)
    before[counts > 0] = cum[starts[counts > 0]] - big[starts[counts > 0]]
    reach_sorted = (cum - before[grp]) == 0
    # the reachable photons of a window are the lowest ones (up to its first big gap), so
    # the highest of them is the last: the same as np.maximum.at, without its slow loop
    n_reach = np.bincount(grp[reach_sorted], minlength=n_win)
    top = np.full(n_win, -np.inf)
    has = n_reach > 0
    top[has] = hs[starts[has] + n_reach[has] - 1]
    toc_sorted = reach_sorted & (hs >= top[grp] - toc_depth)
    reach = np.empty(hs.size, bool)
    toc = np.empty(hs.size, bool)
    reach[order] = reach_sorted
    toc[order] = toc_sorted
    return reach, toc


def _trend(surface: GroundSurface, half: float) -> GroundSurface:
    """The surface smoothed by a running mean over +-``half`` m (its large-scale slope)."""
    k = max(int(round(half / max(float(np.median(np.diff(surface.s))), 1e-9)))
            if surface.s.size > 1 else 0, 0)
    if k == 0 or surface.s.size < 3:
        return surface
    pad = np.concatenate([np.full(k, surface.z[0]), surface.z, np.full(k, surface.z[-1])])
    c = np.concatenate([[0.0], np.cumsum(pad)])
    z = (c[2 * k + 1:] - c[:-2 * k - 1]) / (2 * k + 1)
    return GroundSurface(surface.s, z, surface.supported, surface.candidates)


def _all_noise(track: PhotonTrack, finite: np.ndarray, rate: np.ndarray, source: str
               ) -> Atl08Classes:
    """Every photon noise, no ground (NaN surface over the track's extent)."""
    classes = np.where(finite, CLASS_NOISE, CLASS_NONE).astype(np.int8)
    s = np.asarray(track.s, float)[finite]
    ends = np.array([s.min(), s.max() + 1.0]) if s.size else np.array([0.0, 1.0])
    surface = GroundSurface(ends, np.full(2, np.nan), np.zeros(2, bool),
                            np.zeros(len(track), bool))
    return Atl08Classes(classes, np.full(len(track), np.nan), surface, rate, source)


def classify_photons(track: PhotonTrack, params: Atl08Params | None = None) -> Atl08Classes:
    """Classify a track's photons as ATL08 does (0 noise, 1 ground, 2 canopy, 3 top).

    Parameters
    ----------
    track : PhotonTrack
        Photons in a metric CRS; ``s`` and ``h`` in metres.
    params : Atl08Params, optional

    Returns
    -------
    Atl08Classes

    Fewer than 2 photons passing the noise filter (a beam in cloud) give every photon class
    0 and a NaN ground, with a :class:`~canopyblocks.errors.CanopyBlocksWarning`.
    """
    if not isinstance(track, PhotonTrack):
        raise InputError(f"classify_photons needs a PhotonTrack; got {type(track).__name__}")
    p = Atl08Params() if params is None else params
    if not isinstance(p, Atl08Params):
        raise InputError(f"params must be an Atl08Params; got {type(p).__name__}")
    from .background_check import checked_background
    track = checked_background(track, p.shot_spacing)  # the file's rate, or the photons'
    n = len(track)
    s = np.asarray(track.s, float)
    z = np.asarray(track.h, float)
    finite = np.isfinite(s) & np.isfinite(z)
    rate = background_density(track, p.shot_spacing)
    source = "bckgrd_rate" if rate is not None else "estimated"
    # (the filter's keep and rate only: its counts and thresholds are not needed here)
    signal, bg = _filter(s, z, p.filter, rate, with_rate=True)
    if int(signal.sum()) < 2:
        warnings.warn(
            f"track {track.track} ({track.source or 'in memory'}): {int(signal.sum())} of {n} "
            "photons stand out of the background; every photon is classed noise (is the beam "
            "in cloud?)", CanopyBlocksWarning, stacklevel=2)
        return _all_noise(track, finite, bg, source)
    span = max(float(np.ptp(s[finite])), 1.0)
    sparse = signal.sum() / span < p.sparse_signal
    surface = fit_atl08_surface(s[signal], z[signal], p.surface)
    sp = (replace(p.surface, bandwidth=p.sparse_bandwidth) if sparse else
          replace(p.surface, bandwidth=p.refine_bandwidth, bands=p.refine_bands))
    gsig = signal
    if p.ground_filter is not None:
        # the flat box on heights relative to the first surface's trend (it follows the
        # slope), counted only near that surface: the refit moves by less than its widest
        # band, so farther photons can neither be ground nor be counted by one
        span_z = 2.0 * max(sp.bands) + 2.0 * p.ground_filter.height + p.ground_below
        with np.errstate(invalid="ignore"):
            r1 = z - surface(s)
            near = np.flatnonzero(finite & (np.abs(r1) <= span_z))
        rel = z[near] - _trend(surface, p.ground_trend)(s[near])
        box = _filter(s[near], rel, p.ground_filter,
                      bg[near] if p.ground_filter.background is None else None)[0]
        gsig = signal.copy()
        gsig[near[box]] = True
        with np.errstate(invalid="ignore"):
            fit = np.flatnonzero(gsig & (np.abs(r1) <= 2.0 * max(sp.bands)))
        if fit.size >= 2:
            surface = fit_atl08_surface(s[fit], z[fit], sp, start=surface)
    all_finite = bool(finite.all())
    if all_finite:  # (no copies of the finite photons)
        hrel = surface(s)
        np.subtract(z, hrel, out=hrel)
    else:
        hrel = np.full(n, np.nan)
        hrel[finite] = z[finite] - surface(s[finite])
    # the long, flat canopy test at the same background rate (longer on a sparse track)
    cf = p.sparse_canopy_filter if sparse else p.canopy_filter
    flat = _filter(s, z, cf, bg if cf.background is None else None)[0]
    classes = np.full(n, CLASS_NOISE if all_finite else CLASS_NONE, np.int8)
    if not all_finite:
        classes[finite] = CLASS_NOISE
    with np.errstate(invalid="ignore"):
        ground = gsig & (hrel >= -p.ground_below) & (hrel <= p.ground_buffer)
        above = (signal | flat) & (hrel > p.ground_buffer)
    classes[ground] = CLASS_GROUND
    idx = np.flatnonzero(above)
    if idx.size:
        win = np.floor((s[idx] - np.nanmin(s)) / p.top_window).astype(np.int64)
        n_win = int(win.max()) + 1
        reach, toc = _gap_and_top(win, hrel[idx], n_win, p.max_gap, p.toc_depth)
        classes[idx[reach]] = CLASS_CANOPY
        classes[idx[reach & toc]] = CLASS_TOP
    if log.isEnabledFor(logging.INFO):  # (the tally and median cost a sort each)
        log.info("track %s: ATL08-style classes %s (background %s, median %.3g photons/m^2)",
                 track.track, {int(k): int(v) for k, v in zip(*np.unique(classes,
                                                                         return_counts=True))},
                 source, float(np.median(bg)) if bg.size else 0.0)
    return Atl08Classes(classes, hrel if all_finite else np.where(classes >= 0, hrel, np.nan),
                        surface, bg, source)
