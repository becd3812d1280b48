"""The block engine: canopy top, mean ground, Hmax and H90 per along-track block.

Implements DESIGN.md section 1 (seed 001 section 2.3) for one photon track and any
number of block lengths; the vectorised kernels live in :mod:`.histogram`.
"""

from __future__ import annotations

import logging
import os
import warnings
from dataclasses import replace
from typing import TYPE_CHECKING, Literal, overload

import numpy as np
import pandas as pd

from ..errors import CanopyBlocksWarning, InputError, NoUsableDataError, SparseBlockWarning
from ..geo import from_metric, require_metric_crs
from ..photons import PhotonTrack
from ..progress import Progress, as_progress
from ..schema import (
    BLOCK_COLUMNS,
    FLAG_INVERTED,
    FLAG_OK,
    FLAG_SPARSE,
    LABEL_BETWEEN,
    LABEL_CANOPY,
    LABEL_GROUND,
    LABEL_NOISE,
)
from .histogram import BlockHistograms, segment_starts, sigma_filter
from .params import BlockParams
from .plausibility import background_fraction, flag_implausible_blocks
from .prepared import LengthResult, PreparedTrack
from .uncertainty import mark_use
from .windows import (
    DEFAULT_WINDOW_PHOTONS,
    _block_index,
    concat_length_results,
    window_cuts,
    window_of,
)

if TYPE_CHECKING:
    import geopandas as gpd

MAX_TRACK_SPAN_M = 1.0e9
"""Longest along-track extent accepted, metres (an orbit is ~4e7 m; fills are ~3.4e38)."""

__all__ = ["compute_blocks", "LABEL_OUTSIDE", "PreparedTrack", "prepare_track", "LengthResult",
           "blocks_for_length", "block_skeleton"]

log = logging.getLogger(__name__)

#: Label of photons that lie in no block (``s < s0``, or NaN height/position).
LABEL_OUTSIDE = -1

_FLAG_CODES = np.array([FLAG_OK, FLAG_SPARSE, FLAG_INVERTED], dtype=object)


def prepare_track(track: PhotonTrack, params: BlockParams) -> PreparedTrack:
    """Check the track and select the photons that can lie in a block.

    Raises
    ------
    InputError
        Unequal column lengths, a non-metric CRS, or ``min_signal_conf`` set on a
        track without ``signal_conf``.
    NoUsableDataError
        No photon with finite values at or after ``s0``.
    """
    n = len(track)
    for name in ("s", "h", "x", "y"):
        if getattr(track, name).shape != (n,):
            raise InputError(f"track {track.track}: column {name!r} has shape "
                             f"{getattr(track, name).shape}, expected ({n},)")
    require_metric_crs(track.crs, f"track {track.track} CRS")
    conf = None
    if params.min_signal_conf is not None:
        if track.signal_conf is None:
            raise InputError(
                f"track {track.track}: min_signal_conf={params.min_signal_conf} needs the "
                "ATL03 signal_conf_ph of each photon, but this track has none; read an ATL03 "
                "file or set min_signal_conf=None"
            )
        conf = np.asarray(track.signal_conf)
    s = np.asarray(track.s, dtype=np.float64)
    z = np.asarray(track.h, dtype=np.float64)
    x = np.asarray(track.x, dtype=np.float64)
    y = np.asarray(track.y, dtype=np.float64)
    if n == 0:
        raise NoUsableDataError(f"track {track.track} ({track.source or 'in memory'}) holds "
                                "no photons")
    # a finite sum proves every value finite (cheap); otherwise find the bad photons
    with np.errstate(over="ignore", invalid="ignore"):
        all_finite = bool(np.isfinite(s.sum() + z.sum() + x.sum() + y.sum()))
    finite: np.ndarray | None = None
    if not all_finite:
        finite = np.isfinite(s) & np.isfinite(z) & np.isfinite(x) & np.isfinite(y)
        n_bad = int(n - np.count_nonzero(finite))
        all_finite = n_bad == 0
        if n_bad == n:
            raise NoUsableDataError(
                f"track {track.track} ({track.source or 'in memory'}) holds no photon with a "
                f"finite height and position ({n} photons)")
        if n_bad:
            warnings.warn(
                f"track {track.track}: {n_bad} of {n} photons have a NaN/inf height or "
                "position and lie in no block",
                CanopyBlocksWarning, stacklevel=3,
            )
    if params.s0 is not None:
        s0 = params.s0
    else:
        s0 = float(np.min(s)) if finite is None else float(np.min(s[finite]))
    s_max = float(np.max(s)) if finite is None else float(np.max(s[finite]))
    if s_max - s0 > MAX_TRACK_SPAN_M:  # block indices would overflow int64 (fill values)
        raise InputError(
            f"track {track.track} ({track.source or 'in memory'}): along-track distances run "
            f"from {s0:.6g} to {s_max:.6g} m, longer than any track ({MAX_TRACK_SPAN_M:.0e} m); "
            "s holds fill values (e.g. ATL03's 3.4028235e38): drop those photons")
    is_sorted = all_finite and (n < 2 or bool(np.all(s[1:] >= s[:-1])))
    if is_sorted:
        first = int(np.searchsorted(s, s0, side="left"))
        if first >= n:
            raise _none_after(track, s0, params)
        cm = None if conf is None else conf[first:] >= params.min_signal_conf
        return PreparedTrack(s[first:], z[first:], x[first:], y[first:], cm, s0, None, first, n)
    inside = s >= s0
    if finite is not None:
        inside &= finite
    idx = np.flatnonzero(inside)
    if idx.size == 0:
        raise _none_after(track, s0, params)
    idx = idx[np.argsort(s[idx], kind="stable")]
    cm = None if conf is None else conf[idx] >= params.min_signal_conf
    return PreparedTrack(s[idx], z[idx], x[idx], y[idx], cm, s0, idx, 0, n)


