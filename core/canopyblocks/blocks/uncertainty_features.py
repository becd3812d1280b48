"""The per-block quantities the sigma model reads (:func:`block_features`), in one pass.

Each quantity is a count or a sum over the photons of a block: the photons of each class,
the background rate, the ground photons' heights and squares, the noise photons above the
block's Hmax and near the ground, the geolocation sigma, and the canopy-top profile's
steps. Photons in along-track order (as every reader gives them) fall in the blocks in
turn: where numba is installed one compiled loop walks them once
(``kernels_numba.feature_sums``); otherwise, or for photons out of order, numpy does the
same sums in the same order (the same bits, tested both ways).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..readers.atl03_geolocation import GEOLOCATION_SIGMA_COLUMN

if TYPE_CHECKING:
    from ..photons import PhotonTrack
    from .atl08_classify import Atl08Classes

__all__ = ["block_features", "CANOPY_STEP"]

#: Step of the canopy-top profile whose slope measures a block's canopy relief, m.
CANOPY_STEP = 5.0

#: The sums of :func:`_sums_numpy` / the compiled loop, in this order.
_SUMS = ("by_class", "bg", "g1", "g2", "above", "near", "geo", "geo_n", "grad", "grad_n")


def block_features(track: PhotonTrack, classes: Atl08Classes, s_start: np.ndarray,
                   s_end: np.ndarray, hmax: np.ndarray) -> dict[str, np.ndarray]:
    """Raw per-interval quantities the model uses (sorted, non-overlapping intervals).

    Parameters
    ----------
    track : PhotonTrack
    classes : Atl08Classes
        The classifier's result on ``track``.
    s_start, s_end : ndarray
        Along-track bounds of each block or segment (m), sorted by ``s_start``.
    hmax : ndarray
        The block's Hmax (m; NaN where none).

    Returns
    -------
    dict
        ``n_ground, n_canopy, n_top, n_noise, n_all``, ``n_noise_top`` (noise photons
        0-10 m above ``hmax``), ``n_noise_ground`` (within 3 m of the surface),
        ``background`` (photons per m along
        per m height, mean over the block's photons), ``ground_spread`` (sd of the ground
        photons about the surface, m; NaN under 2 of them), ``ground_offset`` (their mean
        height above the surface, m), ``relief`` (the surface's second difference over
        +-15 m about the centre, m), ``slope``, ``length`` (m),
        ``hmax`` (m).
    """
    from .atl08_classify import CLASS_CANOPY, CLASS_GROUND, CLASS_NOISE, CLASS_TOP

    a = np.asarray(s_start, float)
    b = np.asarray(s_end, float)
    n = a.size
    hmx = np.asarray(hmax, float)
    geo = track.extra.get(GEOLOCATION_SIGMA_COLUMN)
    sums = _sums(np.asarray(track.s, float), a, b, classes,
                 None if geo is None or not n else np.asarray(geo, float),
                 np.where(np.isfinite(hmx), hmx, 0.0))
    by_class = sums["by_class"].astype(float)
    n_all = by_class.sum(axis=1)
    n_ground = by_class[:, CLASS_GROUND]
    with np.errstate(invalid="ignore", divide="ignore"):
        bg = sums["bg"] / n_all
        m1 = sums["g1"] / n_ground
        m2 = sums["g2"] / n_ground
        spread = np.sqrt(np.maximum(m2 - m1 * m1, 0.0) * n_ground / (n_ground - 1))
        geo_b = sums["geo"] / sums["geo_n"] if geo is not None and n else np.full(n, np.nan)
    spread[n_ground < 2] = np.nan
    gradient = np.zeros(n)
    np.divide(sums["grad"], sums["grad_n"], out=gradient, where=sums["grad_n"] > 0)
    surf = classes.surface
    slope = np.abs(np.interp(b, surf.s, surf.z) - np.interp(a, surf.s, surf.z)) / (b - a)
    mid = 0.5 * (a + b)
    relief = np.abs(np.interp(mid - 15.0, surf.s, surf.z) + np.interp(mid + 15.0, surf.s, surf.z)
                    - 2 * np.interp(mid, surf.s, surf.z))
    return {"n_ground": n_ground,
            "canopy_gradient": np.minimum(np.sqrt(gradient), 3.0),
            "geo_sigma": geo_b,
            "n_noise_top": sums["above"].astype(float),
            "n_noise_ground": sums["near"].astype(float),
            "n_canopy": by_class[:, CLASS_CANOPY] + by_class[:, CLASS_TOP],
            "n_top": by_class[:, CLASS_TOP], "n_noise": by_class[:, CLASS_NOISE],
            "n_all": n_all, "background": np.where(np.isfinite(bg), bg, 0.0),
            "ground_spread": spread, "ground_offset": np.where(n_ground > 0, m1, np.nan),
            "relief": relief, "slope": slope, "length": b - a,
            "hmax": hmx}


def _sums(s: np.ndarray, a: np.ndarray, b: np.ndarray, classes: Atl08Classes,
          geo: np.ndarray | None, top: np.ndarray) -> dict[str, np.ndarray]:
    """The per-interval sums, by the compiled loop where it can run, else by numpy."""
    from .kernels import compiled, enabled

    cls = np.asarray(classes.classes)
    height = np.asarray(classes.height, float)
    bgr = np.asarray(classes.background, float)
    n = a.size
    if (enabled() and s.size > 1 and cls.dtype == np.int8 and bool(np.all(s[1:] >= s[:-1]))
            and int(cls.max()) <= 3):
        mod = compiled()
        assert mod is not None
        out = {"by_class": np.zeros((n, 4), np.int64), "bg": np.zeros(n), "g1": np.zeros(n),
               "g2": np.zeros(n), "above": np.zeros(n, np.int64),
               "near": np.zeros(n, np.int64), "geo": np.zeros(n),
               "geo_n": np.zeros(n, np.int64), "grad": np.zeros(n),
               "grad_n": np.zeros(n, np.int64)}
        mod.feature_sums(s, a, b, cls, height, bgr,
                         np.empty(0) if geo is None else geo, geo is not None, top,
                         CANOPY_STEP, *(out[k] for k in _SUMS))
        return out
    return _sums_numpy(s, a, b, cls, height, bgr, geo, top)


def _sums_numpy(s: np.ndarray, a: np.ndarray, b: np.ndarray, cls: np.ndarray,
                height: np.ndarray, bgr: np.ndarray, geo: np.ndarray | None,
                top: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`_sums` by numpy (the photons in any order)."""
    from .atl08_classify import CLASS_GROUND, CLASS_NOISE

    n = a.size
    j = _interval_of(s, a)
    ok = (cls >= 0) & (j >= 0) & np.isfinite(s)
    jj = np.clip(j, 0, max(n - 1, 0))
    ok &= s < b[jj] if n else np.zeros_like(ok)
    row, c = jj[ok], cls[ok]

    def count(mask: np.ndarray) -> np.ndarray:
        return np.bincount(row[mask], minlength=n)

    # the photons of each class per interval, in one count (classes 0-3)
    by_class = np.bincount(row * 4 + c, minlength=4 * n).reshape(n, 4) \
        if c.size and int(c.max()) <= 3 else np.column_stack(
            [count(c == k) for k in range(4)]).reshape(n, 4)
    gr = c == CLASS_GROUND
    hn = height[ok]
    hg, rg = hn[gr], row[gr]
    top_of_row = top[row] if n else np.zeros(0)
    noise = c == CLASS_NOISE
    with np.errstate(invalid="ignore"):
        above = noise & (hn > top_of_row) & (hn <= top_of_row + 10.0)
        near_ground = noise & (np.abs(hn) <= 3.0)
    out = {"by_class": by_class, "bg": np.bincount(row, bgr[ok], minlength=n),
           "g1": np.bincount(rg, hg, minlength=n), "g2": np.bincount(rg, hg * hg, minlength=n),
           "above": count(above), "near": count(near_ground)}
    if geo is not None:
        g = geo[ok]
        fin = np.isfinite(g) & (g > 0)
        out["geo"] = np.bincount(row[fin], g[fin], minlength=n)
        out["geo_n"] = np.bincount(row[fin], minlength=n)
    out["grad"], out["grad_n"] = _gradient_sums(s[ok] - a[row], row, c, hn, n)
    return out


