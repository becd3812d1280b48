"""The flash-lidar paper's threshold table on simulated cubes (its table II).

For each energy fraction: the flash-lidar chain (:mod:`canopyblocks.waveforms.esfl`) on
the cubes, against the airborne reference of the pixels each waveform merges
(:mod:`canopyblocks.reference.pixel_reference`, computed from the points alone): terrain
r2, RMSE, bias and SD of the difference, the share of outliers (the paper's rule), and
canopy height r2, RMSE and bias over the waveforms that are not outliers.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from ..readers.las import LasPoints
from ..reference.pixel_reference import pixel_reference
from ..waveforms.esfl import EsflCubes, EsflParams, esfl_chain

__all__ = ["PAPER_TABLE", "esfl_compare", "esfl_threshold_table"]

#: The paper's figures beside which the table is printed (5 m resolution).
PAPER_TABLE = {"height_r2": (0.84, 0.85), "height_rmse": (2.3, 3.9),
               "terrain_sd": (0.41, 0.69), "terrain_rmse_f50": 1.8,
               "terrain_rmse_f10": 16.7, "terrain_rmse_f90": 17.7}


def _r2(a: np.ndarray, b: np.ndarray) -> float:
    if a.size < 3 or np.std(a) == 0 or np.std(b) == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1] ** 2)


def esfl_compare(res: pd.DataFrame, ref: pd.DataFrame) -> dict[str, float]:
    """Accuracy of one chain result against its reference (rows aligned).

    Returns ``n``, ``outliers_pct`` and, for ``terrain``, ``height`` (against the
    highest point in the pixels) and ``height_chm`` (against the mean of the 1 m
    maximum-elevation canopy height model over the pixels, the paper's kind of
    reference): ``r2``, ``rmse``, ``bias``, ``sd`` and the robust ``nmad`` (1.4826 x the
    median absolute deviation from the median: the spread without the tails), m,
    estimate minus reference.
    """
    out = res["outlier"].to_numpy(bool)
    t = res["terrain"].to_numpy(float)
    h = res["height"].to_numpy(float)
    rg = ref["ref_ground"].to_numpy(float)
    rh = ref["ref_height"].to_numpy(float)
    rc = ref["ref_height_chm"].to_numpy(float)
    row: dict[str, float] = {"n": int(len(res)), "outliers_pct": 100.0 * float(out.mean())
                             if len(res) else float("nan")}
    for name, est, want in (("terrain", t, rg), ("height", h, rh), ("height_chm", h, rc)):
        ok = ~out & np.isfinite(est) & np.isfinite(want)
        e = est[ok] - want[ok]
        row[f"{name}_n"] = int(ok.sum())
        row[f"{name}_r2"] = _r2(est[ok], want[ok])
        row[f"{name}_rmse"] = float(np.sqrt(np.mean(e * e))) if e.size else float("nan")
        row[f"{name}_bias"] = float(e.mean()) if e.size else float("nan")
        row[f"{name}_sd"] = float(e.std(ddof=1)) if e.size > 1 else float("nan")
        if name == "height":
            row["ref_height_sd"] = float(want[ok].std(ddof=1)) if e.size > 1 else float("nan")
        row[f"{name}_nmad"] = (1.4826 * float(np.median(np.abs(e - np.median(e))))
                               if e.size else float("nan"))
    return row


def esfl_threshold_table(lines: list[EsflCubes], points: LasPoints,
                         fractions: tuple[float, ...] = (0.1, 0.25, 0.5, 0.6, 0.7, 0.8, 0.9),
                         params: EsflParams | None = None) -> pd.DataFrame:
    """One row per energy fraction, pooled over the flight ``lines`` (see the module).

    Parameters
    ----------
    lines : list of EsflCubes
        Flight lines (each its own average cube, as in the paper).
    points : LasPoints
        The airborne points the reference comes from.
    fractions : tuple of float
    params : EsflParams, optional
        Chain parameters; ``fraction`` is replaced by each of ``fractions``.
    """
    base = params or EsflParams()
    rows = []
    for f in fractions:
        p = replace(base, fraction=float(f))
        res_all, ref_all = [], []
        n_pixels = 0
        for cubes in lines:
            wf, res = esfl_chain(cubes, p)
            ref = pixel_reference(points, wf.pixel_x, wf.pixel_y, wf.pixel_group,
                                  len(res), wf.pixel_size, wf.along)
            res_all.append(res)
            ref_all.append(ref)
            n_pixels = int(len(wf.pixel_group) // max(1, np.asarray(cubes.cubes).shape[0]))
        row: dict[str, float] = {"fraction": float(f), "pixels_per_footprint": n_pixels}
        row.update(esfl_compare(pd.concat(res_all, ignore_index=True),
                                pd.concat(ref_all, ignore_index=True)))
        rows.append(row)
    return pd.DataFrame(rows)
