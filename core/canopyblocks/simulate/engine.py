"""Simulate ICESat-2/MABEL photons along a track over an airborne point cloud.

The footprint contents and truth are computed once per shot; photons for all
realisations are drawn at once from the same footprint PDFs (a chunk of shots at a
time: bounded memory, no loop over photons).  All random numbers of a run are drawn
up front in shot order (counts, geolocation errors, one uniform and one normal per
signal photon, then noise), so a seed gives the same photons whatever the chunking.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pyproj

from ..errors import InputError, NoUsableDataError
from ..photons import BackgroundRate, PhotonTrack
from ..progress import Progress, as_progress
from ..readers.cloud_checks import refuse_all_noise
from ..readers.las import LasPoints
from ..reference.footprint_index import CloudIndex, _ranges
from .params import SimParams
from .sampling import draw_noise, pick_sources
from .telemetry import telemetry_window
from .tracks import SimTrack, shots_along
from .truth import RH_LEVELS, footprint_truth

if TYPE_CHECKING:
    import geopandas as gpd
    import pandas as pd

__all__ = ["Simulation", "simulate_photons", "cloud_index", "TRUTH_COLUMNS",
           "PHOTON_TRUTH_COLUMNS"]

log = logging.getLogger(__name__)

#: Per-footprint truth columns of :attr:`Simulation.truth`.
TRUTH_COLUMNS: tuple[str, ...] = ("ground", "top", *(f"rh{q}" for q in RH_LEVELS), "cover",
                                  "n_points", "weight_sum")

#: Per-photon truth columns carried in ``PhotonTrack.extra`` and the output files.
PHOTON_TRUTH_COLUMNS: tuple[str, ...] = ("shot", "realisation", "noise", "src_index", "src_x",
                                         "src_y", "src_z", "truth_ground", "truth_top",
                                         "truth_cover", "x_true", "y_true")

#: Along-track length of one chunk of shots, metres (one footprint query each; chunks
#: also end at the track's vertices, so each is straight).  Results do not depend on it.
CHUNK_LENGTH = 100.0

SHOTS_PER_BACKGROUND_SUM = 50
"""ATLAS sums the background over 50 shots (200 Hz): one ``bckgrd_atlas`` row each."""


@dataclass(eq=False)
class Simulation:
    """Result of :func:`simulate_photons`: shots with truth, and photons with truth.

    Attributes
    ----------
    params : SimParams
    track : SimTrack
    crs : pyproj.CRS
        The point cloud's metric CRS (x/y of shots and photons).
    vertical_datum : str
        The point cloud's vertical datum (photon heights are in it).
    n_realisations : int
    shot_x, shot_y, shot_s, shot_time : ndarray float64
        Footprint centres (m), along-track distance (m), time (s) per shot.
    truth : dict[str, ndarray]
        Per-shot truth (:data:`TRUTH_COLUMNS`; see ``truth.py`` for definitions).
    photons : dict[str, ndarray]
        Per-photon columns sorted by (realisation, shot): ``realisation``, ``shot``,
        ``time``, ``x``, ``y`` (reported position = footprint centre + geolocation
        error), ``s``, ``h`` and truth ``noise`` (bool), ``src_index`` (the source point's
        ``LasPoints.rows``: its row in the input files, -1 for noise),
        ``src_x``, ``src_y``, ``src_z``, ``x_true``, ``y_true`` (footprint centre).
    telemetry_bottom, telemetry_top : ndarray float64 or None
        Per shot, the height window (metres, the cloud's vertical datum) the background
        photons fall in: the coarse terrain -/+ ``params.telemetry_window``; NaN where
        the track has not reached the cloud yet or has left it; None without background.
    """

    params: SimParams
    track: SimTrack
    crs: pyproj.CRS
    vertical_datum: str
    n_realisations: int
    shot_x: np.ndarray
    shot_y: np.ndarray
    shot_s: np.ndarray
    shot_time: np.ndarray
    truth: dict[str, np.ndarray]
    photons: dict[str, np.ndarray]
    seed: int | None = None
    source: str = ""
    meta: dict[str, object] = field(default_factory=dict)
    telemetry_bottom: np.ndarray | None = None
    telemetry_top: np.ndarray | None = None

    @property
    def n_shots(self) -> int:
        return int(self.shot_s.size)

    @property
    def length(self) -> float:
        """Simulated track length, metres."""
        return float(self.shot_s[-1] - self.shot_s[0]) if self.n_shots else 0.0

    def photon_columns(self, realisation: int | None = 0) -> dict[str, np.ndarray]:
        """Photon columns (with per-photon truth) of one realisation, or all (None)."""
        ph = self.photons
        if realisation is None:
            sel = slice(None)
        else:
            if not (0 <= realisation < self.n_realisations):
                raise InputError(f"realisation must be in 0..{self.n_realisations - 1}; "
                                 f"got {realisation}")
            r = ph["realisation"]
            sel = slice(int(np.searchsorted(r, realisation, "left")),
                        int(np.searchsorted(r, realisation, "right")))
        cols = {k: v[sel] for k, v in ph.items()}
        shot = cols["shot"]
        cols["truth_ground"] = self.truth["ground"][shot]
        cols["truth_top"] = self.truth["top"][shot]
        cols["truth_cover"] = self.truth["cover"][shot]
        return cols

    def background_rate(self) -> BackgroundRate:
        """The background rate as ATL03 records it: every 50 shots from the first, the
        start time (s, the photons' clock) and the rate (photons/s; 0 without noise)."""
        first = np.arange(0, max(self.n_shots, 1), SHOTS_PER_BACKGROUND_SUM)
        t = self.shot_time[first] if self.n_shots else np.zeros(1)
        return BackgroundRate(time=t, rate=np.full(t.size, self.params.background_rate_mhz * 1e6))

    def photon_track(self, realisation: int = 0, *, name: str | None = None) -> PhotonTrack:
        """One realisation as a :class:`~canopyblocks.photons.PhotonTrack`.

        ``x``/``y`` are in the cloud's CRS, ``s`` is the distance along the simulated
        track, ``time`` = shot index / pulse rate; truth columns go to ``extra``;
        ``background`` = :meth:`background_rate`, as a written file gives it.
        """
        c = self.photon_columns(realisation)
        extra = {k: c[k] for k in PHOTON_TRUTH_COLUMNS}
        return PhotonTrack.from_xy(
            c["x"], c["y"], c["h"], crs=self.crs, track=name or self.track.name,
            time=c["time"], s=c["s"], extra=extra, source=self.source,
            vertical_datum=self.vertical_datum, background=self.background_rate())

    def truth_frame(self) -> gpd.GeoDataFrame:
        """Per-shot truth as a point GeoDataFrame in the cloud's CRS."""
        import geopandas as gpd

        data = {"shot": np.arange(self.n_shots), "s": self.shot_s, "time": self.shot_time,
                "x": self.shot_x, "y": self.shot_y, **self.truth}
        return gpd.GeoDataFrame(data, geometry=gpd.points_from_xy(self.shot_x, self.shot_y),
                                crs=self.crs)

    def photon_frame(self, realisation: int | None = None) -> pd.DataFrame:
        """Photons (all realisations by default) with truth as a point GeoDataFrame."""
        import geopandas as gpd

        c = self.photon_columns(realisation)
        return gpd.GeoDataFrame(c, geometry=gpd.points_from_xy(c["x"], c["y"]), crs=self.crs)


def _chunks(track: SimTrack, s: np.ndarray,
            spacing: float) -> list[tuple[int, int, tuple[float, float, float, float]]]:
    """Runs ``[a, b)`` of shots at most ``CHUNK_LENGTH`` long, each on one track segment
    (given as ``(x0, y0, x1, y1)``)."""
    v = np.asarray(track.vertices, dtype=np.float64)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(v, axis=0).T))])
    # first shot of each segment (a shot on a vertex starts the next segment)
    first = np.searchsorted(s, cum[:-1], side="left")
    per = max(1, int(math.ceil(CHUNK_LENGTH / spacing)))
    out: list[tuple[int, int, tuple[float, float, float, float]]] = []
    for i in range(len(v) - 1):
        a0, b0 = int(first[i]), int(first[i + 1]) if i + 2 < len(v) else int(s.size)
        seg = (float(v[i, 0]), float(v[i, 1]), float(v[i + 1, 0]), float(v[i + 1, 1]))
        out.extend((a, min(a + per, b0), seg) for a in range(a0, b0, per))
    return out


