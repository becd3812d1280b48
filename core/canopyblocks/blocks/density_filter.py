"""A density noise filter in the spirit of ATL08's DRAGANN (DESIGN 1.10, ``noise="density"``).

Signal photons cluster near the surface; solar background photons are spread evenly over
the height window. Each photon's neighbours are counted in a box of ``+-along`` metres
along the track and ``+-height`` metres in height; a photon is kept when its count
exceeds the ``quantile`` of the Poisson count that background alone would give there.

The background rate (photons per metre along-track per metre of height) is estimated
per along-track segment of ``segment`` metres: the photons of the segment are
histogrammed in height bins of ``2 * height`` metres over the segment's whole height
range, and the rate is the median of the bin counts (signal fills few bins of a wide
telemetry window). Where the height range is too narrow to hold background bins
(under ``min_range`` metres), the data carry no measurable background and every photon
is kept. A known rate may be given instead.

Counting uses a summed-area table of a fine grid (cells a fifth of the box by default), per
segment with a margin, so the cost is linear in photons and in segment area.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..readers.atl03_background import poisson_quantile
from .kernels import compiled, enabled

__all__ = ["DensityParams", "DensityResult", "density_filter", "box_area", "poisson_quantile"]

log = logging.getLogger(__name__)

_MAX_CELLS = 40_000_000
_ENTRIES = 1 << 17  # photons (with the segments' margins) counted together
_CELLS = 1 << 21  # grid cells summed together


@dataclass(frozen=True)
class DensityParams:
    """Parameters of :func:`density_filter` (metres unless stated).

    Attributes
    ----------
    along, height : float
        Half-sizes of the neighbour box (10 m along-track, 1.5 m in height).
    quantile : float
        Keep photons whose neighbour count exceeds this Poisson quantile of the
        background count (0.999).
    segment : float
        Along-track length of the segments with their own background rate (200 m).
    background : float or None
        Known background rate (photons per m along-track per m height); None: estimated.
    min_range : float
        Minimum height range (m) of a segment to estimate a background in it (60 m).
    edge_correction : bool
        Scale the counts of photons within ``along`` of the track's ends by the share of
        their box inside the track (otherwise half a box of neighbours is missing there and
        signal at the ends is lost); off by default (the ``density`` estimator's behaviour).
    cells : int
        Grid cells per box half-size (5): the box is ``2 cells + 1`` cells wide, i.e.
        +-(1 + 1/(2 cells)) x ``along`` and ``height``; fewer cells cost less (the grid spans
        the whole telemetry window) and round the box more coarsely.
    origin : float or None
        Along-track distance (m) where the first background segment starts; None: at the
        first photon.  A part of a track read for a box sets the whole track's first
        photon, so that its segments (and rates) are those of a run over the whole track.
    """

    along: float = 10.0
    height: float = 1.5
    quantile: float = 0.999
    segment: float = 200.0
    background: float | None = None
    min_range: float = 60.0
    edge_correction: bool = False
    cells: int = 5
    origin: float | None = None

    def __post_init__(self) -> None:
        for name in ("along", "height", "segment", "min_range"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"density filter {name} must be a positive number of "
                                 f"metres, got {v!r}")
        if not (isinstance(self.quantile, float) and 0.5 <= self.quantile < 1.0):
            raise InputError(f"density filter quantile must be in [0.5, 1), got "
                             f"{self.quantile!r}")
        if self.background is not None and not (np.isfinite(self.background)
                                                and self.background >= 0):
            raise InputError(f"background rate must be >= 0 photons/m^2, got "
                             f"{self.background!r}")
        if not (isinstance(self.cells, int) and not isinstance(self.cells, bool)
                and 1 <= self.cells <= 10):
            raise InputError(f"density filter cells must be an integer 1..10, got "
                             f"{self.cells!r}")
        if self.origin is not None and not (isinstance(self.origin, (int, float))
                                            and np.isfinite(self.origin)):
            raise InputError(f"density filter origin must be None or a finite along-track "
                             f"distance (m), got {self.origin!r}")
        if self.segment < 2 * self.along:
            raise InputError("density filter segment must be at least twice 'along'")


@dataclass(frozen=True)
class DensityResult:
    """``keep`` per photon; ``count`` its neighbours (itself included); ``rate`` the
    background rate (photons/m^2) of its segment; ``threshold`` the count it had to beat."""

    keep: np.ndarray
    count: np.ndarray
    rate: np.ndarray
    threshold: np.ndarray

    @property
    def background_share(self) -> float:
        """Share of the photons removed."""
        return float(1.0 - self.keep.mean()) if self.keep.size else 0.0


def _box_counts(ss: np.ndarray, zs: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                lo: np.ndarray, hi: np.ndarray, p: DensityParams) -> np.ndarray:
    """Neighbours of each photon within the box (itself included), on a fine grid per
    along-track segment: the photons ``starts[k]:ends[k]`` of the s-sorted track counted
    on the grid of ``lo[k]:hi[k]`` (the segment with a margin of one box each side, so
    counts near its ends see their true neighbours), origin at that slice's lowest s and z.

    The grids of many segments are stacked in one array and summed at once (a summed-area
    table): a box's count is a difference of the table between rows of its own grid, in
    which the sums over the grids before it cancel (exact integers). Each grid is padded
    with a box's width of empty cells on every side, so no box needs clipping.
    """
    out = np.empty(ss.size, np.int64)
    _check_span(ss, zs, p)
    mod = compiled() if enabled() else None
    if mod is not None:  # one compiled pass: a running histogram of rows (the same counts)
        k, nc, nr = mod.box_counts(ss, zs, starts.astype(np.int64), ends.astype(np.int64),
                                   lo.astype(np.int64), hi.astype(np.int64),
                                   p.along / p.cells, p.height / p.cells, p.cells,
                                   _MAX_CELLS, out)
        if k >= 0:
            _too_large(nc, nr)
        return out
    lens = hi - lo
    k0 = 0
    while k0 < starts.size:  # groups of segments of about _ENTRIES photons (with margins)
        k1 = k0 + max(int(np.searchsorted(np.cumsum(lens[k0:]), _ENTRIES)), 1)
        _group_counts(ss, zs, starts[k0:k1], ends[k0:k1], lo[k0:k1], hi[k0:k1], p, out)
        k0 = k1
    return out


def _check_span(ss: np.ndarray, zs: np.ndarray, p: DensityParams) -> None:
    """Refuse a track whose heights (or distances) span more grid cells than a cell index
    holds (far outliers): the compiled loop would index outside its grid."""
    if ss.size == 0:
        return
    nc = float(np.ptp(ss)) / (p.along / p.cells)
    nr = float(np.ptp(zs)) / (p.height / p.cells)
    if not (np.isfinite(nc) and np.isfinite(nr)) or max(nc, nr) >= 2**31 - 2:
        _too_large(int(min(nc, 2**62)) + 1 if np.isfinite(nc) else -1,
                   int(min(nr, 2**62)) + 1 if np.isfinite(nr) else -1)


def _too_large(nc: int, nr: int) -> None:
    raise InputError(
        f"density filter grid of {nc} x {nr} cells for one segment is too large; the "
        "height range is huge (fill values or far outliers?): remove them first")


def _group_counts(ss: np.ndarray, zs: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                  lo: np.ndarray, hi: np.ndarray, p: DensityParams, out: np.ndarray) -> None:
    """:func:`_box_counts` of some segments, into ``out``."""
    sub = p.cells
    box = 2 * sub + 1
    ds = p.along / sub
    dz = p.height / sub
    lens = hi - lo
    first = np.concatenate([[0], np.cumsum(lens)[:-1]])  # each segment's first entry
    total = int(lens.sum())
    idx = np.arange(total) + np.repeat(lo - first, lens)  # the photon of each entry
    ze = zs[idx]
    # (the lowest s of a slice of the sorted track is its first)
    ci = np.floor((ss[idx] - np.repeat(ss[lo], lens)) / ds).astype(np.int32)
    ri = np.floor((ze - np.repeat(np.minimum.reduceat(ze, first), lens)) / dz
                  ).astype(np.int32)
    del ze, idx
    nc = np.maximum.reduceat(ci, first).astype(np.int64) + 1
    nr = np.maximum.reduceat(ri, first).astype(np.int64) + 1
    big = np.flatnonzero(nc * nr > _MAX_CELLS)
    if big.size:
        _too_large(int(nc[big[0]]), int(nr[big[0]]))
    # each segment's own photons are a run of its entries; in entry order they are the
    # photons starts[0]:ends[-1] in order
    mark = (np.bincount(first + starts - lo, minlength=total + 1)
            - np.bincount(first + ends - lo, minlength=total + 1))
    own = np.cumsum(mark[:-1]) > 0
    del mark
    width = int(nc.max()) + 2 * sub + 1  # box columns of padding left and right
    rows = nr + 2 * sub + 1  # box rows of padding above and below
    g0 = 0
    while g0 < lens.size:  # stacks of about _CELLS cells
        g1 = g0 + max(int(np.searchsorted(np.cumsum(rows[g0:]) * width, _CELLS, "right")), 1)
        e0, e1 = int(first[g0]), int(first[g1 - 1] + lens[g1 - 1])
        height = int(rows[g0:g1].sum())
        top = np.concatenate([[0], np.cumsum(rows[g0:g1])[:-1]])  # each grid's first row
        it = np.int32 if width * height < 2**31 - 1 else np.int64
        # laid out column by column (the long axis contiguous: both sums run fast); the
        # photon at grid column c, row r of its segment sits in cell (c + sub + 1,
        # top + r + sub + 1); its box's corners in the table, below and left of the box,
        # are column c and row top + r, "base", and base + box columns / rows
        base = (ci[e0:e1].astype(it) * it(height)
                + np.repeat(top.astype(it), lens[g0:g1]) + ri[e0:e1])
        # (bincount, not np.add.at: the same counts, several times faster; int32 sums are
        # exact below 2**31 photons a stack)
        grid = np.bincount(base + it((sub + 1) * height + sub + 1),
                           minlength=width * height).astype(np.int32)
        sat = grid.reshape(width, height).cumsum(1, dtype=np.int32).cumsum(0, dtype=np.int32)
        sat = sat.ravel()
        del grid
        base = base[own[e0:e1]]
        dc, dr = box * height, box
        cnt = (sat[dc + dr:].take(base) - sat[dr:].take(base) - sat[dc:].take(base)
               + sat.take(base))
        out[int(starts[g0]):int(ends[g1 - 1])] = cnt
        g0 = g1


def _segment_rate(z: np.ndarray, length: float, p: DensityParams) -> float:
    lo, hi = float(z.min()), float(z.max())
    if hi - lo < p.min_range:
        return 0.0
    width = 2.0 * p.height
    nb = int(np.ceil((hi - lo) / width))
    counts = np.bincount(np.minimum(((z - lo) / width).astype(np.int64), nb - 1), minlength=nb)
    return float(np.median(counts)) / (length * width)


def density_filter(s: np.ndarray, z: np.ndarray,
                   params: DensityParams | None = None, *,
                   rate: np.ndarray | None = None) -> DensityResult:
    """Keep photons denser than background (DRAGANN-like).

    Parameters
    ----------
    s, z : ndarray
        Along-track distance and height (m) of the photons, any order.
    params : DensityParams, optional
    rate : ndarray, optional
        Known background per photon (photons per m along-track per m of height, e.g.
        from ATL03 ``bckgrd_rate``): each segment uses the mean over its photons
        instead of an estimate (``params.background``, when set, still wins).

    Returns
    -------
    DensityResult
        Per photon, in the input order. Photons with non-finite s/z are not kept.
    """
    p = params or DensityParams()
    s = np.asarray(s, float)
    z = np.asarray(z, float)
    if s.shape != z.shape:
        raise InputError(f"s and z differ in shape: {s.shape} vs {z.shape}")
    if rate is not None:
        rate = np.asarray(rate, float)
        if rate.shape != s.shape:
            raise InputError(f"rate has shape {rate.shape}; one value per photon {s.shape} "
                             "is needed")
    return DensityResult(*_filter(s, z, p, rate, full=True))


def _filter(s: np.ndarray, z: np.ndarray, p: DensityParams, rate: np.ndarray | None, *,
            full: bool = False, with_rate: bool = False) -> tuple[np.ndarray, ...]:
    """:func:`density_filter` on checked float arrays: ``keep``, then with ``full`` the
    count, rate and threshold per photon, or with ``with_rate`` the rate only (fewer
    full-length arrays: the classifier needs no more)."""
    n = s.size
    keep = np.zeros(n, bool)
    fin = np.isfinite(s) & np.isfinite(z)
    order: np.ndarray | slice
    if fin.all():
        # a track read from a file comes sorted by s: then no copies in sorted order
        order = slice(None) if n < 2 or bool(np.all(s[1:] >= s[:-1])) else np.argsort(
            s, kind="stable")
    else:
        ok = np.flatnonzero(fin)
        order = ok[np.argsort(s[ok], kind="stable")]
    del fin
    if n == 0 or (isinstance(order, np.ndarray) and order.size == 0):
        return (keep, np.zeros(n, np.int64), np.zeros(n), np.zeros(n))[:4 if full else
                                                                         2 if with_rate else 1]
    ss = s[order]
    seg = np.floor((ss - (ss[0] if p.origin is None else p.origin)) / p.segment
                   ).astype(np.int64)
    bounds = np.flatnonzero(np.diff(seg)) + 1
    del seg
    starts = np.concatenate([[0], bounds])
    ends = np.concatenate([bounds, [ss.size]])
    area = box_area(p)
    quantiles: dict[float, float] = {}
    zs = z[order]  # sorted once: each segment is then a contiguous slice
    rs = rate[order] if rate is not None else None
    lam_seg = np.empty(starts.size)
    thr_seg = np.empty(starts.size)
    lo_all = np.searchsorted(ss, ss[starts] - p.along, side="left")
    hi_all = np.searchsorted(ss, ss[ends - 1] + p.along, side="right")
    cnt_s = _box_counts(ss, zs, starts, ends, lo_all, hi_all, p)
    for k, (a, b) in enumerate(zip(starts.tolist(), ends.tolist())):
        length = max(float(ss[b - 1] - ss[a]), p.along)
        if p.background is not None:
            lam = p.background
        elif rs is not None:
            lam = float(np.mean(rs[a:b]))
        else:
            lam = _segment_rate(zs[a:b], length, p)
        mu = lam * area
        t = quantiles.get(mu)
        if t is None:  # rates repeat from segment to segment: one quantile each
            t = quantiles[mu] = poisson_quantile(p.quantile, mu)
        lam_seg[k] = lam
        thr_seg[k] = t
    del zs, rs
    if p.edge_correction:
        # the share of the box inside the track is exactly 1 farther than `along` from both
        # ends, where the correction leaves the count as it is: correct the ends only
        near_end = (ss - ss[0] < p.along) | (ss[-1] - ss < p.along)
        e = np.flatnonzero(near_end)
        del near_end
        se = ss[e]
        inside = (np.minimum(se - ss[0], p.along) + np.minimum(ss[-1] - se, p.along)
                  ) / (2.0 * p.along)
        cnt_s[e] = np.rint(1 + (cnt_s[e] - 1) / np.maximum(inside, 0.5)).astype(np.int64)
        del inside, se, e
    del ss
    lens = ends - starts
    thr_s = np.repeat(thr_seg, lens)
    keep[order] = cnt_s - 1 > thr_s  # the count includes the photon itself
    out: tuple[np.ndarray, ...] = (keep,)
    if full:
        count = np.zeros(n, np.int64)
        count[order] = cnt_s
        thr = np.zeros(n)
        thr[order] = thr_s
    del cnt_s, thr_s
    if full or with_rate:
        rates = np.zeros(n)
        rates[order] = np.repeat(lam_seg, lens)
        out = (keep, count, rates, thr) if full else (keep, rates)
    return out


def box_area(p: DensityParams) -> float:
    """Area (m^2) of the counting box: (2 cells + 1) grid cells of along/cells by
    height/cells around the photon's cell."""
    return ((2 * p.cells + 1) * p.along / p.cells) * ((2 * p.cells + 1) * p.height / p.cells)


