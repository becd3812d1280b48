"""Block metrics from ATL08-style classes (the ``atl08`` preset, DESIGN 1.11).

Per block of the engine's table (same blocks, rows, centres and photon counts as the
paper's engine on all photons):

- ``ground``: the mean of the classifier's ground surface over the block (m);
- ``hmax``: the 98th percentile of the canopy photons' heights above the surface (classes
  2 and 3; ATL08's ``h_canopy`` definition), 0 when the block holds signal but no canopy
  photon (bare ground); ``top = ground + hmax``;
- ``h90``: the 90th percentile of the same heights; ``z90 = ground + h90``;
- ``n_kept``: signal photons (classes 1-3), ``n_between``: canopy photons (classes 2-3);
- ``flag``: ``sparse`` when fewer than ``min_photons`` signal photons (metrics NaN), else ``ok``.

Labels (per length, as the engine's): noise, ground, between (canopy, class 2), canopy
(top of canopy, class 3); photons in no block are -1.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..schema import LABEL_BETWEEN, LABEL_CANOPY, LABEL_GROUND, LABEL_NOISE
from .atl08_classify import CLASS_CANOPY, CLASS_NOISE, CLASS_TOP, Atl08Classes
from .ground_surface import block_mean_ground
from .grouped import percentiles_by_group
from .kernels import enabled
from .params import BlockParams

if TYPE_CHECKING:
    import geopandas as gpd

    from ..photons import PhotonTrack
    from ..progress import Progress

__all__ = ["atl08_block_table", "refuse_signal_conf", "HMAX_PERCENTILE"]

HMAX_PERCENTILE = 98.0
"""Percentile of the canopy heights giving a block's Hmax (ATL08's ``h_canopy``)."""

_FILLED = ("n_kept", "n_between", "ground", "top", "hmax", "z90", "h90", "flag")
_LABEL_OF_CLASS = np.array([-1, LABEL_NOISE, LABEL_GROUND, LABEL_BETWEEN, LABEL_CANOPY],
                           np.int8)  # index: class + 1


def refuse_signal_conf(track: PhotonTrack, params: BlockParams) -> None:
    """Refuse ``params.min_signal_conf`` with the ATL08-style classifier (never ignore it).

    ATL08 classifies *all* ATL03 photons: its noise threshold is set from the background
    rate (``bckgrd_atlas``) and the background photons themselves, which a signal
    confidence filter removes (PhoREAL, likewise, attaches the ATL08 classes to every
    ATL03 photon and filters on confidence only afterwards, for display).  Filtering
    before the classifier would leave it a window cut to the surface: its background
    check gives no verdict and the threshold expects photons that are gone.

    Raises
    ------
    InputError
        ``min_signal_conf`` set: on a track without ``signal_conf`` the message names the
        missing column (as the paper's engine does); otherwise it names the presets that
        use the filter.
    """
    level = params.min_signal_conf
    if level is None:
        return
    where = f"track {track.track} ({track.source or 'in memory'})"
    if track.signal_conf is None:
        raise InputError(
            f"{where}: min_signal_conf={level} needs the ATL03 signal_conf_ph of each "
            "photon, but this track has none; drop --min-signal-conf")
    raise InputError(
        f"{where}: --min-signal-conf {level} is not used by the atl08 estimators (their "
        "classifier, like ATL08's, finds the signal among all photons, background "
        "included); drop it, or use --preset icesat2 (or --noise conf) to filter on "
        "signal confidence")


def atl08_block_table(track: PhotonTrack, params: BlockParams, classes: Atl08Classes, *,
                      labels: bool = False, progress: Progress | None = None
                      ) -> tuple[gpd.GeoDataFrame, dict[float, np.ndarray]]:
    """The block table (DESIGN 5 columns) from the classes; labels per length if asked."""
    from .engine import block_skeleton

    blocks = block_skeleton(track, params, progress)
    cls = classes.classes
    s = np.asarray(track.s, float)
    hrel = classes.height
    can_i = np.flatnonzero((cls == CLASS_CANOPY) | (cls == CLASS_TOP))
    # photons in along-track order fall in the blocks in turn: the compiled percentiles
    # sort each block's canopy heights on its own; else they are sorted by height once,
    # for the percentiles of every length
    in_turn = enabled() and s.size > 1 and bool(np.all(s[1:] >= s[:-1]))
    if not in_turn:
        can_i = can_i[np.argsort(hrel[can_i])]
    can_h = hrel[can_i]
    out_labels: dict[float, np.ndarray] = {}
    # the columns filled in as whole arrays (one assignment each, not one per length)
    new = {k: blocks[k].to_numpy(copy=True) for k in _FILLED}
    for length in sorted(params.lengths):
        rows = np.flatnonzero(blocks["length"].to_numpy() == length)
        sub = blocks.iloc[rows]
        if len(sub) == 0:
            continue
        nums = sub["block"].to_numpy()
        s0 = float(sub["s_start"].iloc[0] - nums[0] * length)
        with np.errstate(invalid="ignore"):
            bidx = np.floor((s - s0) / length)
        row = _row_of_block(nums, bidx, cls >= 0)  # -1: in no row
        inrow = row >= 0
        prow = row[inrow]
        c = cls[inrow]
        n = len(sub)
        n_kept = np.bincount(prow[c > CLASS_NOISE], minlength=n)
        crow = row[can_i]
        cin = crow >= 0
        n_can = np.bincount(crow[cin], minlength=n)
        rh = percentiles_by_group(crow[cin], can_h[cin], (HMAX_PERCENTILE, 90.0), n,
                                  values_sorted=not in_turn)
        ground = block_mean_ground(classes.surface, sub["s_start"].to_numpy(float),
                                   sub["s_end"].to_numpy(float))
        hmax = np.where(n_can > 0, rh[:, 0], 0.0)
        h90 = np.where(n_can > 0, rh[:, 1], 0.0)
        sparse = n_kept < params.min_photons
        new["n_kept"][rows] = n_kept
        new["n_between"][rows] = np.where(sparse, 0, n_can)
        new["ground"][rows] = np.where(sparse, np.nan, ground)
        new["top"][rows] = np.where(sparse, np.nan, ground + hmax)
        new["hmax"][rows] = np.where(sparse, np.nan, hmax)
        new["z90"][rows] = np.where(sparse, np.nan, ground + h90)
        new["h90"][rows] = np.where(sparse, np.nan, h90)
        new["flag"][rows] = np.where(sparse, "sparse", "ok")
        if labels:
            lab = _LABEL_OF_CLASS[cls.astype(np.int64) + 1]
            lab[~inrow] = -1
            out_labels[length] = lab
    for k, v in new.items():
        blocks[k] = v
    return blocks, out_labels


def _row_of_block(nums: np.ndarray, bidx: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Per photon, the index in ``nums`` (sorted block numbers) of its block number
    ``bidx`` (float; NaN for none), or -1 when it is not there or ``ok`` is false."""
    row = np.full(bidx.size, -1, np.int64)
    lo, hi = int(nums[0]), int(nums[-1])
    if hi - lo > 4 * bidx.size + 1_000_000:  # a sparse far-flung set of blocks: search
        pos = np.searchsorted(nums, bidx)
        hit = ok & (pos < len(nums)) & (nums[np.minimum(pos, len(nums) - 1)] == bidx)
        row[hit] = pos[hit]
        return row
    with np.errstate(invalid="ignore"):
        at = np.flatnonzero(ok & (bidx >= lo) & (bidx <= hi))
    lut = np.full(hi - lo + 1, -1, np.int64)  # block number - lo -> row
    lut[nums - lo] = np.arange(len(nums))
    row[at] = lut[(bidx[at] - lo).astype(np.int64)]
    return row
