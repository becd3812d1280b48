"""Residuals of classified simulated photons against truth (seed 002 table 3, figure 5).

Residual = photon height - truth of its footprint (metres): ground photons against the
footprint's truth ground, top-of-canopy photons against its truth top.  A positive
ground residual means photons above the true ground; a negative top residual means the
canopy top is underestimated.  (Seed 002 reports the canopy-top bias with the opposite
sign, as an underestimate; its ground bias has this sign.)

Statistics over all realisations: ``bias`` = mean residual, ``std`` = standard
deviation about the bias (the seed's "precision"), ``rms`` = root mean square of the
residuals (``rms^2 = bias^2 + std^2``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import cast

import numpy as np
import pandas as pd

from ..blocks.step_classify import classify_seed002
from ..errors import InputError
from ..progress import Progress, as_progress
from ..readers.las import LasPoints
from .engine import Simulation, cloud_index, simulate_photons
from .params import SimParams
from .tracks import SimTrack

__all__ = [
    "Seed002Result",
    "photon_residuals",
    "residual_stats",
    "cover_table",
    "seed002_experiment",
    "TABLE_COLUMNS",
    "COVER_COLUMNS",
]

log = logging.getLogger(__name__)

TABLE_COLUMNS: tuple[str, ...] = (
    "diameter", "realisations", "n_shots", "n_photons", "mean_cover",
    "n_ground", "ground_bias", "ground_std", "ground_rms",
    "n_top", "top_bias", "top_std", "top_rms",
)
COVER_COLUMNS: tuple[str, ...] = ("diameter", "kind", "cover_lo", "cover_hi", "n", "mean", "std")


def photon_residuals(sim: Simulation, *, step: int = 20) -> dict[str, np.ndarray]:
    """Classify every realisation (seed 002 rule) and return residuals against truth.

    Returns
    -------
    dict of ndarray
        ``ground`` / ``top`` masks over all photons, ``ground_res`` / ``top_res``
        (metres) with the matching ``ground_cover`` / ``top_cover`` (0..1, the truth
        canopy cover of the photon's footprint) and ``ground_shot`` / ``top_shot``.
    """
    ph = sim.photons
    ground, top, _ = classify_seed002(ph["h"], ph["realisation"], psf=sim.params.psf, step=step)
    shot = ph["shot"]
    tg, tt, cov = sim.truth["ground"], sim.truth["top"], sim.truth["cover"]
    return {
        "ground": ground, "top": top,
        "ground_res": ph["h"][ground] - tg[shot[ground]],
        "ground_cover": cov[shot[ground]], "ground_shot": shot[ground],
        "top_res": ph["h"][top] - tt[shot[top]],
        "top_cover": cov[shot[top]], "top_shot": shot[top],
    }


def residual_stats(res: np.ndarray) -> dict[str, float]:
    """``n``, ``bias`` (mean), ``std`` (population) and ``rms`` of residuals (metres)."""
    r = np.asarray(res, dtype=np.float64)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return {"n": 0, "bias": np.nan, "std": np.nan, "rms": np.nan}
    return {"n": int(r.size), "bias": float(r.mean()), "std": float(r.std()),
            "rms": float(np.sqrt(np.mean(r * r)))}


def cover_table(res: dict[str, np.ndarray], *, diameter: float,
                edges: Sequence[float] = tuple(np.linspace(0, 1, 11))) -> pd.DataFrame:
    """Mean and standard deviation of residuals per canopy-cover class (seed 002 fig. 5a).

    Classes are ``[lo, hi)`` of the footprint's truth cover (the last one includes 1).
    """
    e = np.asarray(edges, dtype=np.float64)
    if e.ndim != 1 or e.size < 2 or np.any(np.diff(e) <= 0):
        raise InputError(f"cover class edges must increase; got {edges!r}")
    rows = []
    for kind in ("ground", "top"):
        r, c = res[f"{kind}_res"], res[f"{kind}_cover"]
        ok = np.isfinite(r) & np.isfinite(c)
        r, c = r[ok], c[ok]
        cls = np.clip(np.searchsorted(e, c, side="right") - 1, 0, e.size - 2)
        inside = (c >= e[0]) & (c <= e[-1])
        n = np.bincount(cls[inside], minlength=e.size - 1)
        s1 = np.bincount(cls[inside], weights=r[inside], minlength=e.size - 1)
        s2 = np.bincount(cls[inside], weights=r[inside] ** 2, minlength=e.size - 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(n > 0, s1 / np.maximum(n, 1), np.nan)
            var = np.where(n > 0, s2 / np.maximum(n, 1) - mean ** 2, np.nan)
        std = np.sqrt(np.maximum(var, 0.0))
        for i in range(e.size - 1):
            rows.append({"diameter": diameter, "kind": kind, "cover_lo": e[i],
                         "cover_hi": e[i + 1], "n": int(n[i]), "mean": mean[i],
                         "std": std[i] if n[i] else np.nan})
    return pd.DataFrame(rows, columns=list(COVER_COLUMNS))


@dataclass(eq=False)
class Seed002Result:
    """Seed 002 experiment: table 3 (per diameter) and residuals by canopy cover.

    Attributes
    ----------
    table : DataFrame
        :data:`TABLE_COLUMNS`, one row per footprint diameter.
    cover : DataFrame
        :data:`COVER_COLUMNS`, per diameter, kind (ground/top) and cover class.
    residuals : dict[float, dict[str, ndarray]]
        :func:`photon_residuals` per diameter.
    simulations : dict[float, Simulation]
        The simulations, per diameter.
    """

    table: pd.DataFrame
    cover: pd.DataFrame
    residuals: dict[float, dict[str, np.ndarray]] = field(default_factory=dict)
    simulations: dict[float, Simulation] = field(default_factory=dict)


def summarise(sim: Simulation, *, step: int = 20) -> tuple[dict[str, object],
                                                            dict[str, np.ndarray]]:
    """One row of table 3 for a simulation, and its photon residuals."""
    res = photon_residuals(sim, step=step)
    g, t = residual_stats(res["ground_res"]), residual_stats(res["top_res"])
    cover = sim.truth["cover"]
    # SimParams.__post_init__ fills diameter from the instrument when it is None.
    row: dict[str, object] = {"diameter": float(cast(float, sim.params.diameter)),
           "realisations": sim.n_realisations, "n_shots": sim.n_shots,
           "n_photons": int(sim.photons["h"].size),
           "mean_cover": float(np.nanmean(cover)) if np.isfinite(cover).any() else np.nan,
           "n_ground": g["n"], "ground_bias": g["bias"], "ground_std": g["std"],
           "ground_rms": g["rms"], "n_top": t["n"], "top_bias": t["bias"], "top_std": t["std"],
           "top_rms": t["rms"]}
    return row, res


def seed002_experiment(
    points: LasPoints,
    track: SimTrack,
    params: SimParams | None = None,
    *,
    diameters: Sequence[float] = (13.0, 17.0),
    realisations: int = 100,
    seed: int | None = 0,
    step: int = 20,
    keep_simulations: bool = True,
    progress: Progress | None = None,
) -> Seed002Result:
    """Run the seed 002 experiment: N realisations per footprint diameter.

    Parameters
    ----------
    points : LasPoints
        Airborne cloud (metric CRS).
    track : SimTrack
        Simulated ground track in the cloud's CRS.
    params : SimParams, optional
        Everything but the diameter (which ``diameters`` sets).
    diameters : sequence of float
        Footprint diameters, metres (seed 002: 13 and 17).
    realisations : int
        Photon draws per diameter (seed 002: 100).
    seed : int or None
        Seed; diameter ``i`` uses ``seed + i`` so each run is reproducible alone.
    step : int
        Photons per classification step (20).

    Returns
    -------
    Seed002Result
    """
    from ..arguments import check_instance
    from ..readers.las import LasPoints as _LasPoints
    check_instance(points, _LasPoints, "seed002_experiment: points", "airborne points (read_las)")
    check_instance(track, SimTrack, "seed002_experiment: track", "a SimTrack (line_through)")
    params = params or SimParams()
    if not diameters:
        raise InputError("give at least one footprint diameter")
    prog = as_progress(progress)
    index = cloud_index(points, params)
    rows, covers = [], []
    result = Seed002Result(pd.DataFrame(), pd.DataFrame())
    for i, d in enumerate(diameters):
        p = replace(params, diameter=float(d))
        sim = simulate_photons(points, track, p, realisations=realisations,
                               seed=None if seed is None else seed + i, index=index,
                               progress=prog.sub(i / len(diameters), (i + 0.9) / len(diameters)))
        row, res = summarise(sim, step=step)
        rows.append(row)
        covers.append(cover_table(res, diameter=float(d)))
        result.residuals[float(d)] = res
        if keep_simulations:
            result.simulations[float(d)] = sim
        log.info("diameter %.1f m: ground bias %.3f rms %.3f; top bias %.3f rms %.3f", d,
                 row["ground_bias"], row["ground_rms"], row["top_bias"], row["top_rms"])
        prog.update((i + 1) / len(diameters), f"diameter {d:g} m done")
    result.table = pd.DataFrame(rows, columns=list(TABLE_COLUMNS))
    result.cover = pd.concat(covers, ignore_index=True)
    return result
