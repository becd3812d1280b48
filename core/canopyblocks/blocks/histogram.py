"""Vectorised per-block noise filter, histograms, expansion windows and H90.

Everything here works on photons already cut into contiguous blocks (the track is
sorted by ``s``, so block ``i`` is one run ``z[start_i : start_i + count_i]``).  There
is no Python loop over photons or over blocks:

* sums, minima and maxima per block are ``np.add/np.minimum/np.maximum.reduceat``
  over the block starts;
* each kept photon gets a global histogram key ``offset[block] + bin``, where the
  offsets are the running total of the blocks' bin counts, so all histograms live
  in one array; their cumulative counts are one global ``cumsum`` (or, when the
  histograms would be much larger than the photon count, one ``np.sort`` of the keys);
* the expansion window stops at the first bin where the cumulative fraction reaches
  the cut-off.  With ``m`` the smallest photon count whose fraction ``m / n`` reaches
  the cut-off, that bin is the bin of the ``m``-th lowest kept photon (ground) or the
  ``m``-th highest (top), but never inside the initial window: this is an order
  statistic of the global keys, found with one ``searchsorted`` per block
  (``tests/test_blocks_oracle.py`` checks it against the paper's loop);
* the photons with ``ground <= z <= top`` are, in height order, a run of the block's
  kept photons starting at rank ``#(z < ground)``; both counts are one comparison
  and one ``reduceat`` each, so ``z90`` is again an order statistic of the kept
  photons: its bin comes from the cumulative counts and only the photons of that
  one bin per block are sorted (``np.lexsort`` on a small subset).  Bins are
  non-decreasing in ``z`` (float64 subtraction, division and truncation are
  monotonic), so key order and height order agree.

Floating point: a photon's bin is ``floor((z - zmin) / bin_size)`` evaluated in
float64 and clipped to ``nb - 1`` with ``nb = max(1, ceil((zmax - zmin) / bin_size))``;
``top = zmin + t * bin_size`` and ``ground = zmin + (g + 1) * bin_size``.  These exact
expressions *are* the definition (the test oracle evaluates the same ones), so a
photon within rounding of a bin edge falls where float64 puts it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

__all__ = ["BlockHistograms", "sigma_filter", "count_needed", "segment_starts"]

log = logging.getLogger(__name__)

#: Use dense global histograms while their total bin count is at most this many
#: times the number of kept photons (plus a floor): at most 16 bytes per photon; beyond,
#: sort the keys instead (slower, 8 bytes per photon).
DENSE_FACTOR = 2
DENSE_FLOOR = 1 << 16


def segment_starts(block: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of equal values in a non-decreasing integer array.

    Returns
    -------
    ids : ndarray int64
        The value of each run (the block index).
    starts : ndarray int64
        Index of the first element of each run.
    counts : ndarray int64
        Length of each run (>= 1).
    """
    n = block.size
    if n == 0:
        e = np.empty(0, np.int64)
        return e, e, e
    starts = np.flatnonzero(block[1:] != block[:-1])
    starts += 1
    starts = np.concatenate((np.zeros(1, np.int64), starts.astype(np.int64)))
    counts = np.diff(np.append(starts, n))
    return block[starts].astype(np.int64), starts, counts


