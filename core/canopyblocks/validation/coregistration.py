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
   location of the ground residuals (histogram mode, then two trimmed means); the
   cost is a truncated quadratic ``mean(min(((r - m) / scale)^2, T^2))`` with a fixed
   scale (0.5 m ground, 2 m top), so that a few outlying blocks, vegetation photons in
   a ground window, or positions shifted off the raster cost a bounded, equal amount at
   every candidate. Top residuals have their own free location (a canopy-top estimate
   is biased low against a DSM maximum); their cost is added with a weight.
4. A coarse grid (default +-15 m by 1 m) then a fine grid around its minimum (+-3 m by
   0.25 m). Uncertainties: a bootstrap over blocks (groups of targets) reweighting the
   fine-grid residuals. The optimum is *determined* only when the cost surface has
   contrast and the bootstrap spread of both horizontal components is small; over flat
   terrain the result says so instead of reporting noise.

Sign convention: ``east``, ``north``, ``along_track``, ``cross_track``, ``vertical`` are
the shift (m) to ADD to the track's reported positions and heights. Cross-track is
positive to the right of the direction of travel (90 degrees clockwise from along-track).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..errors import InputError, NoUsableDataError
from ..progress import Progress, as_progress
from ..reference.raster_sampling import RasterSurface
from .coregistration_targets import KIND_GROUND, KIND_TOP, CoregTargets

__all__ = ["CoregParams", "CoregOffset", "CoregResult", "coregister", "track_direction"]

log = logging.getLogger(__name__)

