"""Whether an offset found by the search is real: coverage, held-out test, uncertainty.

An offset search always finds a minimum; over textured terrain with noisy heights that
minimum can sit metres away from the truth while the in-sample misfit improves a little.
These checks decide whether a found offset may be reported as determined and applied:

* **Coverage** -- the track is cut into *segments* (stretches of ``segment`` metres
  along the track, per track); a block is covered when one of its targets lies on a valid
  raster cell at the reported position. Too few covered segments: the rasters do not
  cover the track well enough for any answer, and the caller refuses.
* **Held-out test** -- the segments are dealt into ``folds`` interleaved folds (every
  k-th segment along the track). For each fold the offset is fitted on the other folds and
  the misfit of the held-out segments is compared at that offset and at no offset; the
  per-segment improvements over all folds are tested with a one-sided Wilcoxon
  signed-rank test (normal score; a few stretches on steep ground gain far more than the
  rest, which would drown a t test). The offset is determined only when the held-out
  improvement is significant, its total is positive, and the held-out ground RMSE does
  not get worse.
* **Uncertainty** -- a bootstrap over segments of the whole cost surface (coarse and fine
  candidates), and the linearised (sandwich) covariance of the shift from the raster's
  gradients at the targets against the residuals' scatter, segments as clusters (the
  cost surface's curvature against its noise). The larger of the two is reported; three
  times it is the *minimum detectable offset* for this terrain's texture and these
  heights' noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .coregistration_cost import Kind, residuals, robust_location

__all__ = ["Coverage", "HeldOut", "segments_along", "coverage_of", "held_out_test",
           "signed_rank_score", "bootstrap_sd", "linearised_sd", "DETECTABLE_SDS"]

#: The minimum detectable offset, in standard deviations.
DETECTABLE_SDS = 3.0
_GRADIENT_STEP = 1.0  # m, half the finite-difference baseline


@dataclass(frozen=True)
class Coverage:
    """How much of a track the rasters cover (blocks and segments with a valid cell)."""

    blocks: int
    blocks_covered: int
    segments: int
    segments_covered: int

    @property
    def share(self) -> float:
        """Share of the track's blocks with a valid raster cell (0..1)."""
        return self.blocks_covered / self.blocks if self.blocks else 0.0

    def describe(self) -> str:
        """``"12 of 40 blocks (30 %)"``."""
        return (f"{self.blocks_covered} of {self.blocks} blocks "
                f"({100.0 * self.share:.0f} %)")


@dataclass(frozen=True)
class HeldOut:
    """Result of the held-out test.

    ``improvement`` is the mean over held-out segments of the misfit at no offset minus
    the misfit at the offset fitted without them (cost units; > 0 is better), ``t`` the
    signed-rank test's normal score, ``critical`` its one-sided critical value; ``rmse_before``/``rmse_after``
    the held-out ground RMSE (m) at no shift and at the fold's offset, each with the
    vertical location fitted on the training folds.
    """

    n_segments: int
    folds: int
    improvement: float
    t: float
    critical: float
    rmse_before: float
    rmse_after: float
    fold_along: np.ndarray
    fold_cross: np.ndarray

    @property
    def significant(self) -> bool:
        return bool(np.isfinite(self.t) and self.t > self.critical and self.improvement > 0)

    @property
    def worse(self) -> bool:
        return bool(np.isfinite(self.rmse_after) and np.isfinite(self.rmse_before)
                    and self.rmse_after > self.rmse_before)


def segments_along(x: np.ndarray, y: np.ndarray, track_code: np.ndarray,
                   direction: tuple[float, float], length: float) -> np.ndarray:
    """Segment index (0..n-1) of each target: ``length`` m stretches along the track, per
    track, numbered in track order then along-track order."""
    proj = x * direction[0] + y * direction[1]
    codes = np.asarray(track_code, np.int64)
    start = np.full(int(codes.max()) + 1 if len(codes) else 0, np.inf)
    np.minimum.at(start, codes, proj)
    seg = np.floor((proj - start[codes]) / length).astype(np.int64)
    key = codes * (int(seg.max()) + 1 if len(seg) else 1) + seg
    return np.unique(key, return_inverse=True)[1].astype(np.int64)


