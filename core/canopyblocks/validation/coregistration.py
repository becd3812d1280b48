"""Geolocation offset search against airborne-lidar rasters (DESIGN 2.8).

Spaceborne lidar is geolocated to a few metres; over slopes and patchy canopy a few
metres of horizontal error become metres of height error. For one track (or all
tracks of a file together) this module searches the along-track, cross-track and
vertical shift that, added to the reported positions and heights, best aligns the
track's ground (and optionally canopy-top) heights with the DTM (and DSM).

Method
------
1. Targets (:class:`~canopyblocks.validation.coregistration_targets.CoregTargets`):
   ground and top heights at map positions, in the rasters' horizontal CRS and
   vertical datum.
2. For each candidate horizontal shift (along ``a``, cross ``c``) the rasters are
   sampled bilinearly at the shifted positions (one vectorised lookup for all
   candidates of a chunk) and the residuals ``r = z - DTM(p + shift)`` formed.
3. The vertical shift is solved in closed form at each candidate as minus the robust
   location of the ground residuals; the cost is a truncated quadratic with a fixed
   scale (0.5 m ground, 2 m top), so that a few outlying blocks, vegetation photons in
   a ground window, or positions shifted off the raster cost a bounded, equal amount at
   every candidate (:mod:`~canopyblocks.validation.coregistration_cost`). Top residuals
   have their own free location; their cost is added with a weight.
4. A coarse grid (default +-15 m by 1 m) then a fine grid around its minimum (+-3 m by
   0.25 m).
5. Checks (:mod:`~canopyblocks.validation.coregistration_checks`): the rasters must
   cover enough of the track (else the search is refused); the offset is *determined*
   only when, fitted on some stretches of the track, it improves the misfit of the
   held-out stretches significantly without making their ground RMSE worse, the surface
   has contrast and the uncertainty is small. The uncertainty is the larger of a
   bootstrap over stretches and the linearised (curvature against noise) one, with the
   DTM's resolution floor (cell / sqrt(12)) added in quadrature; three standard
   deviations are the minimum detectable offset over this terrain.
   An undetermined offset is reported, never applied.

Sign convention: ``east``, ``north``, ``along_track``, ``cross_track``, ``vertical`` are
the shift (m) to ADD to the track's reported positions and heights. Cross-track is
positive to the right of the direction of travel (90 degrees clockwise from along-track).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal

import numpy as np
import pandas as pd

from ..errors import CoverageError, InputError, NoUsableDataError
from ..progress import Progress, as_progress
from ..reference.raster_sampling import RasterSurface
from .coregistration_checks import (
    DETECTABLE_SDS,
    Coverage,
    bootstrap_sd,
    coverage_of,
    held_out_test,
    linearised_sd,
    segments_along,
)
from .coregistration_cost import Kind, residuals, segment_costs
from .coregistration_offset import CoregOffset
from .coregistration_targets import KIND_GROUND, KIND_TOP, CoregTargets

__all__ = ["CoregParams", "CoregOffset", "CoregResult", "coregister", "track_direction"]

log = logging.getLogger(__name__)

UseTop = Literal["auto", "yes", "no"]


@dataclass(frozen=True)
class CoregParams:
    """Parameters of the offset search (metres unless stated).

    Attributes
    ----------
    search_range : float
        Half-width of the coarse grid, along and cross track (default 15 m).
    step : float
        Coarse grid step (1 m).
    fine_step : float
        Fine grid step (0.25 m); the fine grid spans ``fine_range`` around the coarse minimum.
    fine_range : float
        Half-width of the fine grid (3 m).
    use_top : "auto", "yes" or "no"
        Add the canopy-top residuals against the DSM to the cost. ``auto``: when a DSM is
        given and the ground alone leaves the optimum undetermined or has fewer than
        ``min_ground`` targets.
    top_weight : float
        Weight of the top cost relative to the ground cost.
    ground_scale, top_scale : float
        Scales of the truncated-quadratic cost (m).
    truncate : float
        Truncation of the cost, in scales (residuals farther than ``truncate * scale``
        from the location count as outliers).
    bootstrap : int
        Bootstrap replicates over stretches of the track for the uncertainties (0: none).
    seed : int
        Random seed of the bootstrap and of target subsampling.
    max_targets : int
        At most this many targets of each kind enter the search (a deterministic
        subsample beyond it).
    min_ground : int
        Fewer usable ground targets: the ground alone is not enough.
    max_sd : float
        Largest standard deviation (m) of a horizontal component (with the DTM's
        resolution floor) for the optimum to count as determined.
    min_contrast : float
        Smallest relative cost contrast ``(median - min) / min`` of the coarse surface
        for the optimum to count as determined.
    segment : float
        Length (m) of the stretches of track that are held out together and resampled
        by the bootstrap (25 m: longer than an ICESat-2 footprint and a block).
    folds : int
        Number of interleaved folds of stretches for the held-out test.
    significance : float
        One-sided significance level of the held-out improvement.
    min_segments : int
        Fewer stretches of track on valid raster cells: the rasters cover too little of
        the track and the search is refused.
    """

    search_range: float = 15.0
    step: float = 1.0
    fine_step: float = 0.25
    fine_range: float = 3.0
    use_top: UseTop = "auto"
    top_weight: float = 1.0
    ground_scale: float = 0.5
    top_scale: float = 2.0
    truncate: float = 3.0
    bootstrap: int = 200
    seed: int = 0
    max_targets: int = 30_000
    min_ground: int = 30
    max_sd: float = 2.0
    min_contrast: float = 0.05
    segment: float = 25.0
    folds: int = 5
    significance: float = 0.01
    min_segments: int = 6

    def __post_init__(self) -> None:
        from ..arguments import check_fields
        check_fields(self)
        for name in ("search_range", "step", "fine_step", "fine_range", "ground_scale",
                     "top_scale", "truncate", "max_sd", "segment"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"coregistration {name} must be a positive number of "
                                 f"metres, got {v!r}")
        if self.step > self.search_range:
            raise InputError(f"coregistration step ({self.step} m) exceeds the search range "
                             f"({self.search_range} m)")
        if self.search_range / self.step > 200:
            raise InputError(f"coregistration grid of +-{self.search_range} m by {self.step} m "
                             "has over 400 x 400 candidates; use a larger step")
        if self.fine_range / self.fine_step > 100:
            raise InputError("coregistration fine grid has over 200 x 200 candidates; use a "
                             "larger fine_step")
        if self.use_top not in ("auto", "yes", "no"):
            raise InputError(f"use_top must be 'auto', 'yes' or 'no', got {self.use_top!r}")
        if not (np.isfinite(self.top_weight) and self.top_weight >= 0):
            raise InputError(f"top_weight must be >= 0, got {self.top_weight!r}")
        for name in ("bootstrap", "max_targets", "min_ground", "seed", "folds",
                     "min_segments"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 0:
                raise InputError(f"coregistration {name} must be a whole number >= 0, got {v!r}")
        if self.max_targets < 10:
            raise InputError(f"max_targets must be at least 10, got {self.max_targets}")
        if not (np.isfinite(self.min_contrast) and self.min_contrast >= 0):
            raise InputError(f"min_contrast must be >= 0, got {self.min_contrast!r}")
        if self.folds < 2:
            raise InputError(f"coregistration folds must be at least 2, got {self.folds}")
        if self.min_segments < 4:
            raise InputError(f"coregistration min_segments must be at least 4, got "
                             f"{self.min_segments}")
        if not (isinstance(self.significance, float) and 0 < self.significance < 0.5):
            raise InputError(f"coregistration significance must be between 0 and 0.5, got "
                             f"{self.significance!r}")


@dataclass(frozen=True)
class CoregResult:
    """Offsets per track, and ``all`` for one offset fitted to every track together."""

    offsets: dict[str, CoregOffset]
    params: CoregParams

    def to_dict(self) -> dict[str, object]:
        """``{track: {...}, "all": {...}}`` as written to ``offsets.json``."""
        return {name: off.to_dict() for name, off in self.offsets.items()}


# ---------------------------------------------------------------- geometry
def track_direction(x: np.ndarray, y: np.ndarray, s: np.ndarray) -> tuple[float, float]:
    """Unit vector (east, north) of the direction of travel (increasing ``s``).

    The principal axis of the positions, signed so that ``s`` grows along it.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    s = np.asarray(s, float)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(s)
    if ok.sum() < 2:
        raise NoUsableDataError("fewer than two positioned targets: no track direction")
    x, y, s = x[ok], y[ok], s[ok]
    dx, dy, ds = x - x.mean(), y - y.mean(), s - s.mean()
    cov = np.cov(np.vstack([dx, dy]))
    w, v = np.linalg.eigh(cov)
    ax, ay = v[:, int(np.argmax(w))]
    if float(np.dot(ax * dx + ay * dy, ds)) < 0:
        ax, ay = -ax, -ay
    n = float(np.hypot(ax, ay))
    if not n > 0:
        raise NoUsableDataError("targets have no spread along a line: no track direction")
    return float(ax / n), float(ay / n)


