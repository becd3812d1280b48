"""Cut a prepared track into windows that no block of any length straddles.

Blocks are independent: every quantity of a block (noise filter, histogram, windows, z90)
depends on its own photons only.  The engine therefore runs window by window over about
a million photons at a time -- its temporaries (block indices, filter masks, histogram
keys) then take a fixed amount of memory instead of growing with the track -- and
concatenates the per-block results, which are the whole-track results value for value.

A cut lies before photon ``i`` only when, for every block length ``L``, the photon's block
index differs from its predecessor's, computed exactly as the engine computes it
(``int64((s - s0) / L)`` in float64).  The first such photon at or after each multiple of
the window size is taken; a window grows until one exists (lengths that never share a
boundary give one window).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .prepared import LengthResult, PreparedTrack

__all__ = ["DEFAULT_WINDOW_PHOTONS", "window_cuts", "window_of", "concat_length_results"]

#: Photons per window of the engine (about 100 MB of temporaries).
DEFAULT_WINDOW_PHOTONS = 1_000_000


def _block_index(s: np.ndarray, s0: float, length: float) -> np.ndarray:
    rel = s - s0
    rel /= length
    return rel.astype(np.int64)


def window_cuts(s: np.ndarray, s0: float, lengths: Sequence[float], window: int) -> np.ndarray:
    """Photon indices ``[0, c1, ..., n]`` of windows of about ``window`` photons each.

    Parameters
    ----------
    s : array (n,)
        Along-track distances of the prepared photons, metres, sorted, ``>= s0``.
    s0 : float
        Start of block 0, metres.
    lengths : sequence of float
        Block lengths, metres.
    window : int
        Target photons per window (>= 1).
    """
    n = s.size
    cuts = [0]
    target = window
    while target < n:
        span = max(4096, window // 8)
        found = -1
        lo = target
        while lo < n and found < 0:
            hi = min(n, lo + span)
            seg = s[lo - 1:hi]
            new = np.ones(hi - lo, bool)
            for length in lengths:
                b = _block_index(seg, s0, length)
                new &= b[1:] != b[:-1]
            hit = np.flatnonzero(new)
            if hit.size:
                found = lo + int(hit[0])
            lo, span = hi, span * 2
        if found < 0:
            break
        cuts.append(found)
        target = found + window
    cuts.append(n)
    return np.asarray(cuts, dtype=np.int64)


def window_of(pt: PreparedTrack, a: int, b: int) -> PreparedTrack:
    """The prepared photons ``a:b`` (views, same ``s0``)."""
    return replace(
        pt, s=pt.s[a:b], z=pt.z[a:b], x=pt.x[a:b], y=pt.y[a:b],
        conf_mask=None if pt.conf_mask is None else pt.conf_mask[a:b],
        index=None if pt.index is None else pt.index[a:b], first=pt.first + a)


def concat_length_results(parts: Sequence[LengthResult]) -> LengthResult:
    """The results of consecutive windows for one length as one."""
    from .prepared import LengthResult

    if len(parts) == 1:
        return parts[0]

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(p, name) for p in parts])

    labels = None if parts[0].labels is None else cat("labels")
    return LengthResult(parts[0].length, cat("block"), cat("n_photons"), cat("n_kept"),
                        cat("n_between"), cat("top"), cat("ground"), cat("z90"), cat("flag"),
                        cat("x"), cat("y"), labels)
