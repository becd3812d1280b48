"""A ``--bbox`` read with the estimators' along-track context around it.

The classifier and the noise filters judge a photon by its neighbours along the track
(density boxes tens of metres long, background rates per 200 m segment, ground surfaces
smoothed over tens of metres).  Photons read only inside a box lose the neighbours beyond
its edges, and photons well inside it changed class.  So a box is read with a margin
(:func:`context_margin`, from the estimators' own parameters), the blocks are computed on
the whole read, and then cut to the box (:func:`cut_to_box`): the blocks overlapping the
box's photons, and the photons inside it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import geopandas as gpd

    from ..blocks.estimators import Estimators
    from ..photons import PhotonTrack

__all__ = ["context_margin", "IN_BOX", "mark_box", "cut_to_box", "box_photons",
           "read_with_context"]

#: The column (of ``PhotonTrack.extra``, removed by :func:`cut_to_box`) marking the
#: photons inside the box of a read with context.
IN_BOX = "_in_box"

#: How many of the widest along-track reach the margin spans: a photon's class depends
#: on its box, whose count depends on its neighbours' classes (one reach each).
REACH_FACTOR = 2.0


def context_margin(estimators: Estimators | None) -> float:
    """Metres of along-track context to read beyond a box: ``REACH_FACTOR`` times the
    widest along-track reach of the estimators' windows (density boxes with their
    background segments, ground-surface kernels at 3 sigma, the classifier's trend and
    top-of-canopy windows).  The paper's per-block method needs none (0)."""
    from ..blocks.estimators import default_estimators

    est = default_estimators() if estimators is None else estimators
    reach = [0.0]
    if est.noise == "atl08":
        a = est.atl08
        boxes = [a.filter, a.canopy_filter, a.sparse_canopy_filter, a.ground_filter]
        reach += [b.segment + b.along for b in boxes if b is not None]
        reach += [a.ground_trend, a.top_window, 3.0 * a.sparse_bandwidth,
                  3.0 * a.refine_bandwidth, a.surface.window, 3.0 * a.surface.bandwidth]
    if est.noise == "density":
        reach.append(est.density.segment + est.density.along)
    if est.ground == "surface":
        reach.append(3.0 * est.surface.bandwidth)
    return REACH_FACTOR * max(reach)


def mark_box(track: PhotonTrack, bbox: tuple[float, float, float, float]) -> PhotonTrack:
    """``track`` with its photons inside ``bbox`` (lon/lat degrees) marked (:data:`IN_BOX`)."""
    from ..readers._common import bbox_mask

    track.extra[IN_BOX] = bbox_mask(track.lon, track.lat, bbox)
    return track


def cut_to_box(track: PhotonTrack, blocks: gpd.GeoDataFrame,
               labels: dict[float, np.ndarray] | None
               ) -> tuple[gpd.GeoDataFrame, dict[float, np.ndarray] | None]:
    """The blocks overlapping the photons of the box of a read with context, and the
    labels of those photons; unchanged for a track read without context."""
    inside = track.extra.get(IN_BOX)
    if inside is None:
        return blocks, labels
    s = np.asarray(track.s, float)[inside]
    keep = np.zeros(len(blocks), bool)
    if s.size:
        lo, hi = float(np.nanmin(s)), float(np.nanmax(s))
        keep = (blocks["s_end"].to_numpy(float) > lo) & \
            (blocks["s_start"].to_numpy(float) <= hi)
    sub = None if labels is None else {k: np.asarray(v)[inside] for k, v in labels.items()}
    return blocks[keep].reset_index(drop=True), sub


def box_photons(track: PhotonTrack) -> PhotonTrack:
    """The photons inside the box of a read with context (the mark removed)."""
    inside = track.extra.pop(IN_BOX, None)
    return track if inside is None else track.subset(inside)


def read_with_context(open_track: Any, path: Any, selection: dict, *,
                      bbox: tuple[float, float, float, float], margin: float,
                      **kw: Any) -> PhotonTrack:
    """One track read inside ``bbox`` and ``margin`` metres along the track beyond it,
    the box's photons marked; the box's own read when the margin is 0."""
    box = open_track(path, bbox=bbox, **kw, **selection)
    if margin <= 0 or len(box) == 0:
        return box
    s = np.asarray(box.s, float)
    lo, hi = float(np.nanmin(s)), float(np.nanmax(s))
    kw = {**kw, "crs": box.crs}
    wide = open_track(path, s_range=(lo - margin, hi + margin), **kw, **selection)
    return mark_box(wide, bbox)