def coverage_of(valid: np.ndarray, group: np.ndarray, segment: np.ndarray) -> Coverage:
    """Blocks (``group``) and segments with at least one target on a valid cell."""
    g_all = np.unique(group)
    g_cov = np.unique(group[valid])
    s_all = np.unique(segment)
    s_cov = np.unique(segment[valid])
    return Coverage(len(g_all), len(g_cov), len(s_all), len(s_cov))


def _z_critical(alpha: float) -> float:
    from scipy.special import ndtri

    return float(ndtri(1.0 - alpha))


def signed_rank_score(gain: np.ndarray) -> float:
    """Normal score of the one-sided (greater) Wilcoxon signed-rank statistic of ``gain``
    (zeros dropped, tied ranks averaged, tie and continuity corrections); > 0 when gains
    are mostly positive.
    NaN with fewer than 6 non-zero values."""
    g = np.asarray(gain, float)
    g = g[np.isfinite(g)]
    scale = float(np.abs(g).max()) if g.size else 0.0
    g = g[np.abs(g) > 1e-12 * scale] if scale > 0 else g[:0]
    n = g.size
    if n < 6:
        return float("nan")
    a = np.abs(g)
    order = np.argsort(a, kind="stable")
    sorted_a = a[order]
    _, first, counts = np.unique(sorted_a, return_index=True, return_counts=True)
    avg = first + (counts + 1) / 2.0  # average 1-based rank of each tie group
    ranks = np.empty(n)
    ranks[order] = np.repeat(avg, counts)
    w_plus = float(ranks[g > 0].sum())
    mean = n * (n + 1) / 4.0
    var = n * (n + 1) * (2 * n + 1) / 24.0 - float((counts ** 3 - counts).sum()) / 48.0
    if var <= 0:
        return float("nan")
    return float((w_plus - mean - 0.5) / np.sqrt(var))  # one-sided: continuity -0.5