def cloud_index(points: LasPoints, params: SimParams | None = None) -> CloudIndex:
    """Grid index over the points the simulator uses: finite, not in ``exclude_classes``.

    Build it once to run several simulations over the same cloud (``index=``).
    """
    params = params or SimParams()
    keep = np.isfinite(points.x) & np.isfinite(points.y) & np.isfinite(points.z)
    if params.exclude_classes:
        refuse_all_noise(points.classification, ", ".join(points.sources) or "the points",
                         tuple(params.exclude_classes))
        keep &= ~np.isin(points.classification, params.exclude_classes)
    ids = np.flatnonzero(keep)
    return CloudIndex(points.x[ids], points.y[ids], points.z[ids], ids=points.rows[ids])


MAX_SIMULATED_ITEMS = 100_000_000
"""Refuse a simulation expected to hold more photons or footprint-point pairs than this
(each costs tens of bytes in several arrays: 1e8 is a few GiB)."""


_SIZE_KNOBS = {"shot_spacing": "shot_spacing", "mean_photons": "mean_photons",
               "background_rate_mhz": "the background noise rate background_rate_mhz "
                                      "(or the telemetry_window)"}


def check_simulation_size(points: LasPoints, track: SimTrack, params: SimParams,
                          realisations: int) -> None:
    """Estimate shots, photons and footprint-point pairs; refuse absurd parameters.

    Raises
    ------
    InputError
        The estimate exceeds :data:`MAX_SIMULATED_ITEMS`; the message names the
        parameter that makes it large.
    """
    spacing = float(params.shot_spacing)  # type: ignore[arg-type]
    shots = track.length / spacing + 1.0
    # the points' own extent (not LasPoints.bounds, which refuses a cloud on a line)
    area = max(float(np.ptp(points.x)) * float(np.ptp(points.y)), 1.0) if len(points) else 1.0
    per_footprint = len(points) / area * np.pi * params.radius ** 2
    estimates = {
        "shot_spacing": shots * max(per_footprint, 1.0),
        "mean_photons": shots * realisations * params.photon_mean,
        "background_rate_mhz": (shots * realisations * params.noise_per_shot_per_m
                                * 2.0 * params.telemetry_window),
    }
    name, worst = max(estimates.items(), key=lambda kv: kv[1])
    if not worst <= MAX_SIMULATED_ITEMS:
        raise InputError(
            f"these simulation parameters would make about {worst:.2g} "
            f"{'footprint-point pairs' if name == 'shot_spacing' else 'photons'} "
            f"({shots:.3g} shots x {realisations} realisations; limit "
            f"{MAX_SIMULATED_ITEMS:.0e}, several GiB of memory): reduce "
            f"{_SIZE_KNOBS[name]} "
            f"(now {getattr(params, name) if name != 'mean_photons' else params.photon_mean:g})"
            ", the number of realisations or the track length")


