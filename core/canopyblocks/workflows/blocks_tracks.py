"""One track of a photon file read and blocked (:func:`read_track`,
:func:`blocks_of_track`), and the tracks of a file so in a pool of worker processes.

One unit of work is one track (an ATL03 beam): it is read, checked and blocked inside a
worker, and only its block table (and, when asked for, its labels and photons) comes back.
h5py serialises every HDF5 call inside one process, so reading and decompressing beams in
parallel needs processes, not threads.  The result is the table :func:`run_blocks` makes
from :func:`read_tracks` in one process, value for value: tracks come back in the order of
the file, every track is projected to the CRS of the first usable one (a track whose own
UTM zone differs is read again in that CRS), and warnings raised in the workers are raised
again here, in track order.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any

import geopandas as gpd
import numpy as np
import pandas as pd

from ..blocks import BlockParams
from ..errors import CanopyBlocksWarning, InputError, NoUsableDataError
from ..photons import PhotonTrack
from ..progress import Progress, as_progress
from ..schema import BLOCK_COLUMNS
from .backends import default_workers, run_items
from .box_context import blocks_in_box, box_photons, read_with_context

if TYPE_CHECKING:
    from ..blocks.estimators import Estimators

__all__ = ["TrackJob", "TrackOutcome", "blocks_in_workers", "track_workers_for",
           "WORKER_BASE_BYTES", "WORKER_BYTES_PER_PHOTON"]

#: Resident memory of one worker before it reads a track (its imports), bytes.
WORKER_BASE_BYTES = 400 * 2**20
#: Peak memory of a worker per photon of its track (reading, sorting, blocking), bytes.
WORKER_BYTES_PER_PHOTON = 250


@dataclass(frozen=True)
class TrackJob:
    """One track to read and block in a worker (every field picklable)."""

    path: str
    selection: dict
    params: BlockParams
    estimators: Estimators | None = None
    atl08: str | None = None
    bbox: tuple[float, float, float, float] | None = None
    crs: Any = None
    min_signal_conf: int | None = None
    labels: bool = False
    keep_track: bool = False
    #: metres read beyond ``bbox`` along the track for the estimators' context
    #: (:func:`~canopyblocks.workflows.box_context.context_margin`)
    context: float = 0.0
    #: (length m, s0 m or None, Atl08Params or None): the track's ATL08-style segments
    #: instead of its blocks (:func:`~canopyblocks.workflows.segments.segments_of_track`)
    segments: tuple[float, float | None, Any] | None = None


@dataclass
class TrackOutcome:
    """What a worker sends back for one :class:`TrackJob`."""

    job: TrackJob
    track_id: str = ""
    crs: Any = None
    blocks: gpd.GeoDataFrame | None = None
    labels: dict[float, np.ndarray] | None = None
    track: PhotonTrack | None = None
    problem: str | None = None
    warnings: tuple[tuple[str, type[Warning]], ...] = ()


def run_track_job(job: TrackJob) -> TrackOutcome:
    """Read and block one track (runs in a worker); a track without usable photons comes
    back as a ``problem``, any other error is raised in the caller."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            t = read_track(job.path, job.selection, atl08=job.atl08, bbox=job.bbox,
                           crs=job.crs, min_signal_conf=job.min_signal_conf,
                           context=job.context, estimators=job.estimators)
        except NoUsableDataError as exc:
            out = TrackOutcome(job, problem=str(exc))
        else:
            if job.segments is not None:
                length, s0, classifier = job.segments
                blocks = segments_of_track(t, classifier, length, s0,
                                           with_photons=job.keep_track)
                labels = None
            else:
                blocks, labels = blocks_in_box(t, job.params, job.estimators, partial(
                    blocks_of_track, t, labels=job.labels))
                t = box_photons(t)
            out = TrackOutcome(job, track_id=t.track, crs=t.crs, blocks=blocks, labels=labels,
                               track=t if job.keep_track else None)
    out.warnings = tuple((str(w.message), w.category) for w in caught)
    return out


