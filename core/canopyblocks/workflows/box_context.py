"""A ``--bbox`` read with the estimators' along-track context around it.

The classifier and the noise filters judge a photon by its neighbours along the track
(density boxes tens of metres long, background rates per 200 m segment, ground surfaces
smoothed over tens of metres).  Photons read only inside a box lose the neighbours beyond
its edges, and photons well inside it changed class.  So a box is read with a margin
(:func:`context_margin`, from the estimators' own parameters and the longest block), the
blocks are computed on the whole read, and then cut to the box (:func:`cut_to_box`): the
blocks overlapping the box's photons, each whole (the margin holds all of its photons),
and the photons inside it.

The blocks lie on the grid of the full run: the along-track origin (``s0``) a run of the
whole track takes, its first usable photon, is found from the track's start
(:func:`grid_origin`), never from the first photon of the box.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import geopandas as gpd

    from ..blocks import BlockParams
    from ..blocks.estimators import Estimators
    from ..photons import PhotonTrack

__all__ = ["context_margin", "IN_BOX", "ORIGIN", "mark_box", "cut_to_box", "box_photons",
           "START", "box_params", "box_estimators", "blocks_in_box", "grid_origin",
           "read_with_context"]

#: The column (of ``PhotonTrack.extra``, removed by :func:`cut_to_box`) marking the
#: photons inside the box of a read with context.
IN_BOX = "_in_box"

#: The column (of ``PhotonTrack.extra``, removed by :func:`box_photons`) holding, on every
#: photon, the along-track origin of the full run's block grid (:func:`grid_origin`).
ORIGIN = "_grid_origin"

#: The column (as :data:`ORIGIN`) holding the along-track distance of the track's first
#: photon, where the density filter's background segments of the full run start.
START = "_track_start"

#: How many of the widest along-track reach the margin spans: a photon's class depends
#: on its box, whose count depends on its neighbours' classes (one reach each).
REACH_FACTOR = 2.0


def context_margin(estimators: Estimators | None, lengths: Sequence[float] = ()) -> float:
    """Metres of along-track context to read beyond a box: ``REACH_FACTOR`` times the
    widest along-track reach of the estimators' windows (density boxes with their
    background segments, ground-surface kernels at 3 sigma, the classifier's trend and
    top-of-canopy windows; the paper's per-block method has none), plus the longest of
    the block ``lengths``, so that every block meeting the box is read whole."""
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
    return REACH_FACTOR * max(reach) + max((float(v) for v in lengths), default=0.0)


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
    """The photons inside the box of a read with context (the marks removed)."""
    track.extra.pop(ORIGIN, None)
    track.extra.pop(START, None)
    inside = track.extra.pop(IN_BOX, None)
    return track if inside is None else track.subset(inside)


def box_params(track: PhotonTrack, params: BlockParams) -> BlockParams:
    """``params`` with the full run's grid origin of a track read with context as ``s0``
    (unchanged when ``s0`` is set, or for a track read whole)."""
    origin = track.extra.get(ORIGIN)
    if origin is None or params.s0 is not None or len(origin) == 0:
        return params
    return replace(params, s0=float(origin[0]))


def box_estimators(track: PhotonTrack, estimators: Estimators | None) -> Estimators | None:
    """``estimators`` with, for a track read with context, the density filter's background
    segments starting where the full run's do (the track's first photon)."""
    start = track.extra.get(START)
    if start is None or len(start) == 0:
        return estimators
    from ..blocks.estimators import default_estimators

    est = default_estimators() if estimators is None else estimators
    if est.noise != "density":
        return estimators
    return replace(est, density=replace(est.density, origin=float(start[0])))


def blocks_in_box(track: PhotonTrack, params: BlockParams, estimators: Estimators | None,
                  block: Callable[..., tuple[gpd.GeoDataFrame, Any]]
                  ) -> tuple[gpd.GeoDataFrame, Any]:
    """``block(params, estimators=estimators)`` (a block table and labels) of a track; of a
    track read with context: on the full run's grid (:func:`box_params`, with the full
    run's density segments, :func:`box_estimators`), cut to the box (:func:`cut_to_box`),
    the warnings on sparse and implausible blocks counting the box's blocks only (not
    those of the margin, cut away)."""
    from ..blocks.plausibility import ImplausibleBlockWarning, flag_implausible_blocks
    from ..errors import SparseBlockWarning
    from ..schema import FLAG_IMPLAUSIBLE

    if IN_BOX not in track.extra:
        return block(params, estimators=estimators)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        blocks, labels = block(box_params(track, params),
                               estimators=box_estimators(track, estimators))
    blocks, labels = cut_to_box(track, blocks, labels)
    for w in caught:
        if not issubclass(w.category, (SparseBlockWarning, ImplausibleBlockWarning)):
            warnings.warn(w.message, stacklevel=2)
    flag = blocks["flag"].to_numpy()
    n = int((flag == "sparse").sum())
    if n:
        warnings.warn(f"track {track.track}: {n} of {len(blocks)} blocks hold fewer than "
                      f"min_photons={params.min_photons} photons kept; they are flagged "
                      "'sparse' with NaN metrics", SparseBlockWarning, stacklevel=2)
    tall = flag == FLAG_IMPLAUSIBLE
    if tall.any():  # flagged again, to be counted among the box's blocks
        blocks.loc[tall, "flag"] = "ok"
        flag_implausible_blocks(blocks, track.track)
    return blocks, labels


def grid_origin(open_track: Any, path: Any, selection: dict, *, box_start: float,
                margin: float, estimators: Estimators | None, crs: Any
                ) -> tuple[float | None, float | None]:
    """The along-track origin of the block grid of a run of the whole track: its first
    photon with a finite position and height (with ``noise="density"``, the first the
    density filter keeps, as the engine blocks the kept photons only); and the track's
    first photon with a finite ``s`` and height (the density filter's start).

    Only the track's head is read: for an ATL03 beam ``margin`` + 100 m from its first
    geolocation segment, else up to ``margin`` beyond ``box_start`` (those readers read
    the whole track anyway).  None when the head holds no such photon (the box's own
    start is then the origin)."""
    from ..blocks.estimators import default_estimators
    from ..errors import NoUsableDataError
    from ..readers import detect_product
    from ..readers.atl03 import atl03_track_start

    start = None
    if "beam" in selection and detect_product(path) == "ATL03":
        start = atl03_track_start(path, selection["beam"])
    upper = (box_start if start is None else start + 100.0) + margin
    try:
        head = open_track(path, s_range=(-np.inf, upper), crs=crs, **selection)
    except NoUsableDataError:
        return None, None
    s, h = np.asarray(head.s, float), np.asarray(head.h, float)
    fin = np.isfinite(s) & np.isfinite(h)
    first = float(np.min(s[fin])) if fin.any() else None
    ok = fin & np.isfinite(np.asarray(head.x, float)) & np.isfinite(np.asarray(head.y, float))
    est = default_estimators() if estimators is None else estimators
    if est.noise == "density":
        from ..blocks.density_filter import density_filter

        ok &= density_filter(s, h, est.density).keep
    elif est.noise == "atl08" and est.ground != "atl08":  # blocks of the signal photons
        from ..blocks.atl08_classify import classify_photons

        ok &= classify_photons(head, est.atl08).classes > 0
    return (float(np.min(s[ok])) if ok.any() else None), first


def read_with_context(open_track: Any, path: Any, selection: dict, *,
                      bbox: tuple[float, float, float, float], margin: float,
                      estimators: Estimators | None = None, **kw: Any) -> PhotonTrack:
    """One track read inside ``bbox`` and ``margin`` metres along the track beyond it,
    the box's photons marked and the full run's grid origin (:data:`ORIGIN`) set; the
    box's own read when the margin is 0."""
    box = open_track(path, bbox=bbox, **kw, **selection)
    if margin <= 0 or len(box) == 0:
        return box
    s = np.asarray(box.s, float)
    lo, hi = float(np.nanmin(s)), float(np.nanmax(s))
    kw = {**kw, "crs": box.crs}
    wide = open_track(path, s_range=(lo - margin, hi + margin), **kw, **selection)
    origin, first = grid_origin(open_track, path, selection, box_start=lo, margin=margin,
                                estimators=estimators, crs=box.crs)
    if first is not None and len(wide) and float(np.nanmin(wide.s)) > first:
        _warn_windows(wide, estimators, float(np.nanmin(wide.s)) - first)
    for name, value in ((ORIGIN, origin), (START, first)):
        if value is not None:
            wide.extra[name] = np.broadcast_to(np.float64(value), (len(wide),))
    return mark_box(wide, bbox)


def _warn_windows(track: PhotonTrack, estimators: Estimators | None, after: float) -> None:
    """Warn that the estimators' windows of a box far along the track start elsewhere
    (the classifier's and the ground surface's; the density filter's start at the track's
    start, :func:`box_estimators`)."""
    from ..blocks.estimators import default_estimators
    from ..errors import CanopyBlocksWarning

    est = default_estimators() if estimators is None else estimators
    if est.noise != "atl08" and est.ground != "surface":
        return
    warnings.warn(
        f"{track.track} of {track.source or 'the photons'}: the box's context starts "
        f"{after:,.0f} m after the track's start, and the {est.name} estimators' windows "
        "(the classifier's and the ground surface's) start at the first photon read: the box's blocks lie on the full run's grid but their heights can "
        "differ from a run over the whole track; for those, run without --bbox (the "
        "paper's method, --preset paper, gives them with --bbox)",
        CanopyBlocksWarning, stacklevel=3)
