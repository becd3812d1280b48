"""The flash-lidar (ESFL) chain as its paper does it: cubes to terrain and canopy height.

Steps (all footprints of one flight line at once):

1. footprint pixels: the 4 x 4 region around each footprint's location, pixels whose
   average time-summed energy reaches a fraction ``f`` of the region's brightest
   (:func:`~canopyblocks.waveforms.flash.footprint_mask`);
2. waveforms: the selected pixels, geolocated, are merged on a regular grid (5 m): all
   pixels in one cell, from any footprint (and so any range gate), make one waveform,
   aligned by elevation (``cell = 0``: one waveform per footprint instead);
3. noise: a Gaussian fitted to each waveform's value histogram; threshold mean + 4 sd
   (by default the maximum-likelihood fit to the histogram's half below its mode, where
   no signal reaches; ``noise_fit="lsq"``: least squares to the counts around the mode);
4. Gaussian decomposition (:func:`~canopyblocks.waveforms.decompose.fit_gaussians`);
   preliminary terrain = the centre of the lowest Gaussian whose amplitude reaches the
   threshold; top = the highest sample above the threshold;
5. outliers: terrain at least 10 m below the median of its neighbours (5 on either side
   along the track); the other terrain points filtered by multiscale curvature
   classification (:mod:`~canopyblocks.waveforms.mcc`), the terrain of the rejected ones
   interpolated from the kept; canopy height = top - terrain; heights over 60 m are
   outliers too.

Elevations are in the cubes' vertical datum (m); positions in their CRS (m).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..errors import InputError, NoUsableDataError
from .decompose import fit_gaussians
from .flash import footprint_mask
from .mcc import MccParams, mcc_ground, terrain_surface
from .noise import estimate_noise, fit_histogram_noise
from .terrain_filter import terrain_outliers

__all__ = ["EsflCubes", "EsflParams", "EsflWaveforms", "esfl_waveforms", "esfl_process",
           "esfl_chain", "lowest_gaussian"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EsflCubes:
    """One flight line of flash-lidar cubes.

    Attributes
    ----------
    cubes : ndarray (footprints, rows, cols, bins)
        Pixel waveforms; bin k of footprint i is centred on ``top[i] - k * bin_size``.
    top : ndarray (footprints,)
        Elevation of bin 0's centre (m).
    bin_size : float
        Range bin (m).
    x, y : ndarray (footprints,)
        Footprint centres (m, the survey's CRS).
    along : (float, float)
        Unit vector of the track (columns of a subset run along it, rows across).
    pixel_size : float
        Ground size of a pixel (m).
    """

    cubes: np.ndarray
    top: np.ndarray
    bin_size: float
    x: np.ndarray
    y: np.ndarray
    along: tuple[float, float]
    pixel_size: float

    def __post_init__(self) -> None:
        c = np.asarray(self.cubes)
        if c.ndim != 4:
            raise InputError(f"cubes must have shape (footprints, rows, cols, bins); got "
                             f"{c.shape}")
        n = c.shape[0]
        for name in ("top", "x", "y"):
            if np.asarray(getattr(self, name)).shape != (n,):
                raise InputError(f"{name} must hold one value per footprint ({n}); got "
                                 f"shape {np.asarray(getattr(self, name)).shape}")
        if not (self.bin_size > 0 and self.pixel_size > 0):
            raise InputError(f"bin_size and pixel_size must be > 0 m; got {self.bin_size!r}, "
                             f"{self.pixel_size!r}")
        ax, ay = self.along
        if not math.isclose(math.hypot(ax, ay), 1.0, rel_tol=1e-6):
            raise InputError(f"along must be a unit vector; got {self.along!r}")

    def pixel_xy(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground centres (m) of every pixel, arrays (footprints, rows, cols)."""
        _, rows, cols, _ = np.shape(self.cubes)
        u = (np.arange(cols) + 0.5) * self.pixel_size - cols * self.pixel_size / 2
        v = (np.arange(rows) + 0.5) * self.pixel_size - rows * self.pixel_size / 2
        uu, vv = np.meshgrid(u, v)               # (rows, cols)
        ax, ay = self.along
        px = np.asarray(self.x, float)[:, None, None] + uu * ax - vv * ay
        py = np.asarray(self.y, float)[:, None, None] + uu * ay + vv * ax
        return px, py


@dataclass(frozen=True)
class EsflParams:
    """Parameters of the flash-lidar chain (the paper's values by default).

    Attributes
    ----------
    fraction : float
        Energy fraction defining a footprint's pixels (0.5).
    region : int
        Side of the pixel region around the footprint's location (4).
    cell : float
        Grid cell (m) on which pixels are merged into waveforms (5); 0: one waveform per
        footprint.
    k : float
        Noise threshold in sd above the noise mean (4).
    noise_fit : str
        How the Gaussian is fitted to a waveform's value histogram: ``"ml"`` (maximum
        likelihood: mean at the mode, refined by truncated means, sd from the values
        below it; :func:`~canopyblocks.waveforms.noise.estimate_noise`) or ``"lsq"``
        (least squares to the counts from 3 sd below the mode to 1 sd above;
        :func:`~canopyblocks.waveforms.noise.fit_histogram_noise`). On 82 samples of pure
        noise: sd 0.97 +- 0.13 and 1.00 +- 0.24 of the truth; the wider spread of
        ``"lsq"`` lets noise peaks through as low Gaussians (tuning tiles, 5 % noise:
        terrain SD 0.37 m against 1.20 m).
    max_gaussians : int
        Gaussians per waveform at most.
    smooth : float
        Smoothing sd (samples) of the decomposition's initial-peak search: 1 sample on
        the flash lidar's 0.75 m bins, whose 4 ns pulse (0.25 m sd) is narrower than a bin.
    mcc : MccParams or None
        Terrain filter (scale = the grid cell); None: no curvature filter.
    max_below, max_height : float
        Outlier rule (m): terrain this far below its neighbours' median, heights above.
    neighbours : int
        Waveforms on each side along the track for the outlier rule.
    """

    fraction: float = 0.5
    region: int = 4
    cell: float = 5.0
    k: float = 4.0
    noise_fit: str = "ml"
    max_gaussians: int = 10
    smooth: float = 1.0
    mcc: MccParams | None = field(default_factory=lambda: MccParams(scale=5.0,
                                                                    curvature=0.3))
    max_below: float = 10.0
    max_height: float = 60.0
    neighbours: int = 5

    def __post_init__(self) -> None:
        from ..arguments import check_fields
        check_fields(self)   # every field against its annotation, at the door
        if not (0.0 < self.fraction <= 1.0):
            raise InputError(f"energy fraction must be in (0, 1]; got {self.fraction!r}")
        if not (math.isfinite(self.cell) and self.cell >= 0):
            raise InputError(f"cell must be >= 0 m (0: one waveform per footprint); got "
                             f"{self.cell!r}")
        if not (math.isfinite(self.k) and self.k > 0):
            raise InputError(f"k must be a positive number of sd; got {self.k!r}")
        if self.noise_fit not in ("ml", "lsq"):
            raise InputError(f"noise_fit must be 'ml' or 'lsq'; got {self.noise_fit!r}")
        if isinstance(self.max_gaussians, bool) or not isinstance(self.max_gaussians, int) \
                or self.max_gaussians < 1:
            raise InputError(f"max_gaussians must be a positive integer; got "
                             f"{self.max_gaussians!r}")
        if not (math.isfinite(self.smooth) and self.smooth > 0):
            raise InputError(f"smooth must be a positive number of samples; got "
                             f"{self.smooth!r}")


@dataclass(frozen=True)
class EsflWaveforms:
    """Merged waveforms: ``waveforms`` (w, m) with NaN where no pixel reaches, sample j
    of waveform i centred on ``top[i] - j * bin_size``; ``x``, ``y`` the mean ground
    position of their pixels, ``n_pixels``; and per selected pixel its waveform
    (``pixel_group``), ground centre (``pixel_x``, ``pixel_y``) and size."""

    waveforms: np.ndarray
    top: np.ndarray
    bin_size: float
    x: np.ndarray
    y: np.ndarray
    n_pixels: np.ndarray
    pixel_group: np.ndarray
    pixel_x: np.ndarray
    pixel_y: np.ndarray
    pixel_size: float
    along: tuple[float, float]


def esfl_waveforms(data: EsflCubes, params: EsflParams | None = None) -> EsflWaveforms:
    """Footprint pixels merged into waveforms per grid cell (or per footprint)."""
    p = params or EsflParams()
    cubes = np.asarray(data.cubes, float)
    n, rows, cols, m = cubes.shape
    mask, _ = footprint_mask(cubes, p.fraction, p.region)
    px, py = data.pixel_xy()
    # footprints without a window (nothing under them: top NaN) give no pixel
    live = np.flatnonzero(np.isfinite(np.asarray(data.top, float)))
    if live.size == 0:
        raise NoUsableDataError("no flash-lidar footprint has a recorded window (every top "
                                "is missing); nothing to process")
    fp = np.repeat(live, int(mask.sum()))
    sel_x = px[live][:, mask].ravel()
    sel_y = py[live][:, mask].ravel()
    vals = cubes[live][:, mask, :].reshape(-1, m)   # (pixels, bins), footprint-major
    top_px = np.asarray(data.top, float)[fp]
    if p.cell > 0:
        key = np.stack([np.floor(sel_x / p.cell), np.floor(sel_y / p.cell)], 1).astype(np.int64)
        _, group = np.unique(key, axis=0, return_inverse=True)
        group = group.ravel()
    else:
        group = np.repeat(np.arange(live.size), int(mask.sum()))
    ng = int(group.max()) + 1
    g_top = np.full(ng, -np.inf)
    np.maximum.at(g_top, group, top_px)
    shift = (g_top[group] - top_px) / data.bin_size     # >= 0 samples
    s0 = np.floor(shift + 1e-9).astype(np.int64)
    fr = np.clip(shift - s0, 0.0, 1.0)
    width = m + int(s0.max()) + 2
    acc = np.zeros((ng, width))
    cov = np.zeros((ng, width))
    j = np.arange(m)[None, :]
    rows_g = np.broadcast_to(group[:, None], vals.shape)
    col0 = s0[:, None] + j
    wa = np.broadcast_to((1.0 - fr)[:, None], vals.shape)
    wb = np.broadcast_to(fr[:, None], vals.shape)
    np.add.at(acc, (rows_g, col0), wa * vals)
    np.add.at(acc, (rows_g, col0 + 1), wb * vals)
    np.add.at(cov, (rows_g, col0), wa)
    np.add.at(cov, (rows_g, col0 + 1), wb)
    with np.errstate(invalid="ignore", divide="ignore"):
        wf = np.where(cov > 1e-6, acc / cov, np.nan)
    cnt = np.bincount(group, minlength=ng)
    gx = np.bincount(group, weights=sel_x, minlength=ng) / np.maximum(cnt, 1)
    gy = np.bincount(group, weights=sel_y, minlength=ng) / np.maximum(cnt, 1)
    return EsflWaveforms(wf, g_top, data.bin_size, gx, gy, cnt, group, sel_x, sel_y,
                         data.pixel_size, data.along)


def lowest_gaussian(gaussians: np.ndarray, threshold: float) -> float:
    """Centre (samples) of the lowest Gaussian (highest sample index) whose amplitude
    reaches ``threshold``; NaN when none does. ``gaussians`` is (g, 3): amplitude,
    centre, sigma as :func:`~canopyblocks.waveforms.decompose.fit_gaussians` returns."""
    g = np.asarray(gaussians, float).reshape(-1, 3)
    ok = g[:, 0] >= threshold
    return float(g[ok, 1].max()) if ok.any() else float("nan")


def esfl_process(wf: EsflWaveforms, params: EsflParams | None = None) -> pd.DataFrame:
    """Terrain and canopy height of merged waveforms (steps 3-5 of the module).

    Returns
    -------
    DataFrame
        One row per waveform: ``x``, ``y`` (m), ``n_pixels``, ``noise_mean``,
        ``noise_sd``, ``n_gaussians``, ``ground_gauss`` (the lowest Gaussian, m),
        ``top`` (m), ``terrain`` (m, after the filters), ``mcc_ground`` (bool: the
        lowest Gaussian kept as terrain), ``height`` (m) and ``outlier`` (bool).
    """
    p = params or EsflParams()
    w = np.asarray(wf.waveforms, float)
    nw, width = w.shape
    valid = np.isfinite(w)
    fit = estimate_noise if p.noise_fit == "ml" else fit_histogram_noise
    noise = fit(w, k=p.k, valid=valid)
    ground = np.full(nw, np.nan)
    top = np.full(nw, np.nan)
    count = np.zeros(nw, np.int64)
    thr = p.k * noise.sd
    above = valid & (np.where(valid, w, -np.inf) > noise.threshold[:, None])
    first = np.where(above.any(axis=1), np.argmax(above, axis=1), -1)
    top = np.where(first >= 0, wf.top - first * wf.bin_size, np.nan)
    for i in range(nw):   # least squares per waveform (decompose.fit_gaussians)
        if not (np.isfinite(thr[i]) and thr[i] > 0) or first[i] < 0:
            continue
        idx = np.flatnonzero(valid[i])
        lo, hi = int(idx[0]), int(idx[-1]) + 1
        y = np.nan_to_num(w[i, lo:hi] - noise.mean[i], nan=0.0)
        g = fit_gaussians(y, float(thr[i]), max_gaussians=p.max_gaussians, smooth=p.smooth)
        count[i] = len(g)
        pos = lowest_gaussian(g, float(thr[i]))
        if np.isfinite(pos):
            ground[i] = wf.top[i] - (lo + pos) * wf.bin_size
    along = np.asarray(wf.x) * wf.along[0] + np.asarray(wf.y) * wf.along[1]
    order = np.argsort(along, kind="stable")
    out_low = np.zeros(nw, bool)
    out_low[order] = terrain_outliers(ground[order], np.zeros(nw), neighbours=p.neighbours,
                                      max_below=p.max_below, max_height=p.max_height)
    keep = np.isfinite(ground) & ~out_low
    if p.mcc is not None and keep.sum() >= 4:
        kept = np.zeros(nw, bool)
        kept[keep] = mcc_ground(wf.x[keep], wf.y[keep], ground[keep], p.mcc)
    else:
        kept = keep
    terrain = np.full(nw, np.nan)
    usable = ~out_low
    if kept.any():
        terrain[usable] = terrain_surface(wf.x[usable], wf.y[usable],
                                          np.where(kept, ground, np.nan)[usable],
                                          kept[usable], scale=p.cell or 5.0)
    height = top - terrain
    with np.errstate(invalid="ignore"):
        outlier = out_low | (np.isfinite(height) & (height > p.max_height))
    return pd.DataFrame({"x": wf.x, "y": wf.y, "n_pixels": wf.n_pixels,
                         "noise_mean": noise.mean, "noise_sd": noise.sd,
                         "n_gaussians": count, "ground_gauss": ground, "top": top,
                         "terrain": terrain, "mcc_ground": kept, "height": height,
                         "outlier": outlier})


def esfl_chain(data: EsflCubes, params: EsflParams | None = None
               ) -> tuple[EsflWaveforms, pd.DataFrame]:
    """The whole chain: :func:`esfl_waveforms` then :func:`esfl_process`."""
    from ..arguments import check_instance, check_optional
    check_instance(data, EsflCubes, "esfl_chain: data", "EsflCubes (flash-array data cubes)")
    check_optional(params, EsflParams, "esfl_chain: params")
    p = params or EsflParams()
    wf = esfl_waveforms(data, p)
    return wf, esfl_process(wf, p)
