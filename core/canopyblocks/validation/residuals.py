"""Residuals per block: photon metrics minus reference values (DESIGN 2.4, section 5).

All blocks are kept; the column ``use`` marks those that enter the statistics:
block ``flag == "ok"`` (so not ``low_confidence``: its sigma too wide, DESIGN 1.12),
the block's own ``use`` where the table has it, and reference ``ref_flag == "ok"``.
The block's ``hmax_sigma`` and ``ground_sigma`` (m) are carried along.

Every block left out has one reason (column ``reason``, empty for the blocks used), by
the precedence :data:`LEFT_OUT_PRECEDENCE`: the reference first (a block the airborne
points do not cover cannot be judged, whatever its photons gave: ``reference outside``,
``reference nodata``, ...), then the block's own flag (``sparse``, ``inverted``,
``implausible``, ``low_confidence``), then ``not used``; the report's counts and every
layer use the same reasons.
"""

from __future__ import annotations

import logging

import geopandas as gpd
import numpy as np
import pandas as pd

from ..blocks.uncertainty import upgrade_table
from ..errors import InputError
from ..schema import BLOCK_COLUMNS, FLAG_OK, REFERENCE_COLUMNS, RESIDUAL_COLUMNS

__all__ = ["compute_residuals", "RESIDUAL_PAIRS", "KEY_COLUMNS", "LEFT_OUT_PRECEDENCE",
           "block_reasons"]

log = logging.getLogger(__name__)

#: Photon column -> reference column of each validated metric.
RESIDUAL_PAIRS: dict[str, str] = {
    "ground": "ref_ground", "top": "ref_top", "hmax": "ref_hmax", "h90": "ref_h90",
}
KEY_COLUMNS: tuple[str, ...] = ("track", "length", "block")

#: The one reason of a block left out, first match wins: the reference's flag, the
#: block's own flag (in the order of ``schema.FLAGS``), not used (the block table's
#: ``use``), then (per metric, in the facts) no value.
LEFT_OUT_PRECEDENCE: tuple[str, ...] = (
    "reference outside", "reference nodata", "reference no_ground", "reference missing",
    "sparse", "inverted", "implausible", "low_confidence", "not used", "no value")