def held_out_test(cost: np.ndarray, zero: int, da: np.ndarray, dc: np.ndarray,
                  ground: Kind, a: tuple[float, float], c: tuple[float, float],
                  folds: int, alpha: float) -> HeldOut:
    """The held-out test over interleaved folds of segments (see the module notes).

    Parameters
    ----------
    cost : ndarray (candidates, segments)
        Per-segment costs of every candidate (:func:`segment_costs`).
    zero : int
        Index of the no-shift candidate.
    da, dc : ndarray
        The candidates' along/cross shifts (m).
    ground : Kind
        Ground targets, for the held-out RMSE.
    folds : int
    alpha : float
        One-sided significance level.
    """
    n_seg = cost.shape[1]
    k = max(2, min(folds, n_seg // 2))
    fold = np.arange(n_seg) % k
    gain = np.zeros(n_seg)
    best = np.zeros(k, np.int64)
    for f in range(k):
        held = fold == f
        best[f] = int(np.argmin(cost[:, ~held].sum(axis=1)))
        gain[held] = cost[zero, held] - cost[best[f], held]
    rb, ra = _held_out_rmse(ground, a, c, da, dc, zero, best, fold)
    return HeldOut(n_seg, k, float(gain.mean()), signed_rank_score(gain),
                   _z_critical(alpha), rb, ra, da[best], dc[best])


def _held_out_rmse(ground: Kind, a: tuple[float, float], c: tuple[float, float],
                   da: np.ndarray, dc: np.ndarray, zero: int, best: np.ndarray,
                   fold: np.ndarray) -> tuple[float, float]:
    """Held-out ground RMSE at no shift and at each fold's offset, vertical location
    fitted on the training folds; only targets valid at both shifts count."""
    if len(ground.z) == 0:
        return float("nan"), float("nan")
    tfold = fold[ground.segment]
    k = len(best)
    cand = np.concatenate([np.full(k, zero), best])
    r = residuals(ground, a, c, da[cand], dc[cand])  # (2k, targets)
    train = tfold[None, :] != np.arange(k)[:, None]
    r_train = np.where(np.concatenate([train, train]), r, np.nan)
    m = robust_location(r_train, ground.scale)
    e = r - m[:, None]
    held = ~train
    sq_b = np.zeros(0)
    sq_a = np.zeros(0)
    for f in range(k):
        ok = held[f] & np.isfinite(e[f]) & np.isfinite(e[k + f])
        sq_b = np.concatenate([sq_b, e[f][ok] ** 2])
        sq_a = np.concatenate([sq_a, e[k + f][ok] ** 2])
    if sq_b.size == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(sq_b.mean())), float(np.sqrt(sq_a.mean()))


def bootstrap_sd(cost: np.ndarray, da: np.ndarray, dc: np.ndarray, replicates: int,
                 rng: np.random.Generator) -> tuple[float, float]:
    """Standard deviations (m) of the along/cross optimum over bootstrap resamples of the
    segments (the whole candidate set: coarse and fine)."""
    n_seg = cost.shape[1]
    if replicates < 2 or n_seg < 2:
        return float("nan"), float("nan")
    draws = rng.integers(0, n_seg, size=(replicates, n_seg))
    counts = np.zeros((replicates, n_seg))
    np.add.at(counts, (np.repeat(np.arange(replicates), n_seg), draws.ravel()), 1.0)
    best = np.argmin(counts @ cost.T, axis=1)
    return float(np.std(da[best], ddof=1)), float(np.std(dc[best], ddof=1))


def linearised_sd(kinds: list[Kind], a: tuple[float, float], c: tuple[float, float],
                  along: float, cross: float, trunc: float, n_segments: int
                  ) -> tuple[float, float, float]:
    """Linearised standard deviations (m) of the along, cross and vertical shift at
    (``along``, ``cross``): the raster's gradients at the targets against the inlier
    residuals, with segments as clusters (sandwich covariance, small-sample corrected).
    NaN where the terrain does not constrain a component."""
    h = _GRADIENT_STEP
    da = np.array([along, along + h, along - h, along, along])
    dc = np.array([cross, cross, cross, cross + h, cross - h])
    cols = 2 + len(kinds)
    xs, ps, segs = [], [], []
    for j, kind in enumerate(kinds):
        if len(kind.z) == 0:
            continue
        r = residuals(kind, a, c, da, dc)
        m = robust_location(r[:1], kind.scale)[0]
        e = r[0] - m
        ga = -(r[1] - r[2]) / (2 * h)  # d raster / d along
        gc = -(r[3] - r[4]) / (2 * h)
        ok = (np.isfinite(e) & np.isfinite(ga) & np.isfinite(gc)
              & (np.abs(e) <= trunc * kind.scale))
        if not ok.any():
            continue
        x = np.zeros((int(ok.sum()), cols))
        x[:, 0], x[:, 1], x[:, 2 + j] = ga[ok], gc[ok], 1.0
        w = kind.weight / len(kind.z) / kind.scale ** 2
        xs.append(x * np.sqrt(w))
        ps.append(x * (w * e[ok])[:, None])
        segs.append(kind.segment[ok])
    if not xs:
        return float("nan"), float("nan"), float("nan")
    xw = np.vstack(xs)
    hess = xw.T @ xw
    scores = np.vstack(ps)
    seg = np.concatenate(segs)
    meat_rows = np.zeros((n_segments, cols))
    for q in range(cols):
        meat_rows[:, q] = np.bincount(seg, scores[:, q], minlength=n_segments)
    meat = meat_rows.T @ meat_rows
    used = np.flatnonzero(np.diag(hess) > 0)
    hu = hess[np.ix_(used, used)]
    if np.linalg.cond(hu) > 1e12:
        return float("nan"), float("nan"), float("nan")
    inv = np.linalg.inv(hu)
    cov = inv @ meat[np.ix_(used, used)] @ inv
    n_cl = int((np.abs(meat_rows).sum(axis=1) > 0).sum())
    if n_cl > len(used):
        cov *= n_cl / (n_cl - len(used))
    var = np.full(cols, np.nan)
    var[used] = np.diag(cov)
    sd = np.sqrt(np.maximum(var, 0.0))
    return float(sd[0]), float(sd[1]), float(sd[2])
