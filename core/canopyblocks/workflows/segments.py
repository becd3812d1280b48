"""File-to-layer orchestration of ATL08-style segments, shared by the CLI and the QGIS plugin.

``segments_from_file``: read the tracks of a photon file (:func:`~.track_blocks.read_tracks`),
classify each track's photons as ATL08 does (:mod:`.blocks.atl08_classify`), summarise them
in segments of any length with ATL08's column names (:mod:`.blocks.atl08_segments`), and
write the table (and, on request, the classified photons) atomically.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Sequence
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd

from ..blocks.atl08_classify import Atl08Params
from ..errors import InputError
from ..photons import PhotonTrack
from ..progress import Progress, as_progress
from ..schema import LAYER_PHOTONS

__all__ = ["segments_from_file", "LAYER_SEGMENTS"]

log = logging.getLogger(__name__)

LAYER_SEGMENTS = "segments"


def segments_from_file(
    path: str | os.PathLike[str],
    *,
    length: float = 100.0,
    s0: float | None = None,
    beams: Sequence[str] = (),
    channel: int | str | None = None,
    bbox: tuple[float, float, float, float] | None = None,
    crs: Any = None,
    params: Atl08Params | None = None,
    output: str | os.PathLike[str] | None = None,
    with_photons: bool = False,
    workers: int | None = None,
    progress: Progress | None = None,
) -> gpd.GeoDataFrame:
    """ATL08-style segments of every track of a photon file.

    Parameters
    ----------
    path : path-like
        ATL03 granule, MABEL file or photon table.
    length : float
        Segment length along the track, m (ATL08: 100).
    s0 : float, optional
        Along-track origin of segment 0 (m); default the start of each track.
    beams, channel, bbox, crs
        As for :func:`~canopyblocks.workflows.blocks.read_tracks`.
    params : Atl08Params, optional
        The classifier's parameters.
    output : path-like, optional
        ``.gpkg`` (layer ``segments``, plus ``photons`` with ``with_photons``), ``.parquet``
        or ``.csv``; written atomically.
    with_photons : bool
        Also write the photons with their ``classed_pc_flag`` (GeoPackage output).
    workers : int, optional
        Processes classifying the beams of an ATL03 granule in parallel (as ``blocks``);
        None: the machine's cores, capped by the memory available; 1: one process.

    Returns
    -------
    GeoDataFrame
        Columns :data:`~canopyblocks.blocks.atl08_segments.SEGMENT_COLUMNS` of all tracks,
        then ``hmax_sigma`` (1 sigma of ``h_canopy``, m), ``ground_sigma`` (of the mean
        ground, m) and ``use`` (:mod:`~canopyblocks.blocks.uncertainty`).
    """
    from ..arguments import check_source
    check_source(path, "segments_from_file: path", "a photon file path or URL")
    from ..outputs.tables import check_output_path, write_layers
    if not (isinstance(length, (int, float)) and np.isfinite(length) and length > 0):
        raise InputError(f"segment length must be a positive number of metres, got {length!r}")
    if output is not None:
        check_output_path(output)
    if with_photons and (output is None or str(output).lower().endswith((".csv", ".parquet"))):
        raise InputError("the classified photons need a GeoPackage output (.gpkg)")
    prog = as_progress(progress)
    from .blocks import small_pages

    with small_pages():  # (as blocks: the workers are forked inside and inherit it)
        table, tracks = _classify_tracks(path, beams, channel, bbox, crs, params,
                                         float(length), s0, with_photons, workers, prog)
    if output is not None:
        layers: dict[str, pd.DataFrame | Iterable[pd.DataFrame]] = {LAYER_SEGMENTS: table}
        if with_photons:
            layers[LAYER_PHOTONS] = (t.to_geodataframe() for t in tracks)
        prog.update(0.9, "writing")
        write_layers(layers, output)
    prog.report(1.0, "done")
    log.info("%d segments of %g m", len(table), length)
    return table


def _classify_tracks(path: Any, beams: Sequence[str], channel: int | str | None,
                     bbox: Any, crs: Any, params: Atl08Params | None, length: float,
                     s0: float | None, with_photons: bool, workers: int | None,
                     prog: Progress) -> tuple[gpd.GeoDataFrame, list[PhotonTrack]]:
    """The segment tables of the tracks, each beam of a granule in a worker process when
    there are several (the pool and memory cap of ``blocks``), else one after another."""
    from ..readers.remote import is_file_object, source_arg
    from .blocks import _workers_for, read_tracks, select_tracks
    from .blocks_tracks import segments_of_track

    n_workers = 1
    if not is_file_object(path) and workers != 1:
        selections = select_tracks(source_arg(path), tuple(beams), channel)
        if len(selections) > 1:
            n_workers, sizes = _workers_for(path, selections, workers)
    if n_workers > 1:
        from ..blocks import BlockParams
        from .blocks_tracks import blocks_in_workers

        table, _, tracks, _ = blocks_in_workers(
            path, selections, BlockParams(), workers=n_workers, sizes=sizes, bbox=bbox,
            crs=crs, keep_tracks=with_photons, segments=(length, s0, params),
            progress=prog.sub(0.0, 0.9))
        return table, tracks
    tracks = read_tracks(path, beams=beams, channel=channel, bbox=bbox, crs=crs,
                         progress=prog.sub(0.0, 0.3))
    frames = []
    for i, t in enumerate(tracks):
        prog.update(0.3 + 0.6 * i / len(tracks), f"classifying {t.track}")
        frames.append(segments_of_track(t, params, length, s0, with_photons=with_photons))
    table = gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), geometry="geometry",
                             crs=tracks[0].crs)
    return table, tracks