def segments_of_track(track: PhotonTrack, params: Any, length: float,
                      s0: float | None, *, with_photons: bool = False) -> pd.DataFrame:
    """One track's segment table (columns as :func:`segments_from_file`); with
    ``with_photons`` its photons get their ``classed_pc_flag``."""
    from ..blocks.atl08_classify import CLASS_COLUMN, classify_photons
    from ..blocks.atl08_segments import atl08_segments
    from ..blocks.uncertainty import add_segment_sigma

    classes = classify_photons(track, params)
    if with_photons:
        track.extra[CLASS_COLUMN] = classes.classes
    return add_segment_sigma(atl08_segments(track, classes, length, s0), track, classes)


def track_workers_for(photons_per_track: Sequence[int], workers: int | None = None) -> int:
    """Worker processes for tracks of these sizes: ``workers`` or the machine's cores,
    never more than the tracks, nor than the memory available holds
    (:data:`WORKER_BASE_BYTES` + :data:`WORKER_BYTES_PER_PHOTON` per photon of the largest
    track each)."""
    if workers is not None and workers < 1:
        raise InputError(f"workers must be >= 1, got {workers}")
    n = min(workers or default_workers(), max(1, len(photons_per_track)))
    if workers is None and photons_per_track:
        per = WORKER_BASE_BYTES + WORKER_BYTES_PER_PHOTON * max(photons_per_track)
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            avail = per * n
        n = max(1, min(n, int(avail // per)))
    return n


def blocks_in_workers(
    path: str | os.PathLike[str],
    selections: Sequence[dict],
    params: BlockParams,
    *,
    workers: int,
    sizes: Sequence[int] = (),
    estimators: Estimators | None = None,
    atl08: str | os.PathLike[str] | None = None,
    bbox: tuple[float, float, float, float] | None = None,
    crs: Any = None,
    min_signal_conf: int | None = None,
    labels: bool = False,
    keep_tracks: bool = False,
    segments: tuple[float, float | None, Any] | None = None,
    context: float = 0.0,
    progress: Progress | None = None,
) -> tuple[gpd.GeoDataFrame, list[str], list[PhotonTrack], dict[str, dict[float, np.ndarray]]]:
    """Blocks of the tracks ``selections`` of ``path`` (see :func:`select_tracks`), read and
    blocked in ``workers`` processes, the largest first (``sizes``: photons per track) so
    that the last to finish is a small one.

    Returns
    -------
    blocks : GeoDataFrame
        All tracks' blocks, in file order, in one metric CRS (``crs`` or the UTM zone of the
        first usable track), equal to ``run_blocks(read_tracks(...))``.
    track_ids : list of str
        The tracks blocked.
    tracks : list of PhotonTrack
        The tracks themselves with ``keep_tracks`` (they cost memory here), else empty.
    labels : dict
        ``labels[track_id][length]`` with ``labels``.

    With ``segments`` (see :class:`TrackJob`), each track's ATL08-style segment table
    instead of its blocks.

    Raises
    ------
    NoUsableDataError
        When no track holds usable photons.
    """
    prog = as_progress(progress)
    jobs = [TrackJob(path=str(path), selection=dict(sel), params=params, estimators=estimators,
                     atl08=None if atl08 is None else str(atl08), bbox=bbox, crs=crs,
                     min_signal_conf=min_signal_conf, labels=labels, keep_track=keep_tracks,
                     segments=segments, context=context)
            for sel in selections]
    finished = [0]

    def done(out: TrackOutcome) -> None:  # raises CancelledError when asked to stop
        finished[0] += 1
        prog.update(finished[0] / max(1, len(jobs)),
                    f"{out.track_id or out.job.selection}: "
                    f"{'classified' if segments else 'blocked'}")

    order = (sorted(range(len(jobs)), key=lambda i: -sizes[i]) if len(sizes) == len(jobs)
             else list(range(len(jobs))))
    ran = run_items(run_track_job, [jobs[i] for i in order], backend="processes",
                    workers=workers, done=done, start="fork")
    outcomes: list[TrackOutcome] = [ran[order.index(i)] for i in range(len(jobs))]
    first = next((o for o in outcomes if o.problem is None), None)
    ref_crs = crs if crs is not None else (first.crs if first is not None else None)
    for i, out in enumerate(outcomes):
        if out.problem is None and crs is None and out.crs != ref_crs:
            # another UTM zone than the first track's: as read_tracks does, in the first's
            outcomes[i] = run_track_job(TrackJob(**{**out.job.__dict__, "crs": ref_crs}))
    problems = []
    for out in outcomes:
        for message, category in out.warnings:
            warnings.warn(message, category, stacklevel=2)
        if out.problem is not None:
            problems.append(out.problem)
    good = [o for o in outcomes if o.problem is None]
    if not good:
        raise NoUsableDataError("; ".join(problems) or f"{path}: no usable photons")
    for msg in problems:
        warnings.warn(f"skipped: {msg}", CanopyBlocksWarning, stacklevel=2)
    blocks = concat_blocks([o.blocks for o in good if o.blocks is not None], good[0].crs)
    tracks = [o.track for o in good if o.track is not None]
    all_labels = {o.track_id: o.labels for o in good if o.labels is not None}
    return blocks, [o.track_id for o in good], tracks, all_labels


def read_track(path: str | os.PathLike[str], selection: dict, *,
               atl08: str | os.PathLike[str] | None = None,
               bbox: tuple[float, float, float, float] | None = None, crs: Any = None,
               min_signal_conf: int | None = None, context: float = 0.0,
               estimators: Estimators | None = None) -> PhotonTrack:
    """One track of a photon file (``selection``: an item of :func:`select_tracks`);
    with ``bbox`` and ``context`` metres, the box's photons and that much of the track
    beyond it, the box's marked, and the origin of the full run's block grid for
    ``estimators`` (:mod:`~canopyblocks.workflows.box_context`).

    Raises
    ------
    NoUsableDataError
        When it holds no photons, or none at ``min_signal_conf``.
    """
    from ..readers import open_track

    if bbox is not None and context > 0:
        t = read_with_context(open_track, path, selection, bbox=bbox, margin=context,
                              estimators=estimators, atl08=atl08, crs=crs)
    else:
        t = open_track(path, bbox=bbox, atl08=atl08, crs=crs, **selection)
    if min_signal_conf is not None:
        _require_signal(t, min_signal_conf)
    if len(t) == 0:
        raise NoUsableDataError(f"{t.track} of {path}: no photons")
    return t


def _require_signal(track: PhotonTrack, level: int) -> None:
    if track.signal_conf is None:
        return  # BlockParams validation reports a missing signal_conf column
    good = int(np.count_nonzero(track.signal_conf >= level))
    if good == 0:
        values = np.unique(track.signal_conf)
        raise NoUsableDataError(
            f"{track.track} of {track.source}: no photon has land signal confidence >= {level} "
            f"(values present: {', '.join(map(str, values[:8]))}); the surface is not land "
            "(e.g. sea ice or ocean) or the level is too strict"
        )


def blocks_of_track(track: PhotonTrack, params: BlockParams, *, labels: bool = False,
                    estimators: Estimators | None = None, progress: Progress | None = None
                    ) -> tuple[gpd.GeoDataFrame, dict[float, np.ndarray] | None]:
    """The block table of one track and, with ``labels``, its per-photon labels
    (``estimators`` None: the recommended ones, :func:`~canopyblocks.blocks.estimators.
    default_estimators`)."""
    from ..blocks.estimators import default_estimators, estimate_blocks

    est = default_estimators() if estimators is None else estimators
    if labels:
        return estimate_blocks(track, params, est, labels=True, progress=progress)
    return estimate_blocks(track, params, est, progress=progress), None


def concat_blocks(frames: Sequence[pd.DataFrame], crs: Any) -> gpd.GeoDataFrame:
    """The block tables of several tracks as one (an empty table with the columns when none)."""
    if not frames:
        return gpd.GeoDataFrame(columns=[*BLOCK_COLUMNS, "geometry"], geometry="geometry",
                                crs=crs)
    return gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), geometry="geometry", crs=crs)
