"""Plots of the seed 002 experiment (figure 5 style), matplotlib Agg, written atomically."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..outputs.plotting import new_figure, save_figure
from .analysis import Seed002Result

__all__ = ["plot_cover_residuals"]


def plot_cover_residuals(result: Seed002Result, path: str | os.PathLike[str], *,
                         dpi: int = 120) -> Path:
    """Residuals vs canopy cover and their histograms, per footprint diameter.

    Row 1: mean ground residual (photon - truth, metres) per canopy-cover class with
    standard-deviation error bars (seed 002 figure 5a) and the histogram of ground
    residuals (figure 5b).  Row 2: the same for top-of-canopy residuals.
    """
    fig, axes = new_figure(figsize=(11.0, 7.5), nrows=2, ncols=2)
    cover = result.cover
    for row, kind in enumerate(("ground", "top")):
        ax_c, ax_h = axes[row][0], axes[row][1]
        for j, (d, res) in enumerate(sorted(result.residuals.items())):
            sub = cover[(cover["diameter"] == d) & (cover["kind"] == kind) & (cover["n"] > 0)]
            centre = (sub["cover_lo"].to_numpy() + sub["cover_hi"].to_numpy()) / 2
            ax_c.errorbar(centre + (j - 0.5) * 0.015, sub["mean"], yerr=sub["std"], fmt="o",
                          capsize=3, label=f"{d:g} m footprint")
            r = res[f"{kind}_res"]
            r = r[np.isfinite(r)]
            if r.size:
                lo, hi = np.percentile(r, [0.5, 99.5])
                ax_h.hist(r, bins=np.linspace(lo, hi if hi > lo else lo + 1, 60),
                          histtype="step", label=f"{d:g} m (n={r.size:,})")
        ax_c.axhline(0.0, color="0.5", lw=0.8)
        ax_c.set_xlim(0, 1)
        ax_c.set_xlabel("canopy cover (fraction of the footprint)")
        ax_c.set_ylabel(f"{'terrain' if kind == 'ground' else 'canopy top'} residual (m)")
        ax_c.set_title(f"{kind} residuals (photon - truth) by canopy cover")
        ax_c.legend(fontsize="small")
        ax_h.set_xlabel(f"{kind} residual (m)")
        ax_h.set_ylabel("photons")
        ax_h.set_title(f"histogram of {kind} residuals")
        ax_h.legend(fontsize="small")
    return save_figure(fig, path, dpi=dpi)
