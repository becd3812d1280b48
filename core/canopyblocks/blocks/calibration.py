"""Calibration of the expansion-window cut-offs against reference blocks (DESIGN.md 1.7).

The paper chose its cut-offs by matching clear blocks to airborne-lidar canopy
tops and mean ground.  :func:`calibrate_cutoffs` does the same systematically: a
grid search over (top, ground) fractions that minimises the RMSE of the blocks'
top and ground against reference values, on the blocks flagged ``ok``.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..errors import CanopyBlocksWarning, InputError, NoUsableDataError
from ..progress import Progress, as_progress
from .engine import blocks_for_length, prepare_track
from .params import BlockParams

if TYPE_CHECKING:
    from ..photons import PhotonTrack

__all__ = ["CalibrationResult", "calibrate_cutoffs", "DEFAULT_GRID", "CutoffEdgeWarning"]

log = logging.getLogger(__name__)

#: Default grid of cut-off fractions: 2.5 % to 50 % in 2.5 % steps.
DEFAULT_GRID: tuple[float, ...] = (0.001, 0.005, 0.01, 0.015,
                                    *(round(0.025 * i, 4) for i in range(1, 21)))
"""Candidate cut-offs: down to 0.001 (a window of one photon: the smallest the paper's
expansion allows) and up to 0.5."""


class CutoffEdgeWarning(CanopyBlocksWarning):
    """The best cut-off lies on the edge of the searched grid: the optimum may lie beyond."""


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of :func:`calibrate_cutoffs`.

    Attributes
    ----------
    length : float
        Block length, metres.
    top_cutoff, ground_cutoff : float
        The best fractions.
    rmse, rmse_top, rmse_ground : float
        Errors of the best pair, metres: ``rmse = sqrt((rmse_top^2 + rmse_ground^2)/2)``.
    n_blocks : int
        Blocks the best pair was scored on.
    default_rmse : float
        ``rmse`` of the paper's cut-offs for this length on the same reference (NaN
        when they leave too few ok blocks).
    table : pandas.DataFrame
        One row per grid pair: ``top_cutoff``, ``ground_cutoff``, ``n``, ``rmse_top``,
        ``rmse_ground``, ``rmse`` (NaN where fewer than ``min_blocks`` were ok).
    """

    length: float
    top_cutoff: float
    ground_cutoff: float
    rmse: float
    rmse_top: float
    rmse_ground: float
    n_blocks: int
    default_rmse: float
    table: pd.DataFrame

    def params(self, base: BlockParams | None = None) -> BlockParams:
        """``base`` (default ``BlockParams``) with this length and the calibrated cut-offs."""
        base = BlockParams() if base is None else base
        return replace(base, lengths=(self.length,), top_cutoff=self.top_cutoff,
                       ground_cutoff=self.ground_cutoff)



_LOW_EDGE = {
    "top": " (at the low edge: the paper's method keeps the canopy top at least 1.75 m below "
           "the highest kept photon even with cut-offs at 0, a floor the 'icesat2' preset "
           "avoids)",
    "ground": " (at the low edge: the paper's method keeps the mean ground at least 2 m above "
              "the lowest kept photon even with cut-offs at 0, a floor the 'atl08' estimators' "
              "ground surface avoids)",
}
"""Why an optimum on the low edge of the cut-off grid is a floor of the method, per window."""

def _grid(values: Sequence[float] | None, what: str) -> np.ndarray:
    g = np.asarray(DEFAULT_GRID if values is None else values, dtype=np.float64).ravel()
    if g.size == 0 or not np.all((g > 0) & (g < 1)):
        raise InputError(f"{what} must hold fractions in (0, 1); got {values!r}")
    return np.unique(g)


