"""The one table of facts of a run: every count, n, bias and RMSE a report prints.

A run's report (HTML), its terminal summary and ``facts.csv`` are written from this
table, computed once per run from the validation layers, so they cannot disagree:

* one row per estimators x reference x block length x metric, over the group ``all``;
* ``n`` = the blocks (or footprints) in the statistics; ``n_blocks`` = all blocks of
  that length; ``left_out`` names every block left out and why (the block's flag, the
  reference's flag, ``no value``), so ``n + sum(left_out) == n_blocks``;
* ``bias``, ``rmse`` (m; cover as a fraction) with their 95 % intervals, per block
  length: a block bootstrap along the track (:data:`N_RESAMPLES` resamples from a fixed
  random state, so the same data give the same interval) -- contiguous runs of
  :data:`RUN_METRES` of blocks (the blocks used, in along-track order, one track at a
  time), as adjacent blocks share terrain and canopy and are not independent -- up to
  :data:`MAX_BOOTSTRAP` blocks, the analytic interval above (normal for the bias, delta
  method for the RMSE); column ``interval`` names it (``block bootstrap``,
  ``bootstrap`` for a table without tracks, ``analytic``);
* ``r2``: the squared Pearson correlation of block and reference values (R²);
* ``median_sigma``, ``within_1sigma``, ``within_2sigma``: the predicted 1-sigma error
  of the blocks in the statistics and the share of them whose residual lies within one
  and two sigma (the observed coverage; a calibrated Gaussian sigma gives 0.68 / 0.95).

Terrain: :func:`share_terrain` gives every residuals layer of a run the one slope,
aspect and class per block (track, length, block), so a block is in one terrain class
in every layer and section.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from .stats import error_stats

__all__ = ["FACT_COLUMNS", "N_RESAMPLES", "MAX_BOOTSTRAP", "RUN_METRES", "TERRAIN", "KEY",
           "fact_rows", "facts_table", "share_terrain", "interval95", "left_out_reasons",
           "format_left_out", "terrain_of"]

#: Bootstrap resamples of the 95 % intervals.
N_RESAMPLES = 2000
#: Above this many blocks the analytic interval is used (memory bounded).
MAX_BOOTSTRAP = 5000
_STATE = 20260101  # fixed random state of the bootstrap: same data, same interval
#: Along-track length (m) of the runs of adjacent blocks the bootstrap resamples (10 m
#: blocks: runs of 10, 25 m: 4, 50 m: 2); footprints (no track order): single ones.
RUN_METRES = 100.0

#: Columns of ``facts.csv``.
FACT_COLUMNS: tuple[str, ...] = (
    "estimators", "reference", "layer", "length", "metric", "n", "n_blocks", "left_out",
    "bias", "bias_lo", "bias_hi", "rmse", "rmse_lo", "rmse_hi", "r2", "interval",
    "median_sigma", "within_1sigma", "within_2sigma")

#: The terrain columns shared by every layer; the block key.
TERRAIN: tuple[str, ...] = ("slope", "aspect", "aspect_class", "slope_class")
KEY: tuple[str, ...] = ("track", "length", "block")


def _track_spans(track: np.ndarray | None, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per value, the first position and the length of its track's run of values
    (values of a track adjacent; no track: one run of all)."""
    if track is None:
        return np.zeros(n, np.int64), np.full(n, n, np.int64)
    t = np.asarray(track)
    new = np.concatenate([[True], t[1:] != t[:-1]])
    first = np.flatnonzero(new)
    lengths = np.diff(np.concatenate([first, [n]]))
    which = np.cumsum(new) - 1
    return first[which], lengths[which]


