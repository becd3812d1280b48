"""Along-track profile: photons (kept and removed) with canopy top and ground per block.

Like seed 001 figure 4.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from ..photons import PhotonTrack
from ..schema import (
    FLAG_OK,
    LABEL_BETWEEN,
    LABEL_CANOPY,
    LABEL_GROUND,
    LABEL_NOISE,
)
from .plotting import new_figure, save_figure

__all__ = ["plot_profile"]

_LABEL_STYLE = {
    LABEL_NOISE: ("removed (noise)", "#bbbbbb"),
    LABEL_BETWEEN: ("kept", "#4d4d4d"),
    LABEL_GROUND: ("ground window", "#a6611a"),
    LABEL_CANOPY: ("canopy-top window", "#1b7837"),
}


def plot_profile(
    track: PhotonTrack,
    blocks: pd.DataFrame,
    path: str | os.PathLike[str],
    *,
    length: float | None = None,
    labels: Mapping[float, np.ndarray] | None = None,
    max_points: int = 200_000,
    title: str | None = None,
    name: str | None = None,
    overlay: pd.DataFrame | None = None,
    overlay_name: str = "other estimators",
) -> Path:
    """Draw the photon profile (height against along-track distance) with block results.

    Parameters
    ----------
    track : PhotonTrack
        The photons (``s`` and ``h`` in metres).
    blocks : DataFrame
        Block table of :func:`canopyblocks.compute_blocks` for this track.
    path : path-like
        PNG to write (atomically).
    length : float, optional
        Whose photon labels to colour (default: the smallest length in ``blocks``);
        the canopy top and ground of every block length are drawn.
    labels : mapping, optional
        Per-photon labels by block length (``compute_blocks(..., labels=True)``):
        removed photons are drawn grey, window photons coloured.
    max_points : int
        Photons beyond this are thinned by a fixed stride for drawing speed.
    title : str, optional
        Figure title (default: track id and file name).
    name : str, optional
        The estimators of ``blocks`` (a preset name; ``paper``: the paper's method),
        named in the legend.
    overlay : DataFrame, optional
        Blocks of other estimators over the same photons, drawn as thin dashed lines
        (the smallest block length) named ``overlay_name`` in the legend.
    """
    fig, ax = new_figure(figsize=(12.0, 4.5))
    tb = blocks[blocks["track"] == track.track] if "track" in blocks else blocks
    lengths = sorted(tb["length"].unique()) if len(tb) else []
    if length is None and lengths:
        length = float(lengths[0])
    n = len(track)
    step = max(1, int(np.ceil(n / max_points))) if n else 1
    idx = np.arange(0, n, step)
    # ATL03 distances count from the equator crossing (~1e7 m): draw them from the track start
    s_ref = float(np.floor(track.s.min())) if n and track.s.min() > 1e5 else 0.0
    s_plot = track.s - s_ref
    lab = None if labels is None or length is None else labels.get(float(length))
    if lab is None:
        ax.scatter(s_plot[idx], track.h[idx], s=1.5, c="#4d4d4d", lw=0, label="photons",
                   rasterized=True)
    else:
        sub = lab[idx]
        windows = name in (None, "paper")  # the paper's method labels windows of photons
        for value, (what, colour) in _LABEL_STYLE.items():
            if not windows:
                what = what.replace(" window", " photons")
            m = sub == value
            if m.any():
                ax.scatter(s_plot[idx][m], track.h[idx][m], s=1.5, c=colour, lw=0, label=what,
                           rasterized=True)
    # the blocks' own lines are solid (thinner for longer blocks): dashes are the
    # overlay's alone, so a title or caption saying "dashed" names only the overlay
    for i, ln in enumerate(lengths):  # every block length, thinner for longer blocks
        bl = tb[(tb["length"] == ln) & (tb["flag"] == FLAG_OK)]
        if not len(bl):
            continue
        xs = np.column_stack([bl["s_start"] - s_ref, bl["s_end"] - s_ref,
                              np.full(len(bl), np.nan)]).ravel()
        top = np.repeat(bl["top"].to_numpy(), 3)
        gr = np.repeat(bl["ground"].to_numpy(), 3)
        lw = max(0.8, 2.0 - 0.4 * i)
        who = "" if name is None else ("the paper's method, " if name == "paper"
                                       else f"{name}, ")
        ax.plot(xs, top, color="#00a000", lw=lw, ls="-", alpha=max(0.4, 1.0 - 0.2 * i),
                label=f"canopy top ({who}{float(ln):g} m blocks)")
        ax.plot(xs, gr, color="#8c510a", lw=lw, ls="-", alpha=max(0.4, 1.0 - 0.2 * i),
                label=f"ground ({who}{float(ln):g} m blocks)")
    if overlay is not None and len(overlay) and lengths:
        ob = overlay[overlay["track"] == track.track] if "track" in overlay else overlay
        ob = ob[(ob["length"] == lengths[0]) & (ob["flag"] == FLAG_OK)]
        if len(ob):
            xs = np.column_stack([ob["s_start"] - s_ref, ob["s_end"] - s_ref,
                                  np.full(len(ob), np.nan)]).ravel()
            ax.plot(xs, np.repeat(ob["top"].to_numpy(), 3), color="#d62728", lw=0.9,
                    ls="--", label=f"canopy top ({overlay_name}, {float(lengths[0]):g} m)")
            ax.plot(xs, np.repeat(ob["ground"].to_numpy(), 3), color="#9467bd", lw=0.9,
                    ls="--", label=f"ground ({overlay_name}, {float(lengths[0]):g} m)")
    ax.set_xlabel("along-track distance s (m)" if s_ref == 0 else
                  f"along-track distance s - {s_ref:.0f} (m)")
    ax.set_ylabel(f"elevation (m, {track.vertical_datum})")
    ax.set_title(title or f"{track.track} - {Path(track.source).name or 'photons'}")
    if n:
        # frame the signal: with labels, the photons the noise filter kept
        kept = track.h if lab is None or not np.any(lab > LABEL_NOISE) else track.h[lab > LABEL_NOISE]
        lo, hi = np.nanpercentile(kept, [0.5, 99.5])
        pad = max(2.0, 0.1 * (hi - lo))
        ax.set_ylim(lo - pad, hi + pad)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, markerscale=4,
              borderaxespad=0.0)  # outside the data
    return save_figure(fig, path)