def calibrate_cutoffs(
    track: PhotonTrack,
    reference: pd.DataFrame,
    length: float,
    *,
    params: BlockParams | None = None,
    grid: Sequence[float] | tuple[Sequence[float], Sequence[float]] | None = None,
    min_blocks: int | None = None,
    progress: Progress | None = None,
) -> CalibrationResult:
    """Find the top/ground cut-offs that best reproduce reference top and ground.

    For every pair of fractions in the grid the blocks of ``length`` are computed
    (the histograms are built once; only the window stops change) and scored on the
    blocks that are ``ok`` for that pair and have finite reference values:
    ``rmse = sqrt((rmse_top^2 + rmse_ground^2) / 2)`` (metres).  The pair with the
    smallest ``rmse`` wins (ties: the first in grid order).  Pairs whose ok blocks
    number fewer than ``min_blocks`` are not eligible, so a pair cannot win by
    flagging the hard blocks away.

    Parameters
    ----------
    track : PhotonTrack
        Photons, metric CRS; heights in the same vertical datum as the reference.
    reference : pandas.DataFrame
        Columns ``block`` (index from ``s0``, as in the block table), ``ref_top``,
        ``ref_ground`` (metres) for blocks of this ``length``; e.g. the output of the
        validation step, or hand-picked clear blocks as in the paper.
    length : float
        Block length, metres.
    params : BlockParams, optional
        Everything else (s0, noise filter, bin size, min_photons).
    grid : sequence of float, or (top_grid, ground_grid), optional
        Candidate fractions in (0, 1); default 0.025..0.5 in steps of 0.025 for both.
    min_blocks : int, optional
        Default: half of the reference blocks that are not sparse (at least 1).
    progress : Progress, optional
        Updated per top fraction.

    Raises
    ------
    InputError
        Missing reference columns, bad grid, or no reference block among the track's
        blocks.
    NoUsableDataError
        No pair leaves ``min_blocks`` ok blocks.
    """
    from ..arguments import check_frame, check_instance, check_number
    from ..photons import PhotonTrack
    check_instance(track, PhotonTrack, "calibrate_cutoffs: track")
    check_frame(reference, "calibrate_cutoffs: reference")
    check_number(length, "calibrate_cutoffs: length", above=0.0, unit=" m")
    base = BlockParams() if params is None else params
    p = replace(base, lengths=(float(length),), top_cutoff=None, ground_cutoff=None)
    missing = {"block", "ref_top", "ref_ground"} - set(reference.columns)
    if missing:
        raise InputError(f"reference table lacks column(s) {sorted(missing)}; it needs block, "
                         "ref_top and ref_ground (metres) per block")
    if grid is not None and len(grid) == 2 and all(np.ndim(g) == 1 for g in grid):
        top_grid = _grid(grid[0], "top grid")  # type: ignore[arg-type]
        ground_grid = _grid(grid[1], "ground grid")  # type: ignore[arg-type]
    else:
        top_grid = ground_grid = _grid(grid, "grid")  # type: ignore[arg-type]
    prog = as_progress(progress)
    pt = prepare_track(track, p)
    res, hist = blocks_for_length(pt, p, p.lengths[0])
    ref = reference.drop_duplicates("block").set_index("block")
    # per represented block (>= 1 kept photon): reference values aligned
    blocks_k = res.block[hist.index]
    rt = ref["ref_top"].reindex(blocks_k).to_numpy(dtype=np.float64)
    rg = ref["ref_ground"].reindex(blocks_k).to_numpy(dtype=np.float64)
    usable = np.isfinite(rt) & np.isfinite(rg) & (hist.nk >= p.min_photons)
    if not usable.any():
        raise InputError(
            f"no reference block matches a non-sparse {length:g} m block of track "
            f"{track.track}: reference blocks {list(ref.index[:10])}..., track blocks "
            f"{int(res.block.min())}..{int(res.block.max())}; check s0 and the block length"
        )
    n_usable = int(usable.sum())
    need = max(1, n_usable // 2) if min_blocks is None else int(min_blocks)
    # window stops per cut-off (vectorised over blocks)
    tops = {c: hist.top_height(hist.top_bin(c)) for c in top_grid}
    grounds = {c: hist.ground_height(hist.ground_bin(c)) for c in ground_grid}
    rows = []
    for i, tc in enumerate(top_grid):
        top = tops[tc]
        et = (top - rt) ** 2
        for gc in ground_grid:
            ground = grounds[gc]
            _, nbw = hist.count_between(top, ground)
            ok = usable & (top > ground) & (nbw > 0)
            n = int(ok.sum())
            if n >= need:
                mt = float(np.sqrt(np.mean(et[ok])))
                mg = float(np.sqrt(np.mean((ground[ok] - rg[ok]) ** 2)))
                rows.append((float(tc), float(gc), n, mt, mg, float(np.hypot(mt, mg) / np.sqrt(2))))
            else:
                rows.append((float(tc), float(gc), n, np.nan, np.nan, np.nan))
        prog.update((i + 1) / top_grid.size, f"calibrating {length:g} m cut-offs")
    table = pd.DataFrame(rows, columns=["top_cutoff", "ground_cutoff", "n", "rmse_top",
                                        "rmse_ground", "rmse"])
    if table["rmse"].notna().sum() == 0:
        raise NoUsableDataError(
            f"no cut-off pair leaves {need} ok blocks of the {n_usable} reference blocks; "
            "give more reference blocks or a lower min_blocks"
        )
    best = table.loc[table["rmse"].idxmin()]
    for what, value, g in (("top", best["top_cutoff"], top_grid),
                           ("ground", best["ground_cutoff"], ground_grid)):
        if g.size > 2 and value in (g[0], g[-1]):
            warnings.warn(
                f"{length:g} m blocks of track {track.track}: the best {what} cut-off "
                f"{value:g} lies on the edge of the searched grid ({g[0]:g}..{g[-1]:g}); "
                "the optimum may lie beyond it" + (_LOW_EDGE[what] if value == g[0] else ""),
                CutoffEdgeWarning, stacklevel=2)
    # the paper's defaults on the same reference
    td, gd = p.cutoffs_for(p.lengths[0])
    top_d, ground_d = hist.top_height(hist.top_bin(td)), hist.ground_height(hist.ground_bin(gd))
    ok_d = usable & (top_d > ground_d) & (hist.count_between(top_d, ground_d)[1] > 0)
    default_rmse = np.nan
    if ok_d.sum() >= need:
        default_rmse = float(np.sqrt((np.mean((top_d[ok_d] - rt[ok_d]) ** 2)
                                      + np.mean((ground_d[ok_d] - rg[ok_d]) ** 2)) / 2))
    log.info("calibrated %g m cut-offs: top %.3f ground %.3f rmse %.2f m (defaults %.2f m)",
             length, best["top_cutoff"], best["ground_cutoff"], best["rmse"], default_rmse)
    return CalibrationResult(
        length=float(length), top_cutoff=float(best["top_cutoff"]),
        ground_cutoff=float(best["ground_cutoff"]), rmse=float(best["rmse"]),
        rmse_top=float(best["rmse_top"]), rmse_ground=float(best["rmse_ground"]),
        n_blocks=int(best["n"]), default_rmse=default_rmse, table=table,
    )