def _cross_of(a: tuple[float, float]) -> tuple[float, float]:
    """Right of the direction of travel: 90 degrees clockwise."""
    return a[1], -a[0]


# ---------------------------------------------------------------- search
def _subsample(idx: np.ndarray, limit: int, rng: np.random.Generator) -> np.ndarray:
    if len(idx) <= limit:
        return idx
    return np.sort(rng.choice(idx, size=limit, replace=False))


def _rmse_bias(r: np.ndarray, shift: float = 0.0) -> tuple[float, float]:
    v = r[np.isfinite(r)] + shift
    if v.size == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(v * v))), float(np.mean(v))


def _contrast(cost: np.ndarray) -> float:
    lo = float(np.nanmin(cost))
    med = float(np.nanmedian(cost))
    return (med - lo) / lo if lo > 0 else (np.inf if med > 0 else 0.0)


def _not_covered(name: str, cov: Coverage, p: CoregParams) -> str:
    return (f"the rasters cover {cov.describe()} of track {name}: "
            f"{cov.segments_covered} stretch(es) of {p.segment:g} m, at least "
            f"{p.min_segments} are needed to test an offset")


def _search_one(name: str, t: CoregTargets, dtm: RasterSurface, dsm: RasterSurface | None,
                direction: tuple[float, float], p: CoregParams, progress: Progress,
                refuse: bool = True) -> CoregOffset:
    """The offset of the targets ``t`` (one track, or all together); see the module notes.

    Raises CoverageError (``refuse``) or returns an undetermined offset when the rasters
    cover too little of the track."""
    rng = np.random.default_rng(p.seed)
    a = direction
    c = _cross_of(a)
    codes = pd.factorize(t.track)[0]
    seg_all = segments_along(t.x, t.y, codes, a, p.segment)
    is_g = (t.kind == KIND_GROUND) & np.isfinite(t.z)
    is_t = (t.kind == KIND_TOP) & np.isfinite(t.z) & (dsm is not None)
    valid = np.zeros(len(t), bool)
    valid[is_g] = np.isfinite(dtm.bilinear(t.x[is_g], t.y[is_g]))
    if dsm is not None and is_t.any():
        valid[is_t] = np.isfinite(dsm.bilinear(t.x[is_t], t.y[is_t]))
    cov = coverage_of(valid, t.group, seg_all)
    if cov.segments_covered < p.min_segments:
        msg = _not_covered(name, cov, p)
        if refuse:
            raise CoverageError(msg + "; give rasters that cover the track (in the track's "
                                "CRS or one it can be transformed to)")
        return _undetermined(name, dtm, a, cov, msg)
    # segments without a valid target carry no information: leave them out
    keep_seg = np.zeros(int(seg_all.max()) + 1, bool)
    keep_seg[seg_all[valid]] = True
    seg_ids = np.cumsum(keep_seg) - 1
    n_seg = int(keep_seg.sum())
    g_idx = _subsample(np.flatnonzero(is_g & keep_seg[seg_all]), p.max_targets, rng)
    t_idx = _subsample(np.flatnonzero(is_t & keep_seg[seg_all]), p.max_targets, rng)
    ground = Kind(t.x[g_idx], t.y[g_idx], t.z[g_idx], seg_ids[seg_all[g_idx]], dtm,
                  p.ground_scale)
    top = (Kind(t.x[t_idx], t.y[t_idx], t.z[t_idx], seg_ids[seg_all[t_idx]], dsm,
                p.top_scale, p.top_weight) if dsm is not None and len(t_idx) else None)
    r0 = ground.z - dtm.bilinear(ground.x, ground.y)
    n_ground = int(np.isfinite(r0).sum())
    coarse = np.arange(-p.search_range, p.search_range + 1e-9, p.step)
    ga, gc = np.meshgrid(coarse, coarse, indexing="ij")  # [along, cross]

    def kinds_for(use_top: bool) -> list[Kind]:
        ks = [ground]
        if use_top and top is not None:
            top.weight = p.top_weight if n_ground else 1.0
            ks.append(top)
        return ks

    want_top = p.use_top == "yes" or (p.use_top == "auto" and n_ground < p.min_ground)
    used_top = bool(want_top and top is not None)
    seg_cost, _ = segment_costs(kinds_for(used_top), a, c, ga.ravel(), gc.ravel(), n_seg,
                                p.truncate, progress.sub(0.0, 0.45))
    contrast = _contrast(seg_cost.sum(axis=1))
    if (p.use_top == "auto" and not used_top and top is not None
            and contrast < p.min_contrast):
        log.info("track %s: ground alone gives no contrast (%.3f); adding the canopy top",
                 name, contrast)
        used_top = True
        seg_cost, _ = segment_costs(kinds_for(True), a, c, ga.ravel(), gc.ravel(), n_seg,
                                    p.truncate, progress.sub(0.45, 0.8))
        contrast = _contrast(seg_cost.sum(axis=1))
    cost = seg_cost.sum(axis=1)
    k = int(np.nanargmin(cost))
    ca, cc = float(ga.ravel()[k]), float(gc.ravel()[k])

    # fine grid around the coarse minimum, and the no-shift candidate (the last one)
    fine = np.arange(-p.fine_range, p.fine_range + 1e-9, p.fine_step)
    fa, fc = np.meshgrid(ca + fine, cc + fine, indexing="ij")
    kinds = kinds_for(used_top)
    fda = np.concatenate([fa.ravel(), [0.0]])
    fdc = np.concatenate([fc.ravel(), [0.0]])
    fine_cost, fine_loc = segment_costs(kinds, a, c, fda, fdc, n_seg, p.truncate)
    kf = int(np.nanargmin(fine_cost[:-1].sum(axis=1)))
    along, cross = float(fda[kf]), float(fdc[kf])
    vertical = -float(fine_loc[kf]) if n_ground else 0.0
    progress.update(0.85, "held-out test")

    all_cost = np.vstack([seg_cost, fine_cost])
    all_da = np.concatenate([ga.ravel(), fda])
    all_dc = np.concatenate([gc.ravel(), fdc])
    held = held_out_test(all_cost, len(all_da) - 1, all_da, all_dc, ground, a, c,
                         p.folds, p.significance)
    boot_a, boot_c = bootstrap_sd(all_cost, all_da, all_dc, p.bootstrap, rng)
    lin_a, lin_c, vertical_sd = linearised_sd(kinds, a, c, along, cross, p.truncate, n_seg)
    # the DTM's cells are averages: where the terrain lies inside a cell is unknown, a
    # floor of cell / sqrt(12) (a uniform position error over one cell) in quadrature
    floor = max(abs(dtm.dx), abs(dtm.dy)) / np.sqrt(12.0)
    along_sd = float(np.hypot(np.nanmax([boot_a, lin_a]), floor)) \
        if np.isfinite([boot_a, lin_a]).any() else float("nan")
    cross_sd = float(np.hypot(np.nanmax([boot_c, lin_c]), floor)) \
        if np.isfinite([boot_c, lin_c]).any() else float("nan")
    east = along * a[0] + cross * c[0]
    north = along * a[1] + cross * c[1]
    # east/north variances from the along/cross ones (taken as independent)
    east_sd = float(np.hypot(along_sd * a[0], cross_sd * c[0]))
    north_sd = float(np.hypot(along_sd * a[1], cross_sd * c[1]))

    reasons = []
    if contrast < p.min_contrast:
        reasons.append(f"the cost surface is flat (contrast {contrast:.3f} < "
                       f"{p.min_contrast}): the terrain does not constrain the position")
    if not held.significant:
        reasons.append(f"no significant improvement on held-out blocks (signed-rank score "
                       f"{held.t:.1f}, needs > {held.critical:.1f}, over {held.n_segments} "
                       f"stretches of {p.segment:g} m)")
    if held.worse:
        reasons.append(f"the held-out ground RMSE gets worse ({held.rmse_before:.2f} -> "
                       f"{held.rmse_after:.2f} m)")
    if not (np.isfinite(along_sd) and along_sd <= p.max_sd):
        reasons.append(f"along-track uncertainty {along_sd:.2f} m > {p.max_sd} m")
    if not (np.isfinite(cross_sd) and cross_sd <= p.max_sd):
        reasons.append(f"cross-track uncertainty {cross_sd:.2f} m > {p.max_sd} m")
    edge = p.search_range - p.step / 2
    if abs(ca) >= edge or abs(cc) >= edge:
        reasons.append(f"the minimum lies on the edge of the +-{p.search_range:g} m grid")
    mdo_a, mdo_c = DETECTABLE_SDS * along_sd, DETECTABLE_SDS * cross_sd
    if reasons and np.isfinite(mdo_a) and np.isfinite(mdo_c):
        reasons.append(f"offsets under {mdo_a:.1f} m along and {mdo_c:.1f} m across the "
                       "track cannot be detected here")
    if n_ground:
        r_after = residuals(ground, a, c, np.array([along]), np.array([cross]))[0]
        ok = np.isfinite(r0) & np.isfinite(r_after)
        after = _rmse_bias(r_after[ok], vertical)
        before = _rmse_bias(r0[ok])
    else:
        before = after = (float("nan"), float("nan"))
    return CoregOffset(
        name=name, east=east, north=north, along_track=along, cross_track=cross,
        vertical=vertical, east_sd=east_sd, north_sd=north_sd, along_track_sd=along_sd,
        cross_track_sd=cross_sd, vertical_sd=vertical_sd,
        rmse_before=before[0], rmse_after=after[0], bias_before=before[1],
        bias_after=after[1], n_ground=n_ground, n_top=len(t_idx) if used_top else 0,
        used_top=used_top, determined=not reasons,
        reason="; ".join(reasons) if reasons else "ok",
        crs_wkt=dtm.horizontal_crs.to_wkt(), along_grid=coarse, cross_grid=coarse,
        cost=cost.reshape(ga.shape), direction=a,
        detectable_along=mdo_a, detectable_cross=mdo_c, coverage=cov,
        heldout_t=held.t, heldout_critical=held.critical,
        heldout_rmse_before=held.rmse_before, heldout_rmse_after=held.rmse_after,
        n_segments=n_seg,
    )