def block_reasons(flag: np.ndarray, ref_flag: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Per block the reason it is left out by :data:`LEFT_OUT_PRECEDENCE` (``""`` when it
    is used): ``reference <ref_flag>`` when the reference is not ``ok``, else the block's
    flag when not ``ok``, else ``not used`` when ``use`` is false."""
    flag = np.asarray(flag, dtype=object).astype(str)
    rflag = np.asarray(ref_flag, dtype=object).astype(str)
    ref_why = np.char.add("reference ", rflag.astype(str)).astype(object)
    return np.where(rflag != "ok", ref_why,
                    np.where(flag != "ok", flag,
                             np.where(~np.asarray(use, bool), "not used", ""))).astype(object)


def _align(blocks: pd.DataFrame, other: pd.DataFrame, what: str) -> pd.DataFrame:
    """Rows of ``other`` in the order of ``blocks``, matched by (track, length, block)."""
    if all(c in other.columns for c in KEY_COLUMNS):
        right = other.drop_duplicates(list(KEY_COLUMNS)).set_index(list(KEY_COLUMNS))
        idx = pd.MultiIndex.from_frame(blocks[list(KEY_COLUMNS)].reset_index(drop=True))
        return right.reindex(idx).reset_index(drop=True)
    if len(other) != len(blocks) or not other.index.equals(blocks.index):
        raise InputError(
            f"the {what} table has neither track/length/block columns nor the blocks' index; "
            "pass the output of block_reference_values / block_terrain for these blocks"
        )
    return other.reset_index(drop=True)


def _require_numbers(blocks: pd.DataFrame, column: str) -> None:
    """Refuse a block column of metres that holds text (a hand-edited or foreign table)."""
    if column not in blocks.columns or pd.api.types.is_numeric_dtype(blocks[column]):
        return
    vals = pd.to_numeric(blocks[column], errors="coerce")
    bad = vals.isna().to_numpy() & blocks[column].notna().to_numpy()
    if bad.any():
        example = blocks[column].to_numpy(object)[bad][0]
        raise InputError(f"the block table's column {column!r} holds {int(bad.sum())} values "
                         f"that are not numbers (e.g. {str(example)[:30]!r}); it must hold "
                         "metres: write the table again with canopyblocks blocks")


def compute_residuals(blocks: pd.DataFrame, ref_values: pd.DataFrame,
                      terrain: pd.DataFrame | None = None, *,
                      corridors: gpd.GeoDataFrame | None = None) -> gpd.GeoDataFrame:
    """Join blocks with reference values and terrain; residuals photon minus reference.

    Parameters
    ----------
    blocks : GeoDataFrame
        Block table (``schema.BLOCK_COLUMNS``), heights in the reference's datum
        (see :func:`~canopyblocks.reference.datum.apply_vertical_offset`).
    ref_values : DataFrame
        ``ref_ground, ref_top, ref_top90, ref_hmax, ref_h90`` (+ ``coverage``,
        ``ref_flag``), matched to blocks by ``track, length, block``.
    terrain : DataFrame, optional
        ``slope, aspect, aspect_class, slope_class``; NaN/``unknown`` when None.
    corridors : GeoDataFrame, optional
        Geometry for the output (corridor polygons); default the blocks' geometry.

    Returns
    -------
    GeoDataFrame
        Block columns (``schema.BLOCK_COLUMNS``, with ``hmax_sigma``, ``ground_sigma`` and
        ``use``: block and reference usable), ``schema.RESIDUAL_COLUMNS``, ``slope_class``
        and ``ref_flag``, in the blocks' order and index.
    """
    from ..arguments import check_frame
    check_frame(blocks, "compute_residuals: blocks")
    check_frame(ref_values, "compute_residuals: ref_values")
    missing = [c for c in (*KEY_COLUMNS, *RESIDUAL_PAIRS) if c not in blocks.columns]
    if missing:
        raise InputError(f"the block table lacks column(s) {', '.join(missing)}")
    for c in (*RESIDUAL_PAIRS, "hmax_sigma", "ground_sigma"):
        _require_numbers(blocks, c)
    ref = _align(blocks, ref_values, "reference")
    out = pd.DataFrame({c: blocks[c].to_numpy() for c in BLOCK_COLUMNS if c in blocks.columns})
    for c in REFERENCE_COLUMNS:
        out[c] = ref[c].to_numpy(float) if c in ref else np.nan
    for m, r in RESIDUAL_PAIRS.items():
        out[f"res_{m}"] = blocks[m].to_numpy(float) - out[r].to_numpy(float)
    if terrain is not None:
        ter = _align(blocks, terrain, "terrain")
        out["slope"] = ter["slope"].to_numpy(float)
        out["aspect"] = ter["aspect"].to_numpy(float)
        out["aspect_class"] = ter["aspect_class"].fillna("unknown").to_numpy(object)
        sc = ter["slope_class"] if "slope_class" in ter else pd.Series(["unknown"] * len(ter))
        slope_cls = sc.fillna("unknown").to_numpy(object)
    else:
        out["slope"] = np.nan
        out["aspect"] = np.nan
        out["aspect_class"] = "unknown"
        slope_cls = np.full(len(out), "unknown", dtype=object)
    out["coverage"] = ref["coverage"].to_numpy(float) if "coverage" in ref else np.nan
    out["slope_class"] = slope_cls
    out["ref_flag"] = ref["ref_flag"].fillna("missing").to_numpy(object) if "ref_flag" in ref \
        else "ok"
    if "flag" not in blocks:  # a hand-made table: every block ok
        blocks = blocks.assign(flag=FLAG_OK)
    if not {"use", "hmax_sigma", "ground_sigma"} <= set(blocks.columns):
        blocks = upgrade_table(blocks.copy())  # a table of an older version, in memory
    for c in ("hmax_sigma", "ground_sigma"):
        out[c] = blocks[c].to_numpy(float)
    # headline statistics take the blocks the block table uses (decided once, by
    # blocks.uncertainty.mark_use) where the reference is usable
    out["use"] = blocks["use"].to_numpy(bool) & (out["ref_flag"].to_numpy(object) == "ok")
    out["reason"] = block_reasons(blocks["flag"].to_numpy(object),
                                  out["ref_flag"].to_numpy(object),
                                  blocks["use"].to_numpy(bool))
    order = [c for c in BLOCK_COLUMNS if c in out] + list(RESIDUAL_COLUMNS) + \
        ["slope_class", "ref_flag", "reason"]
    out = out[order]
    out.index = blocks.index
    geom = corridors.geometry.to_numpy() if corridors is not None else \
        getattr(blocks, "geometry", None)
    crs = corridors.crs if corridors is not None else getattr(blocks, "crs", None)
    if geom is None:
        return gpd.GeoDataFrame(out)
    return gpd.GeoDataFrame(out, geometry=np.asarray(geom), crs=crs)