def _none_after(track: PhotonTrack, s0: float, params: BlockParams) -> NoUsableDataError:
    return NoUsableDataError(
        f"track {track.track}: no photon at or after s0={s0} m (the track's s runs "
        f"{float(np.nanmin(track.s)):.1f}..{float(np.nanmax(track.s)):.1f} m); set s0 "
        "within the track or leave it None"
    )


def blocks_for_length(pt: PreparedTrack, params: BlockParams, length: float, *,
                      labels: bool = False, top_cutoff: float | None = None,
                      ground_cutoff: float | None = None,
                      dense: bool | None = None) -> tuple[LengthResult, BlockHistograms]:
    """Run the engine for one block ``length`` (m) on prepared photons.

    ``top_cutoff``/``ground_cutoff`` override ``params.cutoffs_for(length)``;
    ``dense`` forces a histogram representation (testing).
    """
    top_c, ground_c = params.cutoffs_for(length)
    top_c = top_c if top_cutoff is None else top_cutoff
    ground_c = ground_c if ground_cutoff is None else ground_cutoff
    rel = pt.s - pt.s0
    rel /= length
    bidx = rel.astype(np.int64)     # rel >= 0: truncation is floor
    block, starts, counts = segment_starts(bidx)
    mask = pt.conf_mask
    if params.noise == "sigma":
        # rel is scratch from here on
        keep: np.ndarray | None = sigma_filter(pt.z, starts, counts, mask, params.k_sigma,
                                               work=rel)
    else:
        keep = mask
    del rel
    if keep is not None and bool(keep.all()):
        keep = None
    # bidx is dead after segment_starts: its memory holds the histogram keys
    hist = BlockHistograms.build(pt.z, starts, counts, keep, params.bin_size,
                                 params.window_bins, dense=dense, key_buffer=bidx)
    del bidx
    nblk = block.size
    n_kept = np.zeros(nblk, np.int64)
    n_kept[hist.index] = hist.nk
    t = hist.top_bin(top_c)
    g = hist.ground_bin(ground_c)
    top_k = hist.top_height(t)
    ground_k = hist.ground_height(g)
    below_k, nbw_k = hist.count_between(top_k, ground_k)
    z90_k = hist.z90(below_k, nbw_k)
    top = np.full(nblk, np.nan)
    ground = np.full(nblk, np.nan)
    z90 = np.full(nblk, np.nan)
    n_between = np.zeros(nblk, np.int64)
    top[hist.index] = top_k
    ground[hist.index] = ground_k
    z90[hist.index] = z90_k
    n_between[hist.index] = nbw_k
    sparse = n_kept < params.min_photons
    inverted = ~sparse & ((top <= ground) | (n_between == 0))
    flag = np.where(sparse, 1, np.where(inverted, 2, 0)).astype(np.int8)
    top[sparse] = np.nan
    ground[sparse] = np.nan
    z90[sparse] = np.nan
    n_between[sparse] = 0
    x = np.add.reduceat(pt.x, starts) / counts if nblk else np.empty(0)
    y = np.add.reduceat(pt.y, starts) / counts if nblk else np.empty(0)
    lab = None
    if labels:
        lab = _labels(pt.z.size, keep, starts, counts, hist, g, t, sparse)
    res = LengthResult(length, block, counts, n_kept, n_between, top, ground, z90, flag,
                       x, y, lab)
    return res, hist


