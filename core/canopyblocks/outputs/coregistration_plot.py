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
        cost = off.cost / np.nanmin(off.cost)
        a, c = off.along_grid, off.cross_grid
        step = (a[1] - a[0]) if len(a) > 1 else 1.0
        im = ax.imshow(cost.T, origin="lower", cmap="viridis_r",
                       extent=(a[0] - step / 2, a[-1] + step / 2, c[0] - step / 2,
                               c[-1] + step / 2))
        ax.plot([off.along_track], [off.cross_track], marker="+", color="red", ms=14, mew=2)
        status = "" if off.determined else " (undetermined)"
        ax.set_title(f"{name}: {off.along_track:+.2f} / {off.cross_track:+.2f} m, "
                     f"dz {off.vertical:+.2f}{status}", fontsize=8)
        ax.set_xlabel("along-track shift (m)")
        ax.set_ylabel("cross-track shift (m)")
        fig.colorbar(im, ax=ax, shrink=0.8, label="cost / min")
    return save_figure(fig, path)