def interval95(res: np.ndarray, *, track: np.ndarray | None = None,
               run: int = 1) -> tuple[float, float, float, float, str]:
    """95 % intervals of the mean and the root mean square of residuals ``res`` (m).

    Returns ``(bias_lo, bias_hi, rmse_lo, rmse_hi, method)``: for up to
    :data:`MAX_BOOTSTRAP` values a percentile bootstrap (fixed random state) -- with
    ``run`` > 1 a circular block bootstrap: ``res`` in along-track order, ``track`` the
    track of each value, each resample ``ceil(n / run)`` runs of ``run`` adjacent values
    of one track starting anywhere (wrapping round at the track's end, so every value is
    drawn equally often), cut to ``n`` (``"block bootstrap"``) -- else the analytic one (normal interval of the mean; delta method for
    the RMSE). NaN for fewer than 2 values.
    """
    r = np.asarray(res, dtype=float)
    fin = np.isfinite(r)
    r = r[fin]
    n = r.size
    if n < 2:
        return np.nan, np.nan, np.nan, np.nan, ""
    if n <= MAX_BOOTSTRAP:
        tr = None if track is None else np.asarray(track)[fin]
        run = max(1, int(run))
        t0, tlen = _track_spans(tr, n)
        how = "block bootstrap" if run > 1 else "bootstrap"
        rng = np.random.default_rng(_STATE)
        means = np.empty(N_RESAMPLES)
        rms = np.empty(N_RESAMPLES)
        m = -(-n // run)  # runs per resample
        step = max(1, 400_000 // (m * run))  # resamples per chunk: memory bounded
        for i in range(0, N_RESAMPLES, step):
            k = min(step, N_RESAMPLES - i)
            first = rng.integers(0, n, size=(k, m))
            a, ln = t0[first][:, :, None], tlen[first][:, :, None]
            idx = (a + (first[:, :, None] - a + np.arange(run)) % ln).reshape(k, m * run)[:, :n]
            s = r[idx]
            means[i:i + k] = s.mean(axis=1)
            rms[i:i + k] = np.sqrt((s * s).mean(axis=1))
        b = np.percentile(means, [2.5, 97.5])
        q = np.percentile(rms, [2.5, 97.5])
        return float(b[0]), float(b[1]), float(q[0]), float(q[1]), how
    z = 1.959964
    se_b = float(r.std(ddof=1) / np.sqrt(n))
    mse = float(np.mean(r * r))
    se_mse = float(np.std(r * r, ddof=1) / np.sqrt(n))
    rmse = np.sqrt(mse)
    se_rmse = se_mse / (2 * rmse) if rmse > 0 else 0.0
    m = float(r.mean())
    return m - z * se_b, m + z * se_b, max(0.0, rmse - z * se_rmse), rmse + z * se_rmse, \
        "analytic"


def left_out_reasons(rows: pd.DataFrame, value: str, ref: str) -> tuple[np.ndarray, np.ndarray]:
    """Per row: in the statistics (bool) and, when not, why (str).

    Why, by :data:`~canopyblocks.validation.residuals.LEFT_OUT_PRECEDENCE`: ``reference
    <ref_flag>`` when the reference is not ``ok``; else the block's own flag when not
    ``ok``; else ``not used`` (``use`` false); else ``no value`` (a non-finite value or
    reference).
    """
    from .residuals import block_reasons

    n = len(rows)
    flag = (rows["flag"].astype(str).to_numpy(object) if "flag" in rows
            else np.full(n, "ok", object))
    rflag = (rows["ref_flag"].astype(str).to_numpy(object) if "ref_flag" in rows
             else np.full(n, "ok", object))
    use = (rows["use"].fillna(False).to_numpy(bool) if "use" in rows
           else np.ones(n, bool))
    finite = np.isfinite(pd.to_numeric(rows[value], errors="coerce").to_numpy(float)) & \
        np.isfinite(pd.to_numeric(rows[ref], errors="coerce").to_numpy(float))
    why = block_reasons(flag, rflag, use)
    why = np.where(why == "", "no value", why)
    inside = use & finite
    return inside, np.where(inside, "", why).astype(object)


def format_left_out(counts: Mapping[str, int]) -> str:
    """``{'sparse': 2, 'low_confidence': 1}`` -> ``"low_confidence 1; sparse 2"``."""
    return "; ".join(f"{k} {v}" for k, v in sorted(counts.items()) if v)


def fact_rows(residuals: pd.DataFrame, *, estimators: str, reference: str, layer: str,
              pairs: Mapping[str, str], metrics: Sequence[str],
              length: float | None = None) -> list[dict[str, object]]:
    """The facts of one residuals layer: one row per length and metric.

    ``pairs`` maps each metric to its reference column (``validation.residuals``'s
    ``RESIDUAL_PAIRS``, ``validation.footprints.FOOTPRINT_METRICS``); ``length`` fills
    the length of a table without one (footprints: their diameter, m).
    """
    df = residuals
    lengths = (sorted(float(v) for v in pd.unique(df["length"])) if "length" in df
               else [float(length if length is not None else np.nan)])
    rows: list[dict[str, object]] = []
    for ln in lengths:
        sub = df[df["length"].to_numpy(float) == ln] if "length" in df else df
        for m in metrics:
            if m not in pairs or m not in sub or pairs[m] not in sub:
                continue
            inside, why = left_out_reasons(sub, m, pairs[m])
            use = sub[inside]
            if {"track", "block"} <= set(use.columns):  # along the track, for the runs
                use = use.iloc[np.lexsort((use["block"].to_numpy(),
                                           use["track"].astype(str).to_numpy()))]
            y = use[m].to_numpy(float)
            x = use[pairs[m]].to_numpy(float)
            st = error_stats(y, x, allow_empty=True)
            tracks, run = _along_track(use, ln)
            lo_b, hi_b, lo_r, hi_r, how = interval95(y - x, track=tracks, run=run)
            counts = pd.Series(why[~inside]).value_counts().to_dict()
            row: dict[str, object] = {
                "estimators": estimators, "reference": reference, "layer": layer,
                "length": ln, "metric": m, "n": int(st["n"]), "n_blocks": len(sub),
                "left_out": format_left_out({str(k): int(v) for k, v in counts.items()}),
                "bias": st["bias"], "bias_lo": lo_b, "bias_hi": hi_b, "rmse": st["rmse"],
                "rmse_lo": lo_r, "rmse_hi": hi_r, "r2": st["r2"], "interval": how,
                "median_sigma": np.nan, "within_1sigma": np.nan, "within_2sigma": np.nan}
            sig_col = f"{m}_sigma"
            if sig_col in use:
                s = use[sig_col].to_numpy(float)
                ok = np.isfinite(s)
                if ok.any():
                    r = np.abs(y - x)[ok]
                    row.update(median_sigma=float(np.median(s[ok])),
                               within_1sigma=float(np.mean(r <= s[ok])),
                               within_2sigma=float(np.mean(r <= 2 * s[ok])))
            rows.append(row)
    return rows


def _along_track(rows: pd.DataFrame, length: float) -> tuple[np.ndarray | None, int]:
    """The block bootstrap's arguments for blocks of ``length`` m (``rows`` in
    along-track order): their tracks and the run of :data:`RUN_METRES`; none for a table
    without tracks and block numbers (footprints)."""
    if not ({"track", "block"} <= set(rows.columns)) or not np.isfinite(length) \
            or length <= 0:
        return None, 1
    return rows["track"].astype(str).to_numpy(), max(1, int(round(RUN_METRES / length)))


def facts_table(rows: Sequence[Mapping[str, object]]) -> pd.DataFrame:
    """The rows of :func:`fact_rows` of every layer as one table (``FACT_COLUMNS``)."""
    out = pd.DataFrame(list(rows), columns=list(FACT_COLUMNS))
    out["n"] = out["n"].astype(np.int64)
    out["n_blocks"] = out["n_blocks"].astype(np.int64)
    return out


def share_terrain(residuals: pd.DataFrame, terrain: pd.DataFrame) -> pd.DataFrame:
    """``residuals`` with the slope, aspect and classes of ``terrain`` (matched by track,
    length and block); rows ``terrain`` lacks keep their own."""
    if not len(residuals) or not all(c in residuals for c in KEY):
        return residuals
    t = terrain.drop_duplicates(list(KEY)).set_index(list(KEY))
    key = pd.MultiIndex.from_frame(residuals[list(KEY)].astype(
        {"track": str, "length": float, "block": np.int64}))
    t.index = pd.MultiIndex.from_frame(t.index.to_frame().astype(
        {"track": str, "length": float, "block": np.int64}))
    found = key.isin(t.index)
    out = residuals.copy()
    for c in TERRAIN:
        if c not in t:
            continue
        vals = t[c].reindex(key).to_numpy()
        own = out[c].to_numpy() if c in out else np.full(len(out), np.nan, object)
        out[c] = np.where(found, vals, own)
        if c in ("slope", "aspect"):
            out[c] = out[c].astype(float)
    return out


def terrain_of(residuals: pd.DataFrame) -> pd.DataFrame:
    """The key and terrain columns of a residuals layer (the run's one terrain)."""
    return pd.DataFrame(residuals[[*KEY, *TERRAIN]]).reset_index(drop=True)