def _labels(n: int, keep: np.ndarray | None, starts: np.ndarray, counts: np.ndarray,
            hist: BlockHistograms, g: np.ndarray, t: np.ndarray,
            sparse: np.ndarray) -> np.ndarray:
    """Per-photon labels of the prepared photons (see :func:`compute_blocks`)."""
    jk = hist.bins()
    gk = np.repeat(g, hist.nk)
    tk = np.repeat(t, hist.nk)
    lk = np.full(jk.size, LABEL_BETWEEN, np.int8)
    lk[jk >= tk] = LABEL_CANOPY
    lk[jk <= gk] = LABEL_GROUND            # ground wins where the windows overlap
    lk[np.repeat(sparse[hist.index], hist.nk)] = LABEL_BETWEEN
    if keep is None:
        return lk
    out = np.full(n, LABEL_NOISE, np.int8)
    out[keep] = lk
    return out


@overload
def compute_blocks(track: PhotonTrack, params: BlockParams = ..., *,
                   labels: Literal[False] = ..., progress: Progress | None = ...,
                   window_photons: int | None = ...) -> gpd.GeoDataFrame: ...


@overload
def compute_blocks(track: PhotonTrack, params: BlockParams = ..., *,
                   labels: Literal[True], progress: Progress | None = ...,
                   window_photons: int | None = ...
                   ) -> tuple[gpd.GeoDataFrame, dict[float, np.ndarray]]: ...


