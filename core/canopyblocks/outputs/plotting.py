"""Matplotlib set-up shared by every plot writer (headless Agg backend, atomic PNG writes)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..atomic import atomic_output
from ..errors import DependencyError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["new_figure", "save_figure"]


def new_figure(*, figsize: tuple[float, float] = (10.0, 4.0), nrows: int = 1, ncols: int = 1,
               **kwargs: Any) -> tuple[Figure, Any]:
    """A new matplotlib figure and axes on the Agg backend (no display needed)."""
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise DependencyError(
            "plots need matplotlib: pip install 'canopyblocks[plot]'"
        ) from None
    fig = Figure(figsize=figsize, layout="constrained")
    axes = fig.subplots(nrows, ncols, **kwargs)
    return fig, axes


def save_figure(fig: Figure, path: str | os.PathLike[str], *, dpi: int = 150) -> Path:
    """Write ``fig`` as PNG to ``path`` atomically (temporary name, then rename)."""
    p = Path(path)
    with atomic_output(p) as tmp:
        # tight: no axis label, title or outside legend is ever cut at the edge
        fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight", pad_inches=0.1)
    return p