def _interval_of(s: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Per photon, the last interval start ``a`` (sorted) at or before its ``s`` (-1: none):
    ``np.searchsorted(a, s, side="right") - 1``; for photons in along-track order the
    same from the intervals' first photons (one search per interval, not per photon)."""
    if s.size < 2 or not bool(np.all(s[1:] >= s[:-1])):  # (NaN: False)
        return np.searchsorted(a, s, side="right") - 1
    first = np.searchsorted(s, a, side="left")  # photons before each start
    return np.repeat(np.arange(-1, a.size), np.diff(first, prepend=0, append=s.size))


def _gradient_sums(ds: np.ndarray, row: np.ndarray, cls: np.ndarray, height: np.ndarray,
                   n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per block, the sum of the squared slopes of its canopy-top profile and their number
    (the canopy gradient is the root of their mean, at most 3): the highest signal photon
    above the ground surface in :data:`CANOPY_STEP` m steps from the block's start (ground
    photons count as 0 m), differenced between neighbouring steps."""
    from .atl08_classify import CLASS_CANOPY, CLASS_GROUND, CLASS_TOP

    sig = (cls == CLASS_GROUND) | (cls == CLASS_CANOPY) | (cls == CLASS_TOP)
    h = np.where(cls == CLASS_GROUND, 0.0, height)[sig]
    r = row[sig]
    k = np.floor(ds[sig] / CANOPY_STEP).astype(np.int64)
    ok = np.isfinite(h)
    h, r, k = h[ok], r[ok], k[ok]
    if not h.size:
        return np.zeros(n), np.zeros(n, np.int64)
    r, k, h = _step_tops(r, k, h)  # one top per (block, step), in (block, step) order
    nb = (r[1:] == r[:-1]) & (k[1:] == k[:-1] + 1)
    d2 = ((h[1:] - h[:-1]) / CANOPY_STEP) ** 2
    return np.bincount(r[1:][nb], d2[nb], minlength=n), np.bincount(r[1:][nb], minlength=n)


def _step_tops(r: np.ndarray, k: np.ndarray, h: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The highest ``h`` of each (``r``, ``k``) pair, pairs in ascending order. Photons in
    along-track order come in (block, step) order already: each run's maximum then, by one
    ``np.maximum.reduceat`` (no sort); else a sort by (r, k, h) and each run's last."""
    new = np.empty(r.size, bool)
    new[0] = True
    np.not_equal(r[1:], r[:-1], out=new[1:])
    new[1:] |= k[1:] != k[:-1]
    if bool(np.all(r[1:] >= r[:-1])) and bool(np.all((k[1:] >= k[:-1]) | new[1:])):
        first = np.flatnonzero(new)
        return r[first], k[first], np.maximum.reduceat(h, first)
    order = np.lexsort((h, k, r))
    r, k, h = r[order], k[order], h[order]
    last = np.ones(r.size, bool)
    last[:-1] = (r[1:] != r[:-1]) | (k[1:] != k[:-1])
    return r[last], k[last], h[last]
