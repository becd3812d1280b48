"""The ground surface of the ATL08-style classifier (DESIGN 1.11): an iterated along-track
surface fitted to the signal photons (noise removed first).

1. start: a low percentile (``start_percentile``, 5) of the photons' heights in each
   along-track window of ``window`` metres (30 m), a running median over three windows
   (a window whose low photons are stray noise or a crown is ignored; an end window with
   its neighbour and the line through the next two), joined linearly (with
   ``footprint_radius``: taken again on heights detrended by the slope of that first
   guess, since on a slope a window's low percentile is its downhill end);
2. passes: for each band half-width in ``bands`` (a narrowing sequence, e.g. 3, 2, 1,
   0.6 m; with ``footprint_radius`` widened in quadrature by the height spread the
   footprint has on the local slope, |slope| x 6.5 m: 1 m on a 15 % slope), the photons
   within the band around the current surface are weighted by Tukey's biweight of their
   residual (scale = the band) -- photons above the surface by ``above_weight`` less,
   since understory sits above the ground and never below it (except in the last,
   narrowest pass, which is symmetric so the surface is not biased low) -- and a
   Gaussian-kernel local linear fit along the track (``bandwidth``, the smoothing) gives
   the next surface (the fit of :mod:`.ground_surface`, on 1 m nodes, linear in photons
   and track length).

Stretches without photons near the surface are bridged linearly from their neighbours.
Heights are in the photons' vertical datum (m), ``s`` along-track (m).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, NoUsableDataError
from .ground_surface import (
    GroundSurface,
    _binned_sums,
    _bridge,
    _kernel,
    _local_linear_sums,
    _node_bins,
)
from .grouped import percentile_by_group
from .kernels import compiled, enabled

__all__ = ["SurfaceParams", "fit_atl08_surface"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SurfaceParams:
    """Parameters of :func:`fit_atl08_surface` (metres unless stated).

    Attributes
    ----------
    window : float
        Along-track window of the starting low percentile (30 m).
    start_percentile : float
        The starting percentile of the heights in each window, 0-100 (5).
    bands : tuple of float
        Half-widths of the bands of the successive passes, narrowing (3, 2, 1, 0.6 m).
    above_weight : float
        Weight factor (0-1] of photons above the surface in a pass (0.2).
    bandwidth : float
        Gaussian kernel sigma of the along-track fit (5 m).
    min_support : float
        Nodes whose kernel weight sum is below this many photons are bridged (0.3).
    footprint_radius : float
        Half the laser footprint (6.5 m for ICESat-2's 13 m), or 0 (default: off). On a
        slope the ground photons of one shot spread by +-slope x this much, so each pass's
        band is widened in quadrature by that spread (the along-track slope of the current
        surface over +-25 m), and the starting percentile is taken on heights detrended by
        the slope of a first guess. On synthetic sloped tracks it removes most of the low
        bias (15 % slope: block RMSE 0.68-0.74 -> 0.49-0.54 m; 30 %: 2.4-3.0 -> 1.3 m);
        on the unseen airborne tiles it helped strong beams' ground (1.04 -> 0.93 m at
        1.5 MHz) but cost weak beams by day (2.6-2.7 -> 3.5 m) and strong-beam Hmax at
        4.5 MHz (2.39 -> 2.74 m), so it is not the default.
    """

    window: float = 30.0
    start_percentile: float = 5.0
    bands: tuple[float, ...] = (3.0, 2.0, 1.0, 0.6)
    above_weight: float = 0.2
    bandwidth: float = 5.0
    min_support: float = 0.3
    footprint_radius: float = 0.0

    def __post_init__(self) -> None:
        if not (isinstance(self.footprint_radius, (int, float))
                and np.isfinite(self.footprint_radius) and self.footprint_radius >= 0):
            raise InputError(f"ground surface footprint_radius must be a number of metres >= 0, "
                             f"got {self.footprint_radius!r}")
        for name in ("window", "bandwidth", "min_support"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"ground surface {name} must be a positive number of metres, "
                                 f"got {v!r}")
        if not (isinstance(self.start_percentile, (int, float))
                and 0 <= self.start_percentile <= 100):
            raise InputError(f"ground surface start_percentile must be 0..100, got "
                             f"{self.start_percentile!r}")
        bands = tuple(self.bands) if isinstance(self.bands, (tuple, list)) else None
        if not bands or not all(isinstance(b, (int, float)) and np.isfinite(b) and b > 0
                                for b in bands):
            raise InputError(f"ground surface bands must be one or more positive band "
                             f"half-widths in metres, e.g. (3, 2, 1, 0.6); got {self.bands!r}")
        object.__setattr__(self, "bands", tuple(float(b) for b in bands))
        if not (isinstance(self.above_weight, (int, float)) and 0 < self.above_weight <= 1):
            raise InputError(f"ground surface above_weight must be in (0, 1], got "
                             f"{self.above_weight!r}")


_NODE = 1.0  # m between surface nodes
_RESERVE = 1.0  # m the surface may move before the photons left out are looked at again
_EPS = 1e-9


def _median3(low: np.ndarray) -> np.ndarray:
    """Running median of 3 windows (one window on stray noise or a crown is ignored); an
    end window takes the median of itself, its neighbour and the line through the next
    two (on a slope that line is the end window's value; a crown there is ignored)."""
    if low.size < 3:
        return low
    padded = np.concatenate([[2 * low[1] - low[2]], low, [2 * low[-2] - low[-3]]])
    mid = np.median(np.stack([padded[:-2], padded[1:-1], padded[2:]]), axis=0)
    mid[0] = np.median([low[0], low[1], 2 * low[1] - low[2]])
    mid[-1] = np.median([low[-1], low[-2], 2 * low[-2] - low[-3]])
    return mid


def _start(ss: np.ndarray, zz: np.ndarray, p: SurfaceParams, nodes: np.ndarray) -> np.ndarray:
    """Low percentile per window, placed at the window centres and joined linearly."""
    win = np.floor((ss - ss[0]) / p.window).astype(np.int64)
    n_win = int(win[-1]) + 1
    low = percentile_by_group(win, zz, p.start_percentile, n_win)
    centre = ss[0] + (np.arange(n_win) + 0.5) * p.window
    good = np.isfinite(low)
    low, centre = low[good], centre[good]
    low = _median3(low)
    start = np.interp(nodes, centre, low)
    if p.footprint_radius <= 0 or centre.size < 2:
        return start
    # again on heights detrended by the local slope of that first guess: on a slope the
    # window's low percentile is its downhill end, not the ground under its centre
    slope = np.gradient(low, centre)
    wc = ss[0] + (win + 0.5) * p.window  # each photon's window centre (all are in `centre`)
    k = np.clip(np.searchsorted(centre, wc), 0, centre.size - 1)
    det = zz - slope[k] * (ss - wc)
    low2 = percentile_by_group(win, det, p.start_percentile, n_win)[good]
    low2 = _median3(low2)
    return np.interp(nodes, centre, low2)


def _spread(nodes: np.ndarray, surf: np.ndarray, radius: float) -> np.ndarray:
    """Height spread (m) of a footprint of ``radius`` at each node: |slope| x radius, the
    slope over +-12 m of the surface."""
    if radius <= 0 or nodes.size < 2:
        return np.zeros(nodes.size)
    half = min(25, nodes.size - 1)
    i = np.arange(nodes.size)
    a = np.clip(i - half, 0, nodes.size - 1)
    b = np.clip(i + half, 0, nodes.size - 1)
    slope = (surf[b] - surf[a]) / np.maximum(nodes[b] - nodes[a], _NODE)
    return np.abs(slope) * radius


_CHUNK = 1 << 16  # photons a surface pass handles at once (cut between nodes)


def _pass(ss: np.ndarray, zz: np.ndarray, bins: np.ndarray, nodes: np.ndarray,
          surf: np.ndarray, cur: np.ndarray | None, band: float, p: SurfaceParams,
          near_within: float | None, last: bool
          ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None, np.ndarray | None]:
    """One pass of :func:`fit_atl08_surface` over the photons ``cur`` (None: all): per
    photon whether it weighs, the nodes' binned sums (None when none weighs) and, with
    ``near_within``, which photons lie within that of the surface (indices into ``cur``)."""
    n = ss.size if cur is None else cur.size
    m = nodes.size
    mod = compiled() if p.footprint_radius <= 0 and enabled() else None
    if mod is not None:  # one compiled pass, no chunks (the same bits)
        weighs = np.zeros(n, bool)
        sums2 = np.zeros((5, m))
        near_ix = np.empty(n if near_within is not None else 0, np.int64)
        k = mod.surface_pass(ss, zz, bins, nodes, surf,
                             cur if cur is not None else np.empty(0, np.int64),
                             cur is not None, band, float(p.above_weight), last,
                             -1.0 if near_within is None else near_within,
                             weighs, sums2, near_ix)
        return (weighs, tuple(sums2) if weighs.any() else None,
                near_ix[:k] if near_within is not None else None)
    # chunks cut where a new node starts
    cuts = [0]
    for j in range(_CHUNK, n, _CHUNK):
        first = int(np.searchsorted(bins, bins[j if cur is None else cur[j]], "left"))
        c = first if cur is None else int(np.searchsorted(cur, first, "left"))
        if c > cuts[-1]:
            cuts.append(c)
    cuts.append(n)
    sums = [np.zeros(m) for _ in range(5)]
    weighs = np.zeros(n, bool)
    near_parts = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        ix = slice(a, b) if cur is None else cur[a:b]
        sk, zk = ss[ix], zz[ix]
        r = np.interp(sk, nodes, surf)
        np.subtract(zk, r, out=r)  # the residual, in place (the same bits)
        if p.footprint_radius > 0:
            spread = np.interp(sk, nodes, _spread(nodes, surf, p.footprint_radius))
            u = r / np.hypot(band, spread)
        else:  # (hypot(band, 0) is band, exactly)
            u = r / band
        # Tukey's biweight (1 - u^2)^2 inside |u| < 1, computed in place
        w = u * u
        np.subtract(1.0, w, out=w)
        np.square(w, out=w)
        w[~(np.abs(u) < 1.0)] = 0.0
        if not last:  # the last, narrowest pass is symmetric: no bias
            w[r > 0] *= p.above_weight
        pos = w > 0
        weighs[a:b] = pos
        if near_within is not None:
            near_parts.append(np.flatnonzero(np.abs(r) < near_within) + a)
        on = np.flatnonzero(pos)
        if not on.size:
            continue
        bc = bins[ix][on]
        b0, b1 = int(bc[0]), int(bc[-1])
        part = _binned_sums(bc - b0, sk[on] - nodes[bc], zk[on], w[on], b1 - b0 + 1)
        for total, x in zip(sums, part):
            total[b0:b1 + 1] += x  # (zeros there: no other chunk holds these nodes)
    near = np.concatenate(near_parts) if near_within is not None else None
    return weighs, (tuple(sums) if weighs.any() else None), near


def fit_atl08_surface(s: np.ndarray, z: np.ndarray,
                      params: SurfaceParams | None = None,
                      start: GroundSurface | None = None) -> GroundSurface:
    """Fit the ground surface to signal photons.

    Parameters
    ----------
    s : ndarray
        Along-track distance (m), any order.
    z : ndarray
        Heights (m) of the photons kept by the noise filter.
    params : SurfaceParams, optional
    start : GroundSurface, optional
        A first guess to start the passes from instead of the windows' low percentile.

    Returns
    -------
    GroundSurface
        Heights at 1 m nodes; ``candidates`` marks the photons of the last pass.

    Raises
    ------
    NoUsableDataError
        Fewer than 2 photons with finite values.
    """
    p = params or SurfaceParams()
    s = np.asarray(s, float)
    z = np.asarray(z, float)
    if s.shape != z.shape:
        raise InputError(f"s and z differ in shape: {s.shape} vs {z.shape}")
    ok = np.isfinite(s) & np.isfinite(z)
    if int(ok.sum()) < 2:
        raise NoUsableDataError("fewer than 2 signal photons with a finite position and "
                                "height: no ground surface")
    order: np.ndarray | slice
    if ok.all() and bool(np.all(s[1:] >= s[:-1])):
        order = slice(None)  # finite and sorted: the arrays themselves, no copies
    else:
        idx = np.flatnonzero(ok)
        if bool(np.all(np.diff(s[idx]) >= 0)):
            order = idx
        else:
            order = idx[np.argsort(s[idx], kind="stable")]
    del ok
    ss, zz = s[order], z[order]
    nodes = np.arange(ss[0], ss[-1] + _NODE, _NODE)
    surf = _start(ss, zz, p, nodes) if start is None else start(nodes)
    kernel = _kernel(p.bandwidth, _NODE)
    support = np.zeros(nodes.size)
    bins = _node_bins(ss, nodes, _NODE)[0]
    # Passes after the first look only at the photons that can still weigh: those within
    # the widest band to come plus _RESERVE of the surface, while the surface has moved
    # less than _RESERVE since they were chosen (else all photons again). The others'
    # weights are provably 0, and a weight of 0 adds exact zeros: the same surface.
    # Each pass runs over chunks of photons cut between nodes, so every node's sums come
    # whole from one chunk, in photon order from 0: the same bits as one pass.
    cur: np.ndarray | None = None  # indices into ss of the photons looked at (None: all)
    drift = 0.0  # max |surface change| summed since photons were first left out
    eps = _EPS * (1.0 + float(np.max(np.abs(zz))))  # the rounding of np.interp, amply
    weighs = np.zeros(ss.size, bool)  # w > 0 in the last pass, per photon looked at
    looked = cur
    for k, band in enumerate(p.bands):
        if cur is not None and drift + eps >= _RESERVE:
            cur, drift = None, 0.0
        prune = p.footprint_radius <= 0 and k < len(p.bands) - 1
        weighs, sums, near = _pass(ss, zz, bins, nodes, surf, cur, band, p,
                                   (max(p.bands[k + 1:]) + _RESERVE) if prune else None,
                                   last=k == len(p.bands) - 1)
        looked = cur
        if sums is None:
            break
        level, support = _local_linear_sums(sums, _NODE, kernel)
        try:
            new = _bridge(nodes, level, support >= p.min_support)
        except NoUsableDataError:
            break
        if prune and near is not None:
            step = float(np.max(np.abs(new - surf)))
            drift = drift + step if cur is not None else step
            if drift + eps < _RESERVE and bool(np.all(np.isfinite(surf))):
                if near.size < weighs.size:  # (else nothing is gained)
                    cur = near if cur is None else cur[near]
            elif cur is None:
                drift = 0.0
        surf = new
    used = np.zeros(s.size, bool)
    if looked is None:
        used[order] = weighs
    else:
        used[looked if isinstance(order, slice) else order[looked]] = weighs
    return GroundSurface(nodes, surf, support >= p.min_support, used)