def _undetermined(name: str, dtm: RasterSurface, a: tuple[float, float], cov: Coverage,
                  reason: str) -> CoregOffset:
    nan = float("nan")
    return CoregOffset(
        name=name, east=nan, north=nan, along_track=nan, cross_track=nan, vertical=nan,
        east_sd=nan, north_sd=nan, along_track_sd=nan, cross_track_sd=nan, vertical_sd=nan,
        rmse_before=nan, rmse_after=nan, bias_before=nan, bias_after=nan, n_ground=0,
        n_top=0, used_top=False, determined=False, reason=reason,
        crs_wkt=dtm.horizontal_crs.to_wkt(), direction=a, coverage=cov)


def coregister(targets: CoregTargets, dtm: RasterSurface, dsm: RasterSurface | None = None,
               params: CoregParams | None = None, *, joint: bool = True,
               progress: Progress | None = None) -> CoregResult:
    """Search the geolocation offset of each track, and of all tracks together.

    Parameters
    ----------
    targets : CoregTargets
        Ground/top heights at positions in the rasters' horizontal CRS and vertical
        datum (see :mod:`~canopyblocks.validation.coregistration_targets`).
    dtm : RasterSurface
        Terrain raster (m).
    dsm : RasterSurface, optional
        Canopy surface (maximum) raster on any grid of the same CRS, for the top cost.
    params : CoregParams, optional
    joint : bool
        Also fit one offset to all tracks together (entry ``"all"``).
    progress : Progress, optional

    Returns
    -------
    CoregResult
        ``offsets[track]`` per track and ``offsets["all"]``.

    Raises
    ------
    CoverageError
        The rasters cover too little of the track (of every track together), naming the
        share of its blocks on valid cells.
    """
    from ..arguments import check_instance, check_optional
    check_instance(targets, CoregTargets, "coregister: targets", "CoregTargets (targets_from_photons / targets_from_table)")
    check_instance(dtm, RasterSurface, "coregister: dtm", "a RasterSurface (open the DTM raster)")
    check_optional(params, CoregParams, "coregister: params")
    p = params or CoregParams()
    prog = as_progress(progress)
    names = list(dict.fromkeys(targets.track.tolist()))
    if not names:
        raise NoUsableDataError("no targets to co-register")
    out: dict[str, CoregOffset] = {}
    directions: dict[str, tuple[float, float]] = {}
    n_jobs = len(names) + (1 if joint and len(names) > 1 else 0)
    for i, name in enumerate(names):
        sel = targets.track == name
        sub = targets.subset(sel)
        directions[name] = track_direction(sub.x, sub.y, sub.s)
        # with several tracks, one that misses the rasters is reported undetermined;
        # the joint search (or a single track) refuses
        out[name] = _search_one(name, sub, dtm, dsm, directions[name], p,
                                prog.sub(i / n_jobs, (i + 1) / n_jobs),
                                refuse=len(names) == 1)
    if len(names) > 1 and not joint and not any(
            o.coverage is not None and o.coverage.segments_covered >= p.min_segments
            for o in out.values()):
        raise CoverageError(f"{out[names[0]].reason}; give rasters that cover the tracks")
    if joint:
        if len(names) == 1:
            out["all"] = _renamed(out[names[0]], "all")
        else:
            first = directions[names[0]]
            vx = vy = 0.0
            for d in directions.values():
                sgn = 1.0 if d[0] * first[0] + d[1] * first[1] >= 0 else -1.0
                vx += sgn * d[0]
                vy += sgn * d[1]
            n = float(np.hypot(vx, vy))
            joint_dir = (vx / n, vy / n) if n > 0 else first
            # keep each track's groups distinct in the bootstrap
            out["all"] = _search_one("all", targets, dtm, dsm, joint_dir, p,
                                     prog.sub((n_jobs - 1) / n_jobs, 1.0))
    prog.report(1.0, "offsets found")
    return CoregResult(out, p)


def _renamed(off: CoregOffset, name: str) -> CoregOffset:
    from dataclasses import replace

    return replace(off, name=name)
