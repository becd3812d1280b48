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

from ..blocks.atl08_classify import CLASS_COLUMN, Atl08Params, classify_photons
from ..blocks.atl08_segments import atl08_segments
from ..blocks.uncertainty import add_segment_sigma
from ..errors import InputError
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
    from .blocks import read_tracks

    if not (isinstance(length, (int, float)) and np.isfinite(length) and length > 0):
        raise InputError(f"segment length must be a positive number of metres, got {length!r}")
    if output is not None:
        check_output_path(output)
    if with_photons and (output is None or str(output).lower().endswith((".csv", ".parquet"))):
        raise InputError("the classified photons need a GeoPackage output (.gpkg)")
    prog = as_progress(progress)
    tracks = read_tracks(path, beams=beams, channel=channel, bbox=bbox, crs=crs,
                         progress=prog.sub(0.0, 0.3))
    frames = []
    for i, t in enumerate(tracks):
        prog.update(0.3 + 0.6 * i / len(tracks), f"classifying {t.track}")
        classes = classify_photons(t, params)
        if with_photons:
            t.extra[CLASS_COLUMN] = classes.classes
        frames.append(add_segment_sigma(atl08_segments(t, classes, float(length), s0), t,
                                        classes))
    table = gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), geometry="geometry",
                             crs=tracks[0].crs)
    if output is not None:
        layers: dict[str, pd.DataFrame | Iterable[pd.DataFrame]] = {LAYER_SEGMENTS: table}
        if with_photons:
            layers[LAYER_PHOTONS] = (t.to_geodataframe() for t in tracks)
        prog.update(0.9, "writing")
        write_layers(layers, output)
    prog.report(1.0, "done")
    log.info("%d segments of %g m from %d tracks", len(table), length, len(tracks))
    return table