UseTop = Literal["auto", "yes", "no"]
_CHUNK_ELEMENTS = 4_000_000  # candidate x target residuals held at once
_MODE_BINS = 400
_MEAN_SHIFT_ITERATIONS = 8


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
        Bootstrap replicates over groups for the uncertainties (0: none).
    seed : int
        Random seed of the bootstrap and of target subsampling.
    max_targets : int
        At most this many targets of each kind enter the search (a deterministic
        subsample beyond it).
    min_ground : int
        Fewer usable ground targets: the ground alone is not enough.
    max_sd : float
        Largest bootstrap standard deviation (m) of a horizontal component for the
        optimum to count as determined.
    min_contrast : float
        Smallest relative cost contrast ``(median - min) / min`` of the coarse surface
        for the optimum to count as determined.
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
    bootstrap: int = 50
    seed: int = 0
    max_targets: int = 30_000
    min_ground: int = 30
    max_sd: float = 1.5
    min_contrast: float = 0.05

    def __post_init__(self) -> None:
        for name in ("search_range", "step", "fine_step", "fine_range", "ground_scale",
                     "top_scale", "truncate", "max_sd"):
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
        for name in ("bootstrap", "max_targets", "min_ground", "seed"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 0:
                raise InputError(f"coregistration {name} must be a whole number >= 0, got {v!r}")
        if self.max_targets < 10:
            raise InputError(f"max_targets must be at least 10, got {self.max_targets}")
        if not (np.isfinite(self.min_contrast) and self.min_contrast >= 0):
            raise InputError(f"min_contrast must be >= 0, got {self.min_contrast!r}")


@dataclass(frozen=True)
class CoregOffset:
    """The offset found for one track (or for all tracks together).

    All distances in metres; the shift to ADD to reported positions and heights.
    ``*_sd`` are bootstrap standard deviations (NaN without bootstrap). ``rmse_before``
    and ``rmse_after`` are the RMSE of the ground residuals (target minus DTM) of the
    targets inside the raster, before and after applying the shift (the same targets).
    """

    name: str
    east: float
    north: float
    along_track: float
    cross_track: float
    vertical: float
    east_sd: float
    north_sd: float
    along_track_sd: float
    cross_track_sd: float
    vertical_sd: float
    rmse_before: float
    rmse_after: float
    bias_before: float
    bias_after: float
    n_ground: int
    n_top: int
    used_top: bool
    determined: bool
    reason: str
    crs_wkt: str
    along_grid: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    cross_grid: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    cost: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 0)))
    direction: tuple[float, float] = (0.0, 1.0)

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary (no cost surface)."""
        def num(v: float) -> float | None:
            return None if not np.isfinite(v) else round(float(v), 4)

        return {
            "east": num(self.east), "north": num(self.north),
            "along_track": num(self.along_track), "cross_track": num(self.cross_track),
            "vertical": num(self.vertical),
            "uncertainty": {"east": num(self.east_sd), "north": num(self.north_sd),
                            "along_track": num(self.along_track_sd),
                            "cross_track": num(self.cross_track_sd),
                            "vertical": num(self.vertical_sd)},
            "rmse_before": num(self.rmse_before), "rmse_after": num(self.rmse_after),
            "bias_before": num(self.bias_before), "bias_after": num(self.bias_after),
            "n_ground": int(self.n_ground), "n_top": int(self.n_top),
            "used_top": bool(self.used_top), "determined": bool(self.determined),
            "reason": self.reason,
            "along_track_direction": [round(self.direction[0], 6), round(self.direction[1], 6)],
        }


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


# ---------------------------------------------------------------- cost
def _robust_location(r: np.ndarray, scale: float, trunc: float) -> np.ndarray:
    """Per row of ``r`` (candidates x targets; NaN ignored): mode, then trimmed means."""
    k, n = r.shape
    fin = np.isfinite(r)
    has = fin.any(axis=1)
    rowmin = np.where(has, np.nanmin(np.where(fin, r, np.inf), axis=1), 0.0)
    width = scale
    b = np.floor((r - rowmin[:, None]) / width)
    b = np.where(fin, np.clip(b, 0, _MODE_BINS - 1), 0).astype(np.int64)
    counts = np.bincount((np.arange(k)[:, None] * _MODE_BINS + b)[fin],
                         minlength=k * _MODE_BINS).reshape(k, _MODE_BINS)
    # smooth the histogram by 3 bins so a cluster split over two bins is found
    sm = counts.astype(float)
    sm[:, 1:] += counts[:, :-1]
    sm[:, :-1] += counts[:, 1:]
    m = rowmin + (np.argmax(sm, axis=1) + 0.5) * width
    # mean shift with a narrow Gaussian kernel: converges on the mode, so a one-sided
    # tail (understory photons above the ground, canopy below a DSM maximum) does not
    # pull the location the way a mean would
    bw = 0.5 * scale
    rr = np.where(fin, r, 0.0)
    for _ in range(_MEAN_SHIFT_ITERATIONS):
        u = (rr - m[:, None]) / bw
        w = np.where(fin & (np.abs(u) < 4.0), np.exp(-0.5 * u * u), 0.0)
        sw = w.sum(axis=1)
        m = np.where(sw > 0, (w * rr).sum(axis=1) / np.maximum(sw, 1e-300), m)
    return np.where(has, m, np.nan)


def _rho(r: np.ndarray, m: np.ndarray, scale: float, trunc: float) -> np.ndarray:
    """Truncated quadratic per element; NaN residuals cost the truncation."""
    u = (r - m[:, None]) / scale
    with np.errstate(invalid="ignore"):
        rho = np.minimum(u * u, trunc * trunc)
    return np.where(np.isfinite(rho), rho, trunc * trunc)


@dataclass
class _Kind:
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    group: np.ndarray
    surface: RasterSurface
    scale: float


def _residuals(kind: _Kind, a: tuple[float, float], c: tuple[float, float],
               da: np.ndarray, dc: np.ndarray) -> np.ndarray:
    sx = da * a[0] + dc * c[0]
    sy = da * a[1] + dc * c[1]
    vals = kind.surface.bilinear(kind.x[None, :] + sx[:, None], kind.y[None, :] + sy[:, None])
    return kind.z[None, :] - vals


def _surface_costs(kinds: list[tuple[_Kind, float]], a: tuple[float, float],
                   c: tuple[float, float], da: np.ndarray, dc: np.ndarray, trunc: float,
                   progress: Progress) -> tuple[np.ndarray, np.ndarray]:
    """Cost and ground location for each candidate (flattened grids ``da``, ``dc``)."""
    n_el = max(sum(len(k.z) for k, _ in kinds), 1)
    chunk = max(1, _CHUNK_ELEMENTS // n_el)
    cost = np.zeros(len(da))
    loc = np.full(len(da), np.nan)
    for i0 in range(0, len(da), chunk):
        progress.update(i0 / len(da), "searching offsets")
        sl = slice(i0, i0 + chunk)
        for j, (kind, weight) in enumerate(kinds):
            r = _residuals(kind, a, c, da[sl], dc[sl])
            m = _robust_location(r, kind.scale, trunc)
            cost[sl] += weight * _rho(r, m, kind.scale, trunc).mean(axis=1)
            if j == 0:
                loc[sl] = m
    return cost, loc


def _fine_matrices(kinds: list[tuple[_Kind, float]], a: tuple[float, float],
                   c: tuple[float, float], da: np.ndarray, dc: np.ndarray,
                   trunc: float) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Per kind the rho matrix (candidates x targets), the ground residuals and location."""
    rhos = []
    r_ground = np.zeros((0, 0))
    loc = np.zeros(0)
    for j, (kind, _w) in enumerate(kinds):
        r = _residuals(kind, a, c, da, dc)
        m = _robust_location(r, kind.scale, trunc)
        rhos.append(_rho(r, m, kind.scale, trunc))
        if j == 0:
            r_ground, loc = r, m
    return rhos, r_ground, loc