def compute_blocks(track: PhotonTrack, params: BlockParams | None = None, *,
                   labels: bool = False, progress: Progress | None = None,
                   window_photons: int | None = DEFAULT_WINDOW_PHOTONS
                   ) -> gpd.GeoDataFrame | tuple[gpd.GeoDataFrame, dict[float, np.ndarray]]:
    """Canopy top, mean ground, Hmax and H90 per along-track block (DESIGN.md 1).

    For each block length ``L`` in ``params.lengths``, block ``i`` holds the photons
    with ``i*L <= s - s0 < (i+1)*L``, evaluated as ``floor((s - s0) / L) == i`` in
    float64.  Photons with ``s < s0`` (and photons with a NaN/inf height or
    position, with a warning) lie in no block.  Per block:

    1. optional ATL03 confidence filter (``params.min_signal_conf``), then the
       noise filter ``|z - mean| <= k_sigma * std`` (``std`` ddof=1; std 0 or one
       photon keeps all);
    2. a histogram of the kept photons in ``bin_size`` bins from the lowest one,
       ``nb = max(1, ceil((zmax - zmin)/bin_size))`` bins, photon bin
       ``min(floor((z - zmin)/bin_size), nb - 1)``;
    3. top window: the highest ``window`` (4 bins; the whole histogram if shorter),
       extended downward one bin while it holds less than the top cut-off fraction
       of the kept photons; ``top`` = lower edge of the bin where it stops;
       ground window: the same upward from the lowest bin with the ground cut-off;
       ``ground`` = upper edge of its stopping bin;
    4. ``hmax = top - ground``; ``z90 = sorted(z_between)[floor(0.9 (n - 1))]`` over the
       kept photons with ``ground <= z <= top``; ``h90 = z90 - ground``.

    Flags: ``sparse`` when fewer than ``params.min_photons`` photons are kept: top,
    ground, hmax, z90, h90 are NaN and ``n_between`` 0 (one
    :class:`~canopyblocks.errors.SparseBlockWarning` per call lists how many);
    ``inverted`` when ``top <= ground`` or no kept photon lies between them: the
    values are still reported (``hmax`` may be <= 0, ``z90``/``h90`` are NaN when
    nothing lies between) so the profile can show them, but they are not a canopy
    measurement and validation should use ``flag == "ok"`` rows only; ``ok`` otherwise.

    Parameters
    ----------
    track : PhotonTrack
        Photons in a metric CRS (``track.crs``, metres); heights in metres in
        ``track.vertical_datum``.  Should be sorted by ``s`` (it is re-sorted if not).
    params : BlockParams, optional
        Engine parameters; default ``BlockParams()`` (25 m blocks, paper settings).
    labels : bool
        Also return per-photon labels.
    progress : Progress, optional
        Updated once per block length; cancellation raises
        :class:`~canopyblocks.errors.CancelledError`.
    window_photons : int or None
        The engine runs over windows of about this many photons that no block of any
        length straddles (:mod:`.windows`): the same results in a fixed amount of scratch
        memory.  None or 0: the whole track at once.

    Returns
    -------
    blocks : geopandas.GeoDataFrame
        Columns ``canopyblocks.schema.BLOCK_COLUMNS`` in that order plus a point
        ``geometry`` at the block centre = the mean x/y of all the block's photons
        (``x``/``y``; ``lon``/``lat`` are that point in WGS84 degrees); CRS =
        ``track.crs``.  One row per (length, block) for blocks holding at least one
        photon, sorted by length then block.  ``s_start = s0 + block*L``,
        ``s_end = s_start + L`` (metres).
    labels : dict[float, ndarray of int8]
        Only with ``labels=True``: for each length, one label per photon of
        ``track`` in the track's order: ``schema.LABEL_NOISE`` (removed by the
        confidence or noise filter), ``LABEL_GROUND`` (kept, in the final ground
        window; also where the two windows overlap), ``LABEL_CANOPY`` (kept, in the
        final top window), ``LABEL_BETWEEN`` (kept, in neither window; every kept
        photon of a sparse block), ``LABEL_OUTSIDE`` = -1 (in no block).

    Raises
    ------
    InputError
        Non-metric CRS, unequal columns, or ``min_signal_conf`` without signal_conf.
    NoUsableDataError
        No photon with finite values at or after ``s0``.
    """

    params = BlockParams() if params is None else params
    if not isinstance(params, BlockParams):
        raise InputError(f"params must be a BlockParams; got {type(params).__name__}")
    if not isinstance(track, PhotonTrack):
        raise InputError(
            f"compute_blocks needs a PhotonTrack (from read_atl03, read_mabel, read_table or "
            f"open_track); got {type(track).__name__}"
            + (" (a path: read it with canopyblocks.open_track first)"
               if isinstance(track, (str, os.PathLike)) else ""))
    prog = as_progress(progress)
    prog.update(0.0, f"blocks of track {track.track}")
    pt = prepare_track(track, params)
    lengths = sorted(params.lengths)
    frames: list[dict[str, np.ndarray]] = []
    label_out: dict[float, np.ndarray] = {}
    sparse_counts: dict[float, int] = {}
    if window_photons is not None and window_photons < 0:
        raise InputError(f"window_photons must be >= 0 or None, got {window_photons}")
    cuts = (window_cuts(pt.s, pt.s0, lengths, window_photons) if window_photons
            else np.array([0, pt.s.size]))
    for i, length in enumerate(lengths):
        res = concat_length_results([
            blocks_for_length(window_of(pt, int(a), int(b)), params, length, labels=labels)[0]
            for a, b in zip(cuts[:-1], cuts[1:])])
        n_sparse = int(np.count_nonzero(res.flag == 1))
        if n_sparse:
            sparse_counts[length] = n_sparse
        frames.append(_columns(track.track, pt.s0, res))
        if labels:
            assert res.labels is not None
            label_out[length] = _labels_in_track_order(pt, res.labels)
        prog.update((i + 1) / len(lengths), f"{length:g} m blocks: {res.block.size} blocks")
    gdf = _table(track, frames)
    if sparse_counts:
        detail = ", ".join(f"{n} of {int((gdf['length'] == L).sum())} {L:g} m blocks"
                           for L, n in sparse_counts.items())
        warnings.warn(
            f"track {track.track}: {detail} hold fewer than min_photons="
            f"{params.min_photons} kept photons; they are flagged 'sparse' with NaN metrics",
            SparseBlockWarning, stacklevel=2,
        )
    flag_implausible_blocks(gdf, track.track, None if params.min_signal_conf is not None
                            else background_fraction(track.signal_conf))
    mark_use(gdf)  # the paper's blocks carry no sigma model: use = flag ok
    log.info("track %s: %d blocks for lengths %s", track.track, len(gdf), lengths)
    if labels:
        return gdf, label_out
    return gdf