def simulate_photons(
    points: LasPoints,
    track: SimTrack,
    params: SimParams | None = None,
    *,
    realisations: int = 1,
    seed: int | None = 0,
    index: CloudIndex | None = None,
    progress: Progress | None = None,
) -> Simulation:
    """Simulate photon-counting lidar along ``track`` over an airborne cloud (seed 002).

    Parameters
    ----------
    points : LasPoints
        Airborne points in a metric CRS; ``params.exclude_classes`` are ignored.
    track : SimTrack
        Polyline in the cloud's CRS, metres.
    params : SimParams, optional
        Footprint, photon rate, PSF, background noise, geolocation error (defaults:
        ICESat-2 strong beam, 13 m, temperate 1.9 photons per shot, no background).
        Background photons fall uniformly in a telemetry window that follows the
        coarse terrain (:mod:`~canopyblocks.simulate.telemetry`), at
        ``background_rate_mhz``.
    realisations : int
        Independent photon draws from the same footprint PDFs (seed 002 used 100).
    seed : int or None
        Seed of the numpy Generator; the same seed gives identical photons.
    index : CloudIndex, optional
        :func:`cloud_index` of the same ``points`` (and ``exclude_classes``), to reuse
        across runs; built here when None.
    progress : Progress, optional

    Returns
    -------
    Simulation

    Raises
    ------
    NoUsableDataError
        When no footprint along the track contains a point.
    """
    from ..arguments import check_instance
    check_instance(points, LasPoints, "simulate_photons: points", "airborne points (read_las)")
    check_instance(track, SimTrack, "simulate_photons: track", "a SimTrack (line_through)")
    params = params or SimParams()
    if not (isinstance(realisations, (int, np.integer)) and realisations >= 1):
        raise InputError(f"realisations must be an integer >= 1; got {realisations!r}")
    if seed is not None and not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise InputError(f"seed must be an integer >= 0 (or None); got {seed!r}")
    try:
        return _simulate(points, track, params, int(realisations), seed, index, progress)
    except (InputError, NoUsableDataError) as exc:  # say which cloud the problem is in
        names = ", ".join(points.sources)
        if not names or names in str(exc):
            raise
        raise type(exc)(f"{names}: {exc}") from None


