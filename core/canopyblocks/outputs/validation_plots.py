"""Validation figures: photon vs reference scatter per block length, errors by aspect.

* :func:`plot_validation_scatter`: one panel per metric (ground, top, Hmax, H90) with
  the 1:1 line, the OLS fit of photon on reference and n / r^2 / RMSE / bias (as in
  seed 001 figure 5); blocks with ``use`` only.
* :func:`plot_aspect_errors`: bars of RMSE (or bias) per aspect class (flat included),
  one panel per metric, classes of fewer than 3 blocks named without a bar.
* :func:`write_validation_plots`: both, per block length, into a folder.

All PNGs are written atomically (Agg backend, no display).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from ..schema import METRICS
from ..validation.residuals import RESIDUAL_PAIRS
from ..validation.stats import error_stats
from .plotting import new_figure, save_figure

__all__ = ["plot_validation_scatter", "plot_aspect_errors", "write_validation_plots"]

log = logging.getLogger(__name__)

_TITLES = {"ground": "Ground (m)", "top": "Canopy top (m)", "hmax": "Hmax (m above ground)",
           "h90": "H90 (m above ground)"}


def _axis_title(metric: str, datum: str | None) -> str:
    """Axis label with units; elevations name their vertical datum."""
    if metric in ("ground", "top") and datum:
        return _TITLES[metric].replace("(m)", f"(m, {datum})")
    return _TITLES.get(metric, metric)
_ASPECTS = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")


def _length_rows(df: pd.DataFrame, length: float) -> pd.DataFrame:
    sub = df[np.isclose(df["length"].to_numpy(float), float(length))]
    if "use" in sub.columns:
        sub = sub[sub["use"].to_numpy(bool)]
    return sub


def plot_validation_scatter(residuals: pd.DataFrame, path: str | os.PathLike[str], *,
                            length: float, metrics: Sequence[str] = METRICS,
                            datum: str | None = None, estimator: str | None = None,
                            reference: str | None = None) -> Path:
    """Photon vs reference scatter for one block length, one panel per metric.

    Parameters
    ----------
    residuals : DataFrame
        From :func:`~canopyblocks.validation.residuals.compute_residuals`.
    path : path
        PNG to write (atomically).
    length : float
        Block length, metres.
    datum : str, optional
        Vertical datum of the elevations (ground, top), named on their axes.
    estimator, reference : str, optional
        The estimators (preset name; ``paper``: the paper's method) and the reference
        the figure shows, named in its title and axes.  Blocks with ``hmax_sigma`` /
        ``ground_sigma`` columns get 1-sigma error bars on those panels.
    """
    sub = _length_rows(residuals, length)
    who = _who(estimator)
    fig, axes = new_figure(figsize=(3.6 * len(metrics), 4.4), ncols=len(metrics), squeeze=False)
    for ax, m in zip(axes[0], metrics):
        if m not in RESIDUAL_PAIRS:
            raise InputError(f"unknown metric {m!r}; use {', '.join(RESIDUAL_PAIRS)}")
        x = sub[RESIDUAL_PAIRS[m]].to_numpy(float)
        y = sub[m].to_numpy(float)
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok], y[ok]
        st = error_stats(y, x, allow_empty=True)
        sig_col = {"hmax": "hmax_sigma", "ground": "ground_sigma"}.get(m)
        sig = (sub[sig_col].to_numpy(float)[ok]
               if sig_col is not None and sig_col in sub.columns else np.array([]))
        if np.isfinite(sig).any():  # no bars (nor legend entry) where no sigma exists
            ax.errorbar(x, y, yerr=np.where(np.isfinite(sig), sig, 0.0), fmt="none",
                        ecolor="0.6", elinewidth=0.7, capsize=0,
                        label="predicted 1-sigma error of the block")
        ax.scatter(x, y, s=12, alpha=0.7, color="tab:green", edgecolor="none")
        if x.size:
            lo = float(min(x.min(), y.min()))
            hi = float(max(x.max(), y.max()))
            pad = 0.05 * (hi - lo if hi > lo else 1.0)
            lim = (lo - pad, hi + pad)
            ax.plot(lim, lim, color="0.4", lw=1, ls="--", label="1:1")
            if np.isfinite(st["slope"]):
                ax.plot(lim, [st["intercept"] + st["slope"] * v for v in lim], color="tab:red",
                        lw=1.2, label="OLS")
            ax.set_xlim(lim)
            ax.set_ylim(lim)
            ax.set_aspect("equal")
        ax.set_xlabel(f"reference {_axis_title(m, datum)}", fontsize=8)
        ax.set_ylabel(f"{estimator or 'photon'} {_axis_title(m, datum)}", fontsize=8)
        ax.set_title(m, fontsize=10)
        ax.text(0.03, 0.97,
                f"n = {st['n']}\nR² = {st['r2']:.2f}\nRMSE = {st['rmse']:.2f} m\n"
                f"bias = {st['bias']:+.2f} m",
                transform=ax.transAxes, va="top", ha="left", fontsize=8,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.8"})
    handles, names = axes[0][0].get_legend_handles_labels()
    if handles:  # one legend for all panels, below them (never over the data)
        # anchored just below the figure (the tight save takes it in): every matplotlib
        # from 3.5 ("outside" locations need 3.7, ``ncols`` 3.6)
        fig.legend(handles, names, loc="upper center", bbox_to_anchor=(0.5, 0.0),
                   ncol=len(handles), fontsize=8, frameon=False)
    fig.suptitle(f"{who} vs the {reference or 'reference'}, {length:g} m blocks"
                 if estimator or reference else f"Photon blocks vs reference, {length:g} m blocks")
    return save_figure(fig, path)


def _who(estimator: str | None) -> str:
    if estimator is None:
        return "Photon blocks"
    return "The paper's method" if estimator == "paper" else f"The '{estimator}' estimator"


def plot_aspect_errors(stats: pd.DataFrame, path: str | os.PathLike[str], *, length: float,
                       value: str = "rmse", metrics: Sequence[str] = METRICS,
                       estimator: str | None = None, reference: str | None = None,
                       min_n: int = 3) -> Path:
    """Bars of ``value`` (``rmse``, ``bias`` or ``mae``, metres) per aspect class.

    Every class N..NW and ``flat`` (terrain slope below the flat threshold) with at
    least ``min_n`` blocks gets a bar, its n written on it; classes with fewer blocks
    are named below the axis with their n and drawn without a bar.
    """
    if value not in ("rmse", "bias", "mae"):
        raise InputError(f"value must be rmse, bias or mae, got {value!r}")
    st = stats[np.isclose(stats["length"].to_numpy(float), float(length))]
    classes = (*_ASPECTS, "flat")
    fig, axes = new_figure(figsize=(3.6 * len(metrics), 3.4), ncols=len(metrics),
                           squeeze=False)
    words = {"rmse": "RMSE", "bias": "bias", "mae": "MAE"}[value]
    xs = np.arange(len(classes))
    for ax, m in zip(axes[0], metrics):
        sm = st[st["metric"] == m].set_index("group")
        vals = np.array([sm[value].get(f"aspect:{c}", np.nan) for c in classes], dtype=float)
        ns = np.array([int(sm["n"].get(f"aspect:{c}", 0)) for c in classes])
        shown = (ns >= min_n) & np.isfinite(vals)
        colours = ["tab:red" if v < 0 else "tab:blue" for v in np.nan_to_num(vals)]
        ax.bar(xs[shown], vals[shown], color=[c for c, k in zip(colours, shown) if k],
               alpha=0.8)
        ax.axhline(0.0, color="0.4", lw=0.8)
        ax.set_xticks(xs)
        ax.set_xticklabels([f"{c}\nn={k}" for c, k in zip(classes, ns)], fontsize=6)
        for x, v, sh in zip(xs, vals, shown):
            if sh:
                ax.text(x, v, f"{v:.2f}", ha="center",
                        va="bottom" if v >= 0 else "top", fontsize=6)
        ax.set_ylabel(f"{words} (m)", fontsize=8)
        ax.set_title(f"{m}: {words} by aspect class", fontsize=9)
    whose = (f"{_who(estimator)} vs the {reference or 'reference'}: "
             if estimator or reference else "")
    fig.suptitle(f"{whose}{words} (m) by aspect class, {length:g} m blocks (bars: classes "
                 f"of {min_n} or more blocks; flat = terrain slope below 2 degrees)",
                 fontsize=9)
    return save_figure(fig, path)


def write_validation_plots(residuals: pd.DataFrame, stats: pd.DataFrame,
                           folder: str | os.PathLike[str], *,
                           datum: str | None = None, estimator: str | None = None,
                           reference: str | None = None, prefix: str = "") -> list[Path]:
    """Scatter and aspect figures for every block length into ``folder`` (``datum``:
    the elevations' vertical datum, named on their axes; ``estimator`` and ``reference``
    named in the titles).

    Files: ``<prefix>validation_<L>m.png`` and ``<prefix>aspect_rmse_<L>m.png``.
    """
    out = Path(folder)
    paths = []
    for length in sorted(pd.unique(residuals["length"])):
        tag = f"{float(length):g}m"
        paths.append(plot_validation_scatter(residuals, out / f"{prefix}validation_{tag}.png",
                                             length=float(length), datum=datum,
                                             estimator=estimator, reference=reference))
        paths.append(plot_aspect_errors(stats, out / f"{prefix}aspect_rmse_{tag}.png",
                                        length=float(length), estimator=estimator,
                                        reference=reference))
    log.info("wrote %d validation figures to %s", len(paths), out)
    return paths