def _table(track: PhotonTrack, frames: list[dict[str, np.ndarray]]) -> gpd.GeoDataFrame:
    """The block table of the lengths' columns (:func:`_columns`), centres in WGS84 too."""
    import geopandas as gpd

    cols = {c: np.concatenate([f[c] for f in frames]) for c in BLOCK_COLUMNS if c != "lon"
            and c != "lat"}
    cols["lon"], cols["lat"] = _lonlat(cols["x"], cols["y"], track)
    df = pd.DataFrame({c: cols[c] for c in BLOCK_COLUMNS})
    return gpd.GeoDataFrame(df, geometry=gpd.points_from_xy(df["x"], df["y"]), crs=track.crs)


def block_skeleton(track: PhotonTrack, params: BlockParams, progress: Progress | None = None
                   ) -> gpd.GeoDataFrame:
    """The rows :func:`compute_blocks` gives with ``noise="none"`` and no confidence
    filter (same blocks, bounds, centres, ``n_photons``), without their heights: one pass
    per length over the photons in along-track order (no histograms). ``n_kept``,
    ``n_between`` are 0, the heights NaN, ``flag`` ``ok``: for the caller to fill."""
    prog = as_progress(progress)
    prog.update(0.0, f"blocks of track {track.track}")
    pt = prepare_track(track, replace(params, noise="none", min_signal_conf=None))
    frames = []
    lengths = sorted(params.lengths)
    for i, length in enumerate(lengths):
        block, starts, counts = segment_starts(_block_index(pt.s, pt.s0, length))
        nblk = block.size
        x = np.add.reduceat(pt.x, starts) / counts if nblk else np.empty(0)
        y = np.add.reduceat(pt.y, starts) / counts if nblk else np.empty(0)
        zero, nan = np.zeros(nblk, np.int64), np.full(nblk, np.nan)
        res = LengthResult(length, block, counts, zero, zero, nan, nan, nan,
                           np.zeros(nblk, np.int8), x, y, None)
        frames.append(_columns(track.track, pt.s0, res))
        prog.update((i + 1) / len(lengths), f"{length:g} m blocks: {nblk} blocks")
    return _table(track, frames)


def _columns(track_id: str, s0: float, res: LengthResult) -> dict[str, np.ndarray]:
    n = res.block.size
    s_start = s0 + res.block * res.length
    return {
        "track": np.full(n, track_id, dtype=object),
        "length": np.full(n, res.length),
        "block": res.block.astype(np.int64),
        "s_start": s_start,
        "s_end": s_start + res.length,
        "x": res.x,
        "y": res.y,
        "n_photons": res.n_photons.astype(np.int64),
        "n_kept": res.n_kept,
        "n_between": res.n_between,
        "top": res.top,
        "ground": res.ground,
        "hmax": res.top - res.ground,
        "z90": res.z90,
        "h90": res.z90 - res.ground,
        "flag": _FLAG_CODES[res.flag],
        "hmax_sigma": np.full(n, np.nan),
        "ground_sigma": np.full(n, np.nan),
        "use": res.flag == 0,
    }


def _lonlat(x: np.ndarray, y: np.ndarray, track: PhotonTrack) -> tuple[np.ndarray, np.ndarray]:
    """Block centres in WGS84 degrees (pyproj treats 1-element arrays as scalars: pad)."""
    if x.size == 1:
        lon, lat = from_metric(np.repeat(x, 2), np.repeat(y, 2), track.crs)
        return lon[:1], lat[:1]
    return from_metric(x, y, track.crs)


def _labels_in_track_order(pt: PreparedTrack, lab: np.ndarray) -> np.ndarray:
    out = np.full(pt.n_track, LABEL_OUTSIDE, np.int8)
    if pt.index is None:
        out[pt.first:] = lab
    else:
        out[pt.index] = lab
    return out