def _simulate(points: LasPoints, track: SimTrack, params: SimParams, realisations: int,
              seed: int | None, index: CloudIndex | None,
              progress: Progress | None) -> Simulation:
    """:func:`simulate_photons` after its argument checks."""
    prog = as_progress(progress)
    if index is None:
        index = cloud_index(points, params)
    n_real = int(realisations)
    check_simulation_size(points, track, params, n_real)
    sx, sy, ss = shots_along(track, float(params.shot_spacing))  # type: ignore[arg-type]
    n = ss.size
    radius, psf = params.radius, params.psf
    # all random numbers up front, in shot order: the photons of a seed do not depend
    # on the chunks below (counts at shots without points are dropped afterwards)
    rng = np.random.default_rng(seed)
    counts = rng.poisson(params.photon_mean, size=(n_real, n))
    err = (rng.standard_normal((2, n_real, n)) * params.geolocation_sigma
           if params.geolocation_sigma > 0 else None)
    flat = counts.ravel()
    total = int(flat.sum())
    u_pick = rng.random(total)
    h_err = rng.standard_normal(total) * psf
    real = np.repeat(np.repeat(np.arange(n_real, dtype=np.int64), n), flat)
    shot = np.repeat(np.tile(np.arange(n, dtype=np.int64), n_real), flat)
    offset = np.zeros(flat.size + 1, np.int64)
    np.cumsum(flat, out=offset[1:])
    src = np.full(total, -1, np.int64)  # source point: row in the index
    truth = {c: np.full(n, np.nan) for c in TRUTH_COLUMNS}
    truth["n_points"] = np.zeros(n, np.int64)
    chunks = _chunks(track, ss, float(params.shot_spacing))  # type: ignore[arg-type]
    prog.update(0.0, f"{n:,} shots in {len(chunks)} chunks")
    for a, b, segment in chunks:
        pairs = index.pairs(sx[a:b], sy[a:b], radius, line=segment)
        t = footprint_truth(pairs, psf, params.truth, params.rh_floor)
        for c in TRUTH_COLUMNS:
            truth[c][a:b] = t[c]
        # the chunk's photons: shots a..b-1 of every realisation
        r0 = np.arange(n_real, dtype=np.int64) * n
        ph = _ranges(offset[r0 + a], offset[r0 + b] - offset[r0 + a])
        pick = pick_sources(pairs, shot[ph] - a, u_pick[ph])
        got = pick >= 0
        src[ph[got]] = pairs.point_of(pick[got])
        prog.update(b / n, f"{b:,} of {n:,} shots")
    if not np.any(truth["n_points"] > 0):
        raise NoUsableDataError(
            f"no airborne point lies within {radius} m of the track {track.vertices}: "
            "the track misses the point cloud")
    keep = src >= 0
    real, shot, src = real[keep], shot[keep], src[keep]
    h = index.z[src] + h_err[keep]
    noise = np.zeros(h.size, bool)
    t_lo = t_hi = None
    if params.background_rate_mhz > 0:
        # one window from the coarse terrain (never a footprint's truth), from the first
        # shot that reaches the cloud to the last
        t_lo, t_hi = telemetry_window(points, track, ss, half_height=params.telemetry_window,
                                      smoothing=params.telemetry_smoothing,
                                      exclude_classes=params.exclude_classes)
        covered = np.flatnonzero(truth["n_points"] > 0)
        outside = np.ones(n, bool)
        outside[covered[0]:covered[-1] + 1] = False
        t_lo[outside] = np.nan
        t_hi[outside] = np.nan
        nr, ns, nh = draw_noise(t_lo, t_hi, params.noise_per_shot_per_m, n_real, rng)
        real = np.concatenate([real, nr])
        shot = np.concatenate([shot, ns])
        h = np.concatenate([h, nh])
        src = np.concatenate([src, np.full(nr.size, -1, np.int64)])
        noise = np.concatenate([noise, np.ones(nr.size, bool)])
    x_true, y_true = sx[shot], sy[shot]
    if err is not None:
        x_rep, y_rep = x_true + err[0][real, shot], y_true + err[1][real, shot]
    else:
        x_rep, y_rep = x_true, y_true
    ok = src >= 0
    src_xyz = [np.full(src.size, np.nan) for _ in range(3)]
    for arr, col in zip(src_xyz, (index.x, index.y, index.z)):
        arr[ok] = col[src[ok]]
    src[ok] = index.ids[src[ok]]
    photons = {"realisation": real, "shot": shot, "h": h, "noise": noise, "src_index": src,
               "src_x": src_xyz[0], "src_y": src_xyz[1], "src_z": src_xyz[2],
               "x": x_rep, "y": y_rep, "x_true": x_true, "y_true": y_true}
    # order by (realisation, shot, height descending as ATL03 photons of a pulse arrive)
    order = np.lexsort((-photons["h"], photons["shot"], photons["realisation"]))
    photons = {key: v[order] for key, v in photons.items()}
    photons["realisation"] = photons["realisation"].astype(np.int32)
    photons["s"] = ss[photons["shot"]]
    photons["time"] = photons["shot"] / float(params.pulse_rate)  # type: ignore[arg-type]
    log.info("simulated %d photons over %d shots x %d realisations", photons["h"].size, n,
             realisations)
    return Simulation(
        params=params, track=track, crs=points.crs, vertical_datum=points.vertical_datum,
        n_realisations=int(realisations), shot_x=sx, shot_y=sy, shot_s=ss,
        shot_time=np.arange(n) / float(params.pulse_rate),  # type: ignore[arg-type]
        truth=truth, photons=photons, seed=seed, source=";".join(points.sources),
        telemetry_bottom=t_lo, telemetry_top=t_hi)