def _rmse_bias(r: np.ndarray, shift: float = 0.0) -> tuple[float, float]:
    v = r[np.isfinite(r)] + shift
    if v.size == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(v * v))), float(np.mean(v))


# ---------------------------------------------------------------- search
def _subsample(idx: np.ndarray, limit: int, rng: np.random.Generator) -> np.ndarray:
    if len(idx) <= limit:
        return idx
    return np.sort(rng.choice(idx, size=limit, replace=False))


def _search_one(name: str, t: CoregTargets, dtm: RasterSurface, dsm: RasterSurface | None,
                direction: tuple[float, float], p: CoregParams, progress: Progress
                ) -> CoregOffset:
    rng = np.random.default_rng(p.seed)
    g_idx = np.flatnonzero((t.kind == KIND_GROUND) & np.isfinite(t.z))
    t_idx = np.flatnonzero((t.kind == KIND_TOP) & np.isfinite(t.z))
    g_idx = _subsample(g_idx, p.max_targets, rng)
    t_idx = _subsample(t_idx, p.max_targets, rng)
    ground = _Kind(t.x[g_idx], t.y[g_idx], t.z[g_idx], t.group[g_idx], dtm, p.ground_scale)
    top = (_Kind(t.x[t_idx], t.y[t_idx], t.z[t_idx], t.group[t_idx], dsm, p.top_scale)
           if dsm is not None and len(t_idx) else None)
    r0 = ground.z - dtm.bilinear(ground.x, ground.y)
    n_ground = int(np.isfinite(r0).sum())
    if n_ground == 0 and top is None:
        raise NoUsableDataError(
            f"track {name}: no ground target lies on the DTM (and no DSM/top targets); "
            "check that the rasters cover the track and share its CRS")
    a = direction
    c = _cross_of(a)
    coarse = np.arange(-p.search_range, p.search_range + 1e-9, p.step)
    ga, gc = np.meshgrid(coarse, coarse, indexing="ij")  # [along, cross]

    def run(use_top: bool, prog: Progress) -> tuple[np.ndarray, np.ndarray]:
        kinds: list[tuple[_Kind, float]] = []
        if n_ground:
            kinds.append((ground, 1.0))
        if use_top and top is not None:
            kinds.append((top, p.top_weight if n_ground else 1.0))
        return _surface_costs(kinds, a, c, ga.ravel(), gc.ravel(), p.truncate, prog)

    want_top = p.use_top == "yes" or (p.use_top == "auto" and n_ground < p.min_ground)
    used_top = bool(want_top and top is not None)
    cost, _ = run(used_top, progress.sub(0.0, 0.45))
    contrast = _contrast(cost)
    if (p.use_top == "auto" and not used_top and top is not None
            and contrast < p.min_contrast):
        log.info("track %s: ground alone gives no contrast (%.3f); adding the canopy top",
                 name, contrast)
        used_top = True
        cost, _ = run(True, progress.sub(0.45, 0.8))
        contrast = _contrast(cost)
    k = int(np.nanargmin(cost))
    ca, cc = float(ga.ravel()[k]), float(gc.ravel()[k])

    fine = np.arange(-p.fine_range, p.fine_range + 1e-9, p.fine_step)
    fa, fc = np.meshgrid(ca + fine, cc + fine, indexing="ij")
    kinds: list[tuple[_Kind, float]] = []
    if n_ground:
        kinds.append((ground, 1.0))
    if used_top and top is not None:
        kinds.append((top, p.top_weight if n_ground else 1.0))
    rhos, r_ground, loc = _fine_matrices(kinds, a, c, fa.ravel(), fc.ravel(), p.truncate)
    weights = [w for _, w in kinds]
    fcost = sum(w * rho.mean(axis=1) for w, rho in zip(weights, rhos))
    kf = int(np.nanargmin(fcost))
    along, cross = float(fa.ravel()[kf]), float(fc.ravel()[kf])
    vertical = -float(loc[kf]) if n_ground else 0.0
    progress.update(0.85, "bootstrap")

    sd = _bootstrap(kinds, rhos, weights, r_ground, loc, fa.ravel(), fc.ravel(), p, rng)
    along_sd, cross_sd, vertical_sd = sd
    east = along * a[0] + cross * c[0]
    north = along * a[1] + cross * c[1]
    # east/north variances from the along/cross ones (taken as independent)
    east_sd = float(np.hypot(along_sd * a[0], cross_sd * c[0]))
    north_sd = float(np.hypot(along_sd * a[1], cross_sd * c[1]))

    reasons = []
    if contrast < p.min_contrast:
        reasons.append(f"the cost surface is flat (contrast {contrast:.3f} < "
                       f"{p.min_contrast}): the terrain does not constrain the position")
    if p.bootstrap and not (np.isfinite(along_sd) and along_sd <= p.max_sd):
        reasons.append(f"along-track uncertainty {along_sd:.2f} m > {p.max_sd} m")
    if p.bootstrap and not (np.isfinite(cross_sd) and cross_sd <= p.max_sd):
        reasons.append(f"cross-track uncertainty {cross_sd:.2f} m > {p.max_sd} m")
    edge = p.search_range - p.step / 2
    if abs(ca) >= edge or abs(cc) >= edge:
        reasons.append(f"the minimum lies on the edge of the +-{p.search_range} m grid; "
                       "widen the search range")
    determined = not reasons
    if n_ground:
        before = _rmse_bias(r0)
        r_after = r_ground[kf]
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
        used_top=used_top, determined=determined,
        reason="; ".join(reasons) if reasons else "ok",
        crs_wkt=dtm.horizontal_crs.to_wkt(), along_grid=coarse, cross_grid=coarse,
        cost=cost.reshape(ga.shape), direction=a,
    )


