"""The fast paths of the ATL08-style classifier against brute force: the density filter's
neighbour counts (each photon's quantised box on its segment's grid, counted pair by pair)
and the surface's binned local linear fit (a weighted least-squares line per node)."""

from __future__ import annotations

import numpy as np

from canopyblocks.blocks.density_filter import DensityParams, density_filter
from canopyblocks.blocks.ground_surface import _kernel, _local_linear


def _brute_counts(s: np.ndarray, z: np.ndarray, p: DensityParams) -> np.ndarray:
    """Per photon: photons of its segment's grid (the segment plus one box each side,
    origin at their lowest s and z) whose cell is within ``cells`` cells of its own."""
    order = np.argsort(s, kind="stable")
    ss, zs = s[order], z[order]
    seg = np.floor((ss - ss[0]) / p.segment).astype(int)
    out = np.zeros(s.size, int)
    ds, dz = p.along / p.cells, p.height / p.cells
    for k in np.unique(seg):
        own = np.flatnonzero(seg == k)
        ext = np.flatnonzero((ss >= ss[own[0]] - p.along) & (ss <= ss[own[-1]] + p.along))
        ci = np.floor((ss[ext] - ss[ext].min()) / ds).astype(int)
        ri = np.floor((zs[ext] - zs[ext].min()) / dz).astype(int)
        for i in own:
            j = int(np.flatnonzero(ext == i)[0])
            out[order[i]] = int(np.sum((np.abs(ci - ci[j]) <= p.cells)
                                       & (np.abs(ri - ri[j]) <= p.cells)))
    return out


def test_density_counts_equal_brute_force():
    rng = np.random.default_rng(3)
    n_sig, n_bg = 1500, 1500
    s = np.concatenate([rng.uniform(0, 700, n_sig), rng.uniform(0, 700, n_bg)])
    z = np.concatenate([0.02 * s[:n_sig] + rng.normal(0, 1.0, n_sig),
                        rng.uniform(-80, 80, n_bg)])
    for p in (DensityParams(along=10.0, height=1.5, quantile=0.999, segment=200.0),
              DensityParams(along=20.0, height=3.0, quantile=0.99, segment=200.0, cells=3)):
        res = density_filter(s, z, p)
        assert np.array_equal(res.count, _brute_counts(s, z, p))
        assert np.array_equal(res.keep, res.count - 1 > res.threshold)


def test_local_linear_equals_weighted_least_squares():
    rng = np.random.default_rng(4)
    s = np.sort(rng.uniform(0, 120, 400))
    z = 3.0 + 0.1 * s + np.sin(s / 9.0) + rng.normal(0, 0.3, s.size)
    w = rng.uniform(0, 1, s.size)
    nodes = np.arange(s[0], s[-1] + 1.0, 1.0)
    kernel = _kernel(4.0, 1.0)
    level, support = _local_linear(s, z, w, nodes, 1.0, kernel)
    half = kernel.size // 2
    b = np.clip(np.rint(s - nodes[0]).astype(int), 0, nodes.size - 1)
    for i in range(nodes.size):  # each photon weighted by the kernel at its bin's lag
        lag = b - i
        kw = np.where(np.abs(lag) <= half, kernel[np.clip(lag + half, 0, kernel.size - 1)], 0.0)
        ww = w * kw
        x = s - nodes[i]
        a = np.array([[ww.sum(), (ww * x).sum()], [(ww * x).sum(), (ww * x * x).sum()]])
        rhs = np.array([(ww * z).sum(), (ww * z * x).sum()])
        assert abs(support[i] - ww.sum()) < 1e-9 * max(1.0, ww.sum())
        assert abs(level[i] - np.linalg.solve(a, rhs)[0]) < 1e-7