def sigma_filter(z: np.ndarray, starts: np.ndarray, counts: np.ndarray,
                 mask: np.ndarray | None, k_sigma: float,
                 work: np.ndarray | None = None) -> np.ndarray:
    """The paper's noise filter: keep ``|z - mean| <= k * std`` per block.

    ``std`` uses ``ddof=1``; a block whose std is 0 or that holds one photon keeps
    all its photons.  Mean and std are two-pass (no loss of precision on large
    ellipsoidal heights).  Only photons with ``mask`` True take part (all when
    ``mask`` is None); the others are never kept.

    ``work`` is an optional float64 scratch array of at least ``z.size`` elements
    (its content is overwritten).

    Returns
    -------
    keep : ndarray of bool, one per photon.
    """
    if mask is None:
        cnt = counts.astype(np.float64)
        zsum = np.add.reduceat(z, starts)
    else:
        cnt = np.add.reduceat(mask, starts, dtype=np.int64).astype(np.float64)
        zsum = np.add.reduceat(np.where(mask, z, 0.0), starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = zsum / cnt
        rep = np.repeat(mean, counts)
        d = np.subtract(z, rep, out=None if work is None else work[: z.size])
        d2 = np.multiply(d, d, out=rep)
        del rep
        if mask is not None:
            d2[~mask] = 0.0
        var = np.add.reduceat(d2, starts)
        del d2
        var /= cnt - 1.0
        thr = k_sigma * np.sqrt(var)
        thr[(cnt <= 1.0) | (var == 0.0)] = np.inf
    np.abs(d, out=d)
    keep = d <= np.repeat(thr, counts)
    if mask is not None:
        keep &= mask
    return keep


def _ranges(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Concatenated ``arange(start, start + length)`` for each pair, vectorised."""
    total = int(lengths.sum())
    first = np.zeros(lengths.size, np.int64)
    np.cumsum(lengths[:-1], out=first[1:])
    return np.arange(total, dtype=np.int64) + np.repeat(starts - first, lengths)


def count_needed(cutoff: float, n: np.ndarray) -> np.ndarray:
    """Smallest count ``m`` (1..n) with ``m / n >= cutoff`` in float64, per block.

    This is where the paper's loop ("extend while the fraction is below the
    cut-off") stops counting; ``n`` must be >= 1 and ``0 < cutoff < 1``.
    """
    nf = n.astype(np.float64)
    m = np.ceil(cutoff * nf)
    m = np.where((m - 1.0) / nf >= cutoff, m - 1.0, m)
    m = np.where(m / nf < cutoff, m + 1.0, m)
    return np.clip(m, 1.0, nf).astype(np.int64)


@dataclass
class BlockHistograms:
    """Histograms of the kept photons of every block, built once.

    Only blocks with at least one kept photon are represented; ``index`` maps them
    to the caller's block positions.  Attributes are per represented block unless
    stated.

    Attributes
    ----------
    index : ndarray int64
        Positions (in the caller's block arrays) of the represented blocks.
    zk : ndarray float64
        Kept photons' heights, block by block, in track order (metres).
    nk : ndarray int64
        Kept photons per block.
    base : ndarray int64
        Index in ``zk`` of each block's first kept photon.
    zmin : ndarray float64
        Lowest kept photon, the histogram anchor (metres).
    nb : ndarray int64
        Bins per block.
    offset : ndarray int64
        Global key of each block's bin 0.
    key : ndarray int64
        Global histogram key of every kept photon.
    """

    index: np.ndarray
    zk: np.ndarray
    nk: np.ndarray
    base: np.ndarray
    zmin: np.ndarray
    nb: np.ndarray
    offset: np.ndarray
    key: np.ndarray
    bin_size: float
    window_bins: int
    _cum: np.ndarray | None = None      # dense: cumulative counts per global bin
    _sorted: np.ndarray | None = None   # sparse: keys sorted

    @classmethod
    def build(cls, z: np.ndarray, starts: np.ndarray, counts: np.ndarray,
              keep: np.ndarray | None, bin_size: float, window_bins: int,
              dense: bool | None = None, key_buffer: np.ndarray | None = None
              ) -> BlockHistograms:
        """Histogram the photons ``z`` (blocks given by ``starts``/``counts``).

        ``keep`` selects the photons that count (None: all).  ``dense`` forces the
        dense (True) or sorted-key (False) representation; None chooses by size.
        ``key_buffer`` (int64, at least ``z.size`` long, content overwritten) becomes
        the storage of the photon keys, saving an allocation.
        """
        if keep is None:
            nk_all = counts
            zk = z
        else:
            nk_all = (np.add.reduceat(keep.view(np.uint8), starts, dtype=np.int32)
                      if starts.size else counts)
            zk = z[keep]
        index = np.flatnonzero(nk_all > 0)
        nk = nk_all[index].astype(np.int64)
        base = np.zeros(nk.size, np.int64)
        if nk.size:
            np.cumsum(nk[:-1], out=base[1:])
            zmin = np.minimum.reduceat(zk, base)
            zmax = np.maximum.reduceat(zk, base)
        else:
            zmin = zmax = np.empty(0)
        span = (zmax - zmin) / bin_size
        nb = np.maximum(1.0, np.ceil(span)).astype(np.int64)
        offset = np.zeros(nb.size, np.int64)
        if nb.size:
            np.cumsum(nb[:-1], out=offset[1:])
        total = int(nb.sum())
        # bin = floor((z - zmin) / bin_size) (>= 0, so truncation is floor) ...
        rel = np.repeat(zmin, nk)
        np.subtract(zk, rel, out=rel)
        rel /= bin_size
        if key_buffer is None:
            key = rel.astype(np.int64)
        else:
            key = key_buffer[: rel.size]
            np.copyto(key, rel, casting="unsafe")
        del rel
        # ... clipped to nb - 1: only blocks whose span is a whole number >= 1 of bins
        # can hold a photon with bin == nb (those at the top of the span)
        clip = np.flatnonzero((span == nb) & (nb >= 1))
        n_clip = int(nk[clip].sum())
        if n_clip * 16 > key.size:
            np.minimum(key, np.repeat(nb - 1, nk), out=key)
        elif n_clip:
            idx = _ranges(base[clip], nk[clip])
            key[idx] = np.minimum(key[idx], np.repeat(nb[clip] - 1, nk[clip]))
        key += np.repeat(offset, nk)
        self = cls(index, zk, nk, base, zmin, nb, offset, key, float(bin_size), int(window_bins))
        if dense is None:
            dense = total <= DENSE_FACTOR * int(key.size) + DENSE_FLOOR
        if dense:
            cum = np.bincount(key, minlength=total)
            self._cum = np.cumsum(cum, out=cum)
        else:
            self._sorted = np.sort(key)
        log.debug("histograms: %d blocks, %d kept photons, %d bins (%s)", nk.size, key.size,
                  total, "dense" if dense else "sorted")
        return self

    # -------------------------------------------------------------- helpers
    def _key_of_rank(self, rank: np.ndarray) -> np.ndarray:
        """Global key of the kept photon with global 0-based rank ``rank`` (key order)."""
        if self._cum is not None:
            return np.searchsorted(self._cum, rank, side="right")
        assert self._sorted is not None
        return self._sorted[rank]

    @property
    def first_window(self) -> np.ndarray:
        """Initial window height in bins per block (the whole histogram if shorter)."""
        return np.minimum(self.window_bins, self.nb)

    # -------------------------------------------------------------- windows
    def ground_bin(self, cutoff: float) -> np.ndarray:
        """Local index of the bin where the ground window stops, per block."""
        if self.nk.size == 0:
            return np.empty(0, np.int64)
        m = count_needed(cutoff, self.nk)
        g = self._key_of_rank(self.base + m - 1) - self.offset
        return np.maximum(g, self.first_window - 1)

    def top_bin(self, cutoff: float) -> np.ndarray:
        """Local index of the bin where the top window stops, per block."""
        if self.nk.size == 0:
            return np.empty(0, np.int64)
        m = count_needed(cutoff, self.nk)
        t = self._key_of_rank(self.base + self.nk - m) - self.offset
        return np.minimum(t, self.nb - self.first_window)

    def top_height(self, t: np.ndarray) -> np.ndarray:
        """Canopy top: the lower edge of bin ``t`` (metres)."""
        return self.zmin + t * self.bin_size

    def ground_height(self, g: np.ndarray) -> np.ndarray:
        """Mean ground: the upper edge of bin ``g`` (metres)."""
        return self.zmin + (g + 1) * self.bin_size

    # -------------------------------------------------------------- between / z90
    def count_between(self, top: np.ndarray, ground: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Per block: kept photons below ``ground`` and kept photons between.

        Returns ``(n_below, n_between)`` with ``n_below = #(z < ground)`` and
        ``n_between = #(ground <= z <= top) = max(0, #(z <= top) - n_below)``.
        """
        if self.nk.size == 0:
            e = np.empty(0, np.int64)
            return e, e
        cmp = np.less(self.zk, np.repeat(ground, self.nk))
        n_below = np.add.reduceat(cmp.view(np.uint8), self.base, dtype=np.int32)
        np.less_equal(self.zk, np.repeat(top, self.nk), out=cmp)
        n_le = np.add.reduceat(cmp.view(np.uint8), self.base, dtype=np.int32)
        n_between = np.maximum(n_le.astype(np.int64) - n_below, 0)
        return n_below.astype(np.int64), n_between

    def z90(self, n_below: np.ndarray, n_between: np.ndarray, q: float = 0.9) -> np.ndarray:
        """``sorted(z_between)[floor(q * (n - 1))]`` per block (NaN when none between).

        The photons between ground and top are ranks ``n_below .. n_below + n - 1`` of
        the block's kept photons in height order, so ``z90`` is the kept photon of
        rank ``n_below + floor(q (n - 1))``: its bin comes from the cumulative
        counts, and only the photons of that bin are sorted.
        """
        out = np.full(self.nk.size, np.nan)
        has = n_between > 0
        if not has.any():
            return out
        rank = n_below[has] + np.floor(q * (n_between[has] - 1)).astype(np.int64)
        grank = self.base[has] + rank
        qkey = self._key_of_rank(grank)
        if self._cum is not None:
            before = np.where(qkey > 0, self._cum[np.maximum(qkey - 1, 0)], 0)
        else:
            assert self._sorted is not None
            before = np.searchsorted(self._sorted, qkey, side="left")
        within = grank - before
        qfull = np.full(self.nk.size, -1, np.int64)
        qfull[has] = qkey
        idx = np.flatnonzero(self.key == np.repeat(qfull, self.nk))
        ks, zs = self.key[idx], self.zk[idx]
        order = np.lexsort((zs, ks))
        ks, zs = ks[order], zs[order]
        first = np.searchsorted(ks, qkey, side="left")
        out[has] = zs[first + within]
        return out

    # -------------------------------------------------------------- labels
    def bins(self) -> np.ndarray:
        """Local bin index of every kept photon."""
        return self.key - np.repeat(self.offset, self.nk)