def _contrast(cost: np.ndarray) -> float:
    lo = float(np.nanmin(cost))
    med = float(np.nanmedian(cost))
    return (med - lo) / lo if lo > 0 else (np.inf if med > 0 else 0.0)


def _bootstrap(kinds: list[tuple[_Kind, float]], rhos: list[np.ndarray], weights: list[float],
               r_ground: np.ndarray, loc: np.ndarray, fa: np.ndarray, fc: np.ndarray,
               p: CoregParams, rng: np.random.Generator) -> tuple[float, float, float]:
    """Bootstrap over groups (blocks): reweight the fine-grid costs, take the argmin."""
    if p.bootstrap == 0 or not kinds:
        return float("nan"), float("nan"), float("nan")
    groups = np.unique(np.concatenate([k.group for k, _ in kinds]))
    draws = rng.integers(0, len(groups), size=(p.bootstrap, len(groups)))
    counts = np.zeros((p.bootstrap, len(groups)))
    np.add.at(counts, (np.repeat(np.arange(p.bootstrap), len(groups)), draws.ravel()), 1.0)
    total = np.zeros((p.bootstrap, len(fa)))
    wts_ground = None
    for (kind, _), rho, w in zip(kinds, rhos, weights):
        wt = counts[:, np.searchsorted(groups, kind.group)]  # replicates x targets
        denom = np.maximum(wt.sum(axis=1, keepdims=True), 1.0)
        total += w * (wt @ rho.T) / denom
        if wts_ground is None:
            wts_ground = wt
    best = np.argmin(total, axis=1)
    along = fa[best]
    cross = fc[best]
    vert = np.full(p.bootstrap, np.nan)
    if wts_ground is not None and r_ground.size:
        r = r_ground[best]  # replicates x ground targets
        inl = np.isfinite(r) & (np.abs(r - loc[best][:, None])
                                <= p.truncate * kinds[0][0].scale)
        wsum = (wts_ground * inl).sum(axis=1)
        vert = -np.where(wsum > 0, (wts_ground * np.where(inl, r, 0.0)).sum(axis=1)
                         / np.maximum(wsum, 1e-12), np.nan)
    return (float(np.std(along, ddof=1)), float(np.std(cross, ddof=1)),
            float(np.nanstd(vert, ddof=1)) if np.isfinite(vert).sum() > 1 else float("nan"))


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
    """
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
        out[name] = _search_one(name, sub, dtm, dsm, directions[name], p,
                                prog.sub(i / n_jobs, (i + 1) / n_jobs))
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
