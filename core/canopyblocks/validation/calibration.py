"""Cut-off calibration against a reference (DESIGN.md 1.7 and 2.2), with a held-out check.

The block engine's :func:`~canopyblocks.blocks.calibrate_cutoffs` finds the top/ground
fractions that best reproduce given reference tops and grounds.  Here the reference
comes from the validation step (corridor values from the airborne rasters), and the
blocks are split in two by parity: cut-offs fitted on the even blocks are scored on the
odd blocks and the other way round, so the reported improvement is out of sample.  The
cut-offs returned for use are fitted on all blocks.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..blocks import BlockParams, CalibrationResult, calibrate_cutoffs, compute_blocks
from ..errors import InputError, SparseBlockWarning
from ..photons import PhotonTrack
from ..progress import Progress, as_progress
from ..schema import FLAG_OK

__all__ = ["CutoffCalibration", "calibrate_against_reference",
           "HOLDOUT_COLUMNS"]

log = logging.getLogger(__name__)

#: Columns of :attr:`CutoffCalibration.table`.
HOLDOUT_COLUMNS: tuple[str, ...] = (
    "length", "top_cutoff", "ground_cutoff", "default_top_cutoff", "default_ground_cutoff",
    "n_holdout", "rmse_top_default", "rmse_top_calibrated", "rmse_ground_default",
    "rmse_ground_calibrated", "rmse_hmax_default", "rmse_hmax_calibrated",
)


@dataclass(frozen=True)
class CutoffCalibration:
    """Result of :func:`calibrate_against_reference`.

    Attributes
    ----------
    params : BlockParams
        The input parameters with the calibrated cut-offs for every length.
    fits : dict[float, CalibrationResult]
        The fit on all reference blocks, per length.
    table : pandas.DataFrame
        One row per length (:data:`HOLDOUT_COLUMNS`): the cut-offs, and the held-out
        RMSE (metres) of top, ground and Hmax with the paper's and the calibrated
        cut-offs, each scored only on blocks the fit did not see.
    """

    params: BlockParams
    fits: dict[float, CalibrationResult]
    table: pd.DataFrame


def _rmse(a: pd.Series) -> float:
    v = a.dropna().to_numpy(dtype=np.float64)
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def _holdout_residuals(track: PhotonTrack, params: BlockParams, length: float,
                       ref: pd.DataFrame) -> pd.DataFrame:
    """Residuals (m) of top, ground and Hmax of the ok blocks listed in ``ref`` under ``params``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SparseBlockWarning)
        b = compute_blocks(track, replace(params, lengths=(length,)))
    j = b[b["flag"] == FLAG_OK].merge(ref, on="block")
    return pd.DataFrame({
        "block": j["block"],
        "top": j["top"] - j["ref_top"],
        "ground": j["ground"] - j["ref_ground"],
        "hmax": j["hmax"] - (j["ref_top"] - j["ref_ground"]),
    })


def _with_cutoffs(params: BlockParams, cut: dict[float, tuple[float, float]]) -> BlockParams:
    lengths = params.lengths
    top = tuple((L, cut[L][0] if L in cut else params.cutoffs_for(L)[0]) for L in lengths)
    ground = tuple((L, cut[L][1] if L in cut else params.cutoffs_for(L)[1]) for L in lengths)
    return replace(params, top_cutoff=top, ground_cutoff=ground)


def calibrate_against_reference(
    track: PhotonTrack,
    residuals: pd.DataFrame,
    params: BlockParams,
    *,
    progress: Progress | None = None,
) -> CutoffCalibration:
    """Calibrate the cut-offs of every block length against validation reference values.

    Parameters
    ----------
    track : PhotonTrack
        The photons the blocks were computed from (metric CRS).
    residuals : pandas.DataFrame
        The ``residuals`` layer of :func:`~canopyblocks.validate_blocks` for blocks of this
        track computed with ``params``: ``track``, ``length``, ``block``, ``ref_top``,
        ``ref_ground`` (metres) and ``ref_flag``; only blocks whose reference is ``ok``
        are used.
    params : BlockParams
        The parameters the blocks were computed with (lengths, s0, noise filter).

    Returns
    -------
    CutoffCalibration

    Raises
    ------
    InputError
        No usable reference block for a length (see ``calibrate_cutoffs``).
    """
    need = {"track", "length", "block", "ref_top", "ref_ground"}
    if not need <= set(residuals.columns):
        raise InputError(f"residual table lacks {sorted(need - set(residuals.columns))}; "
                         "give the 'residuals' layer of the validation")
    prog = as_progress(progress)
    r = residuals[residuals["track"] == track.track]
    if "ref_flag" in r.columns:
        r = r[r["ref_flag"] == "ok"]
    fits: dict[float, CalibrationResult] = {}
    rows = []
    for i, length in enumerate(params.lengths):
        sub = prog.sub(i / len(params.lengths), (i + 1) / len(params.lengths))
        ref = r.loc[np.isclose(r["length"], length), ["block", "ref_top", "ref_ground"]]
        ref = ref.dropna()
        if ref.empty:
            raise InputError(f"no reference block of length {length:g} m for track "
                             f"{track.track}; validate blocks of this length first")
        fits[length] = calibrate_cutoffs(track, ref, length, params=params,
                                         progress=sub.sub(0.0, 0.5))
        held_d: list[pd.DataFrame] = []  # held-out residuals, paper's cut-offs
        held_c: list[pd.DataFrame] = []  # held-out residuals, calibrated cut-offs
        for part in (0, 1):  # fit on one parity, score on the other
            train = ref[ref["block"] % 2 == part]
            test = ref[ref["block"] % 2 != part]
            if train.empty or test.empty:
                continue
            try:
                fit = calibrate_cutoffs(track, train, length, params=params)
            except InputError:
                continue
            cal = _with_cutoffs(params, {length: (fit.top_cutoff, fit.ground_cutoff)})
            held_d.append(_holdout_residuals(track, params, length, test))
            held_c.append(_holdout_residuals(track, cal, length, test))
        sub.update(1.0, f"{length:g} m calibrated")
        empty = pd.DataFrame({k: pd.Series(dtype=float)
                              for k in ("block", "top", "ground", "hmax")})
        rd = pd.concat(held_d, ignore_index=True) if held_d else empty
        rc = pd.concat(held_c, ignore_index=True) if held_c else empty
        # both cut-offs scored on the same held-out blocks (those ok under both), so the
        # two RMSEs and the n beside them are of one set of blocks
        both = np.intersect1d(rd["block"].to_numpy(), rc["block"].to_numpy())
        rd = rd[rd["block"].isin(both)]
        rc = rc[rc["block"].isin(both)]
        td, gd = params.cutoffs_for(length)
        f = fits[length]
        rows.append((length, f.top_cutoff, f.ground_cutoff, td, gd, len(rc),
                     _rmse(rd["top"]), _rmse(rc["top"]), _rmse(rd["ground"]),
                     _rmse(rc["ground"]), _rmse(rd["hmax"]), _rmse(rc["hmax"])))
    table = pd.DataFrame(rows, columns=list(HOLDOUT_COLUMNS))
    calibrated = _with_cutoffs(params, {L: (f.top_cutoff, f.ground_cutoff)
                                        for L, f in fits.items()})
    return CutoffCalibration(calibrated, fits, table)


def __getattr__(name: str) -> object:
    """Names that moved up to a workflow keep working here (see canopyblocks._aliases)."""
    from .._aliases import moved_name

    return moved_name(__name__, name)
