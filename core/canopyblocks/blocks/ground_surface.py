"""A robust along-track ground surface from photons (DESIGN 1.10, ``ground="surface"``).

The paper's mean ground is the upper edge of a window at least 2 m tall, so on sparse
ICESat-2 photons it sits about 1.5 m above the terrain by construction. This estimator
fits a surface to the ground photons instead:

1. start: seed 002's ground candidates, the photons below ``min20 + 3 PSF`` in each
   along-track step of 20 photons (:func:`canopyblocks.blocks.step_classify.classify_seed002`);
2. fit: a local linear regression of height on along-track distance, Gaussian kernel of
   ``bandwidth`` metres, on binned sums (1 m bins along the track, convolved with the
   kernel), so the cost is linear in photons and track length;
3. iterate: photons within ``band`` (m) of the surface become the candidates, weighted by
   Tukey's biweight of their residual (scale from their MAD), and the surface is refitted;
   candidates more than ``band`` above it (understory, canopy) drop out.

Stretches without candidates (dense canopy) are bridged linearly between supported
nodes. A block's ground is the mean of the surface over its along-track extent.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, NoUsableDataError

__all__ = ["GroundSurfaceParams", "GroundSurface", "fit_ground_surface", "block_mean_ground"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GroundSurfaceParams:
    """Parameters of :func:`fit_ground_surface` (metres unless stated).

    Attributes
    ----------
    step : int
        Photons per seed-002 step for the starting candidates (20).
    psf : float
        Instrument point-spread sigma (ATLAS 0.25 m): the start keeps photons below the
        step minimum + 3 PSF.
    bandwidth : float
        Gaussian kernel sigma along the track (10 m).
    band : float
        Photons within +-band of the surface are candidates in the next iteration (1 m).
    iterations : int
        Refits after the start (4).
    node_spacing : float
        Along-track spacing of the surface nodes (1 m).
    min_support : float
        Nodes whose kernel weight sum is below this many photons are unsupported and
        bridged from their neighbours (0.5).
    """

    step: int = 20
    psf: float = 0.25
    bandwidth: float = 10.0
    band: float = 1.0
    iterations: int = 4
    node_spacing: float = 1.0
    min_support: float = 0.5

    def __post_init__(self) -> None:
        for name in ("psf", "bandwidth", "band", "node_spacing", "min_support"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"ground surface {name} must be a positive number, got {v!r}")
        if not (isinstance(self.step, int) and self.step >= 2):
            raise InputError(f"ground surface step must be an integer >= 2 photons, "
                             f"got {self.step!r}")
        if not (isinstance(self.iterations, int) and 0 <= self.iterations <= 50):
            raise InputError(f"ground surface iterations must be 0..50, got {self.iterations!r}")
        if self.bandwidth < self.node_spacing:
            raise InputError("ground surface bandwidth must be at least the node spacing")


@dataclass(frozen=True)
class GroundSurface:
    """Ground height (m) at along-track nodes ``s`` (m); ``supported`` nodes had photons."""

    s: np.ndarray
    z: np.ndarray
    supported: np.ndarray
    candidates: np.ndarray  # bool per input photon: used in the last fit

    def __call__(self, s: np.ndarray) -> np.ndarray:
        """Surface height at along-track positions ``s`` (linear between nodes)."""
        return np.interp(np.asarray(s, float), self.s, self.z)


def _kernel(bandwidth: float, spacing: float) -> np.ndarray:
    half = int(np.ceil(3.0 * bandwidth / spacing))
    u = np.arange(-half, half + 1) * spacing / bandwidth
    return np.exp(-0.5 * u * u)


def _local_linear(s: np.ndarray, z: np.ndarray, w: np.ndarray, nodes: np.ndarray,
                  spacing: float, kernel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kernel-weighted local linear fit of z(s) at ``nodes``: (height, weight sum)."""
    b, ds = _node_bins(s, nodes, spacing)
    return _local_linear_binned(b, ds, z, w, nodes.size, spacing, kernel)


