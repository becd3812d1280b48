"""The co-registration cost surface: along-track x cross-track, the minimum marked."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .plotting import new_figure, save_figure

if TYPE_CHECKING:
    from ..validation.coregistration import CoregResult

__all__ = ["write_cost_surfaces"]


def write_cost_surfaces(result: CoregResult, path: str | os.PathLike[str]) -> Path:
    """One panel per track (and ``all``): the coarse cost surface with the optimum.

    An undetermined offset is titled as such (its minimum is not an offset).

    The cost is the truncated-quadratic misfit of the residuals (dimensionless; see
    :mod:`canopyblocks.validation.coregistration`), normalised by its minimum.
    """
    names = list(result.offsets)
    ncols = min(len(names), 4)
    nrows = int(np.ceil(len(names) / ncols))
    fig, axes = new_figure(figsize=(3.6 * ncols, 3.4 * nrows), nrows=nrows, ncols=ncols,
                           squeeze=False)
    for ax in axes.ravel()[len(names):]:
        ax.set_visible(False)
    for ax, name in zip(axes.ravel(), names):
        off = result.offsets[name]
        if off.cost.size == 0:  # a track the rasters do not cover: nothing was searched
            ax.set_axis_off()
            ax.set_title(f"{name}: undetermined (not searched)", fontsize=8)
            ax.text(0.5, 0.5, "the rasters cover too little\nof this track", ha="center",
                    va="center", fontsize=8, transform=ax.transAxes)
            continue
        cost = off.cost / np.nanmin(off.cost)
        a, c = off.along_grid, off.cross_grid
        step = (a[1] - a[0]) if len(a) > 1 else 1.0
        im = ax.imshow(cost.T, origin="lower", cmap="viridis_r",
                       extent=(a[0] - step / 2, a[-1] + step / 2, c[0] - step / 2,
                               c[-1] + step / 2))
        ax.plot([off.along_track], [off.cross_track], marker="+", ms=14, mew=2,
                color="red" if off.determined else "grey")
        if off.determined:
            ax.set_title(f"{name}: {off.along_track:+.2f} / {off.cross_track:+.2f} m\n"
                         f"(+-{off.along_track_sd:.2f} / {off.cross_track_sd:.2f}), "
                         f"dz {off.vertical:+.2f}", fontsize=8)
        else:  # the minimum is drawn (grey), but it is no offset
            ax.set_title(f"{name}: undetermined\n(minimum {off.along_track:+.2f}/"
                         f"{off.cross_track:+.2f} m, not significant)", fontsize=8)
        ax.set_xlabel("along-track shift (m)")
        ax.set_ylabel("cross-track shift (m)")
        fig.colorbar(im, ax=ax, shrink=0.8, label="cost / min")
    return save_figure(fig, path)
