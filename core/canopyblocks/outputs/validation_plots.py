"""Validation figures: photon vs reference scatter per block length, errors by aspect.

* :func:`plot_validation_scatter`: one panel per metric (ground, top, Hmax, H90) with
  the 1:1 line, the OLS fit of photon on reference and n / r^2 / RMSE / bias (as in
  seed 001 figure 5); blocks with ``use`` only.
* :func:`plot_aspect_errors`: polar bars of RMSE (or bias) per aspect class, one panel
  per metric (seed 001 found the largest errors on easterly aspects).
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
        if sig_col is not None and sig_col in sub.columns:
            sig = sub[sig_col].to_numpy(float)[ok]
            ax.errorbar(x, y, yerr=np.where(np.isfinite(sig), sig, 0.0), fmt="none",
                        ecolor="0.6", elinewidth=0.7, capsize=0, label="1 sigma")
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
                f"n = {st['n']}\nr² = {st['r2']:.2f}\nRMSE = {st['rmse']:.2f} m\n"
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
                       estimator: str | None = None, reference: str | None = None) -> Path:
    """Polar bars of ``value`` (``rmse``, ``bias`` or ``mae``) per aspect class.

    The bar length is the statistic (metres; negative biases are drawn in red by
    their magnitude); the class's n is written at the bar end.
    """
    if value not in ("rmse", "bias", "mae"):
        raise InputError(f"value must be rmse, bias or mae, got {value!r}")
    st = stats[np.isclose(stats["length"].to_numpy(float), float(length))]
    fig, axes = new_figure(figsize=(3.4 * len(metrics), 3.8), ncols=len(metrics), squeeze=False,
                           subplot_kw={"projection": "polar"})
    theta = np.radians(np.arange(8) * 45.0)
    for ax, m in zip(axes[0], metrics):
        sm = st[st["metric"] == m].set_index("group")
        vals = np.array([sm[value].get(f"aspect:{c}", np.nan) for c in _ASPECTS], dtype=float)
        ns = [int(sm["n"].get(f"aspect:{c}", 0)) for c in _ASPECTS]
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)
        # classes with fewer than 3 blocks are greyed (too few to say anything)
        colours = ["0.8" if k < 3 else "tab:red" if v < 0 else "tab:blue"
                   for v, k in zip(np.nan_to_num(vals), ns)]
        ax.bar(theta, np.abs(np.nan_to_num(vals)), width=np.radians(40), color=colours,
               alpha=0.75)
        ax.set_xticks(theta)
        ax.set_xticklabels(_ASPECTS)
        top = np.nanmax(np.abs(vals)) if np.isfinite(vals).any() and np.nanmax(
            np.abs(vals)) > 0 else 1.0
        ax.set_ylim(0, 1.2 * top)
        ax.set_rlabel_position(202.5)
        ax.tick_params(axis="y", labelsize=6)
        for th, v, k in zip(theta, vals, ns):
            if np.isfinite(v):
                ax.text(th, abs(v) + 0.08 * top, f"n={k}", ha="center", fontsize=6)
        ax.set_title(f"{m}: {value} by aspect (m)", fontsize=9, pad=16)
    note = "red: negative bias; " if value == "bias" else ""
    whose = (f"{_who(estimator)} vs the {reference or 'reference'}: "
             if estimator or reference else "")
    fig.suptitle(f"{whose}errors by aspect, {length:g} m blocks ({note}grey: fewer than "
                 "3 blocks)",
                 fontsize=10, y=1.06)  # above the panel titles (saved with a tight box)
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