def _node_bins(s: np.ndarray, nodes: np.ndarray, spacing: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Each photon's nearest node and its offset from it (m)."""
    b = np.clip(np.rint((s - nodes[0]) / spacing).astype(np.int64), 0, nodes.size - 1)
    return b, s - nodes[b]


def _local_linear_binned(b: np.ndarray, ds: np.ndarray, z: np.ndarray, w: np.ndarray, m: int,
                         spacing: float, kernel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_local_linear` from the photons' nodes ``b`` and offsets ``ds`` (of
    :func:`_node_bins`) on ``m`` nodes. Photons of weight 0 add exact zeros to the binned
    sums, so leaving them out changes no bit."""
    return _local_linear_sums(_binned_sums(b, ds, z, w, m), spacing, kernel)


def _binned_sums(b: np.ndarray, ds: np.ndarray, z: np.ndarray, w: np.ndarray, m: int
                 ) -> tuple[np.ndarray, ...]:
    """Per node (of ``m``), the sums of w, w ds, w z, w ds^2 and w z ds over its photons
    (bincount: in photon order, from 0)."""
    wds = w * ds
    wz = w * z
    return tuple(np.bincount(b, weights=v, minlength=m)
                 for v in (w, wds, wz, wds * ds, wz * ds))


def _local_linear_sums(sums: tuple[np.ndarray, ...], spacing: float, kernel: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_local_linear` from the nodes' :func:`_binned_sums`."""
    b_w, b_wds, b_wz, b_wdsds, b_wzds = sums
    m = b_w.size
    half = kernel.size // 2

    def same(x: np.ndarray, k: np.ndarray) -> np.ndarray:
        # np.convolve(mode="same") returns max(len(x), len(k)) values: a track shorter than
        # the kernel would get more values than nodes; the centred slice of "full" is the
        # same values for long tracks and the right length for short ones
        return np.convolve(x, k, mode="full")[half:half + m]

    # moments about each photon's own node, then shifted to the evaluation node:
    # for a photon in bin j evaluated at node i, (s - node_i) = ds + (node_j - node_i);
    # with the kernel symmetric, sum over j of K(i-j) * (node_j - node_i) terms is a
    # convolution with the kernel times its lag.
    lag = (np.arange(kernel.size) - kernel.size // 2) * spacing
    klag = kernel * lag
    klag2 = kernel * lag * lag

    def conv(binned: np.ndarray, k: np.ndarray) -> np.ndarray:
        # np.convolve flips the kernel: index k[q] pairs bin j = i + (half - q); use the
        # reversed lag kernel so node_j - node_i = +lag
        return same(binned, k[::-1])

    w0 = same(b_w, kernel)
    wds_lag = conv(b_wds, klag)  # used twice
    sw_d = conv(b_wds, kernel) + conv(b_w, klag)
    sw_dd = conv(b_wdsds, kernel) + 2 * wds_lag + conv(b_w, klag2)
    swz = conv(b_wz, kernel)
    swzd = conv(b_wzds, kernel) + conv(b_wz, klag)
    det = w0 * sw_dd - sw_d * sw_d
    with np.errstate(invalid="ignore", divide="ignore"):
        level = np.where(det > 1e-9 * np.maximum(w0, 1e-300) ** 2,
                         (sw_dd * swz - sw_d * swzd) / det,
                         swz / w0)
    return level, w0


def fit_ground_surface(s: np.ndarray, z: np.ndarray,
                       params: GroundSurfaceParams | None = None) -> GroundSurface:
    """Fit the ground surface to photons (signal photons: filter the noise first).

    Parameters
    ----------
    s : ndarray
        Along-track distance (m), any order.
    z : ndarray
        Photon heights (m).
    params : GroundSurfaceParams, optional

    Raises
    ------
    NoUsableDataError
        Fewer than 2 finite photons.
    """
    from .step_classify import classify_seed002

    p = params or GroundSurfaceParams()
    s = np.asarray(s, float)
    z = np.asarray(z, float)
    ok = np.isfinite(s) & np.isfinite(z)
    if ok.sum() < 2:
        raise NoUsableDataError("fewer than 2 photons with finite s and height: no ground "
                                "surface")
    idx = np.flatnonzero(ok)
    order = idx[np.argsort(s[idx], kind="stable")]
    ss, zz = s[order], z[order]
    cand, _, _ = classify_seed002(zz, psf=p.psf, step=p.step)
    nodes = np.arange(ss[0], ss[-1] + p.node_spacing, p.node_spacing)
    kernel = _kernel(p.bandwidth, p.node_spacing)
    w = cand.astype(float)
    level, support = _local_linear(ss, zz, w, nodes, p.node_spacing, kernel)
    surf = _bridge(nodes, level, support >= p.min_support)
    for _ in range(p.iterations):
        r = zz - np.interp(ss, nodes, surf)
        near = np.abs(r) <= p.band
        if near.sum() < 2:
            break
        mad = float(np.median(np.abs(r[near] - np.median(r[near]))))
        scale = max(4.685 * 1.4826 * mad, 0.25)
        u = r / scale
        w = np.where(near & (np.abs(u) < 1.0), (1.0 - u * u) ** 2, 0.0)
        level, support = _local_linear(ss, zz, w, nodes, p.node_spacing, kernel)
        surf = _bridge(nodes, level, support >= p.min_support)
        cand = w > 0
    used = np.zeros(s.size, bool)
    used[order] = cand
    return GroundSurface(nodes, surf, support >= p.min_support, used)


def _bridge(nodes: np.ndarray, level: np.ndarray, good: np.ndarray) -> np.ndarray:
    good = good & np.isfinite(level)
    if not good.any():
        raise NoUsableDataError("no ground photons found along the track: no ground surface")
    return np.interp(nodes, nodes[good], level[good])


def block_mean_ground(surface: GroundSurface, s_start: np.ndarray, s_end: np.ndarray
                      ) -> np.ndarray:
    """Mean of the surface (m) over each block's ``[s_start, s_end)``, exactly.

    The surface is piecewise linear between nodes; its integral is taken with the
    trapezoid rule on the nodes plus the two end points of each block (vectorised via
    a cumulative integral). Blocks outside the surface's extent use its end values.
    """
    ns, nz = surface.s, surface.z
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (nz[1:] + nz[:-1]) * np.diff(ns))])

    def integral(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, float)
        tc = np.clip(t, ns[0], ns[-1])
        j = np.clip(np.searchsorted(ns, tc, side="right") - 1, 0, ns.size - 2)
        zt = np.interp(tc, ns, nz)
        inner = cum[j] + 0.5 * (nz[j] + zt) * (tc - ns[j])
        # beyond the ends: constant extension
        return inner + (t - tc) * np.where(t > ns[-1], nz[-1], nz[0])

    a = np.asarray(s_start, float)
    b = np.asarray(s_end, float)
    return (integral(b) - integral(a)) / (b - a)
