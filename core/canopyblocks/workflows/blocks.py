"""File-to-layer orchestration shared by the CLI and the QGIS plugin.

``read_tracks`` (file -> PhotonTracks) and ``blocks_from_file`` (file -> block
table, optional photon layer and profile plot, written atomically).
"""

from __future__ import annotations

import importlib
import logging
import os
import warnings
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import geopandas as gpd
import numpy as np
import pandas as pd

from ..blocks import BlockParams
from ..errors import CanopyBlocksWarning, NoUsableDataError
from ..photons import PhotonTrack
from ..progress import Progress, as_progress
from ..schema import LABEL_NAMES, LAYER_BLOCKS, LAYER_PHOTONS
from .blocks_tracks import blocks_of_track, concat_blocks, read_track
from .box_context import blocks_in_box, box_photons, context_margin

if TYPE_CHECKING:
    from ..blocks.estimators import Estimators

__all__ = ["BlocksResult", "select_tracks", "read_tracks", "run_blocks", "blocks_from_file",
           "photon_layer", "track_strengths", "calibrate_blocks"]

log = logging.getLogger(__name__)


@dataclass
class BlocksResult:
    """What :func:`blocks_from_file` produced.

    Attributes
    ----------
    tracks : list of PhotonTrack
        One per beam/channel read, all in the same metric CRS (with ``workers`` > 1 only
        when the photon layer or the profile needed them).
    blocks : GeoDataFrame
        The block table of all tracks (DESIGN section 5 columns).
    labels : dict
        ``labels[track_id][length]`` -> per-photon int8 labels.
    outputs : list of Path
        Files written.
    track_ids : list of str
        The tracks blocked, in file order.
    """

    tracks: list[PhotonTrack]
    blocks: gpd.GeoDataFrame
    labels: dict[str, dict[float, np.ndarray]] = field(default_factory=dict)
    outputs: list[Path] = field(default_factory=list)
    track_ids: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.track_ids:
            self.track_ids = [t.track for t in self.tracks]


def select_tracks(path: Any, beams: tuple[str, ...], channel: int | str | None) -> list[dict]:
    """The list of ``open_track`` keyword sets to read: one per beam/channel.

    ATL03 without ``--beam``: every beam that holds photons.  MABEL without
    ``--channel``: the channel with the most photons (as seed 001 picked channel 49).
    """
    from ..readers import atl03_beams, detect_product

    # only the product and the beam list: reading the tracks is open_track's job
    product = detect_product(path)
    if product == "ATL03":
        names = list(beams) or [b.name for b in atl03_beams(path) if b.n_photons]
        return [{"beam": b} for b in names]
    if product == "MABEL":
        return [{"channel": channel if channel is not None else "most"}]
    return [{}]


def read_tracks(
    path: str | os.PathLike[str],
    *,
    beams: Sequence[str] = (),
    channel: int | str | None = None,
    atl08: str | os.PathLike[str] | None = None,
    bbox: tuple[float, float, float, float] | None = None,
    crs: Any = None,
    min_signal_conf: int | None = None,
    context: float = 0.0,
    estimators: Estimators | None = None,
    progress: Progress | None = None,
) -> list[PhotonTrack]:
    """Read the tracks of a photon file: the given ATL03 beams (default every beam
    with photons), a MABEL channel (default the one with most photons), or a table.

    All tracks are projected to one metric CRS (``crs`` or the UTM zone of the
    first track).  Beams without usable photons are skipped with a warning.  With
    ``bbox`` and ``context`` metres, each track also holds that much beyond the box, its
    photons inside the box marked, and the origin of the full run's block grid for
    ``estimators`` (:mod:`~canopyblocks.workflows.box_context`).

    Raises
    ------
    NoUsableDataError
        When no requested beam/channel holds usable photons (e.g. a sea-ice granule
        with ``min_signal_conf`` set: its land confidence is -1 everywhere).
    """
    from ..arguments import check_source
    from ..readers.remote import source_arg, source_name
    check_source(path, "read_tracks: path", "a photon file path or URL")
    prog = as_progress(progress)
    selections = select_tracks(source_arg(path), tuple(beams), channel)
    tracks: list[PhotonTrack] = []
    problems: list[str] = []
    for i, sel in enumerate(selections):
        prog.update(i / max(1, len(selections)), f"reading {sel or source_name(path)}")
        try:
            t = read_track(path, sel, atl08=atl08, bbox=bbox, crs=crs,
                           min_signal_conf=min_signal_conf, context=context,
                           estimators=estimators)
        except NoUsableDataError as exc:
            problems.append(str(exc))
            continue
        if crs is None:
            crs = t.crs
        tracks.append(t)
    if not tracks:
        raise NoUsableDataError("; ".join(problems) or f"{path}: no usable photons")
    for msg in problems:
        warnings.warn(f"skipped: {msg}", CanopyBlocksWarning, stacklevel=2)
    prog.update(1.0)
    return tracks


def run_blocks(
    tracks: Sequence[PhotonTrack],
    params: BlockParams,
    *,
    labels: bool = False,
    estimators: Estimators | None = None,
    progress: Progress | None = None,
) -> tuple[gpd.GeoDataFrame, dict[str, dict[float, np.ndarray]]]:
    """Block table of several tracks (concatenated) and, optionally, their labels.

    ``estimators`` (DESIGN 1.10; e.g. ``blocks.estimators.preset("icesat2")``) chooses
    the noise filter, ground and top estimators; None: the recommended ones (the
    ``atl08`` preset); ``preset("paper")`` runs the paper's method, bit for bit.
    """
    prog = as_progress(progress)
    frames: list[gpd.GeoDataFrame] = []
    all_labels: dict[str, dict[float, np.ndarray]] = {}
    for i, t in enumerate(tracks):
        sub = prog.sub(i / len(tracks), (i + 1) / len(tracks))
        # a track read with context: its box's blocks, on the full run's grid
        b, lab = blocks_in_box(t, params, estimators, partial(
            blocks_of_track, t, labels=labels, progress=sub))
        if lab is not None:
            all_labels[t.track] = lab
        frames.append(b)
    return concat_blocks(frames, tracks[0].crs if tracks else None), all_labels


def photon_layer(tracks: Sequence[PhotonTrack],
                 labels: dict[str, dict[float, np.ndarray]]) -> gpd.GeoDataFrame:
    """Photons of all tracks as points, with a ``label_<L>m`` column per block length
    (and ``time_utc`` beside ``time`` for ATL03 granules)."""
    from ..readers import detect_product
    from ..readers.utc_time import file_counts_from_sdp_epoch, utc_from_delta_time

    frames = []
    for t in tracks:
        g = t.to_geodataframe()
        if t.source and detect_product(str(t.source)) == "ATL03" and \
                file_counts_from_sdp_epoch(t.source):  # UTC beside delta_time, to the ms
            utc = utc_from_delta_time(t.time).astype("datetime64[ms]")
            g.insert(g.columns.get_loc("time") + 1, "time_utc", utc.astype("datetime64[ns]"))
        for length, lab in sorted(labels.get(t.track, {}).items()):
            names = np.array([LABEL_NAMES.get(i, "outside") for i in range(-1, 4)], dtype=object)
            g[f"label_{length:g}m"] = names[np.asarray(lab, dtype=np.int64) + 1]
        frames.append(g)
    return gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), geometry="geometry",
                            crs=tracks[0].crs)


def track_strengths(path: str | os.PathLike[str], tracks: Sequence[PhotonTrack | str]
                    ) -> dict[str, str]:
    """Beam strength (``strong``/``weak``) of each ATL03 track (tracks or their ids);
    ``{}`` for other files (one calibration model for all their tracks)."""
    from ..readers import atl03_beams, detect_product

    if detect_product(str(path)) != "ATL03":
        return {}
    info = {b.name: b.strength for b in atl03_beams(path)}
    ids = [t if isinstance(t, str) else t.track for t in tracks]
    return {i: info[i] for i in ids if i in info}


def _workers_for(path: str | os.PathLike[str], selections: Sequence[dict],
                 workers: int | None) -> tuple[int, list[int]]:
    """Processes for the beams ``selections`` of an ATL03 granule (1 for other files), and
    the photons of each beam."""
    from ..readers import atl03_beams, detect_product
    from .blocks_tracks import track_workers_for

    if workers == 1 or detect_product(path) != "ATL03":
        return 1, []
    n_photons = {b.name: b.n_photons for b in atl03_beams(path)}
    sizes = [n_photons.get(s.get("beam", ""), 0) for s in selections]
    return track_workers_for(sizes, workers), sizes


def calibrate_blocks(blocks: gpd.GeoDataFrame, calibration: Any,
                     strengths: dict[str, str]) -> gpd.GeoDataFrame:
    """Blocks with a bias calibration (a BiasCalibration or its JSON file) applied."""
    from ..validation.bias_calibration import (
        BiasCalibration,
        apply_bias_calibration,
        read_bias_calibration,
    )

    source = str(calibration)
    cal = (calibration if isinstance(calibration, BiasCalibration)
           else read_bias_calibration(calibration))
    out = apply_bias_calibration(blocks, cal, strengths=strengths or None, source=source)
    return gpd.GeoDataFrame(out, geometry="geometry", crs=blocks.crs)


@contextmanager
def small_pages() -> Iterator[None]:
    """numpy's new arrays without transparent huge pages for the duration.

    numpy asks the kernel for huge pages (``madvise``) on every large array; where the
    kernel honours that only on request (``transparent_hugepage`` set to ``madvise``, the
    usual default) each such array is faulted in by compacting memory first. Reading and
    blocking a 14 M-photon beam allocates a few GB of short-lived columns: measured 1.4-1.7
    s of system time in the read with huge pages, 0.55-0.6 s without (user time +0.2 s, the
    TLB), read and blocks together 4.0 -> 3.4 s CPU. Restored on exit."""
    setter = None
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            setter = getattr(importlib.import_module(name), "_set_madvise_hugepage", None)
        except ImportError:
            continue
        if setter is not None:
            break
    previous = setter(False) if setter is not None else None
    try:
        yield
    finally:
        if setter is not None:
            setter(bool(previous))


def blocks_from_file(
    path: str | os.PathLike[str],
    params: BlockParams | None,
    *,
    estimators: Estimators | None = None,
    calibration: Any = None,
    beams: Sequence[str] = (),
    channel: int | str | None = None,
    atl08: str | os.PathLike[str] | None = None,
    bbox: tuple[float, float, float, float] | None = None,
    crs: object = None,
    output: str | os.PathLike[str] | None = None,
    with_photons: bool = False,
    profile: str | os.PathLike[str] | None = None,
    workers: int | None = 1,
    progress: Progress | None = None,
) -> BlocksResult:
    """Read a photon file, compute the block table, and write the requested outputs.

    Parameters
    ----------
    path : path-like
        ATL03 granule, MABEL L2A file, or a CSV/Parquet photon table.
    params : BlockParams or None
        Block lengths, noise filter, cut-offs (None: the defaults).
    estimators : Estimators, optional
        The block estimators (DESIGN 1.10); default the recommended ones (the ``atl08``
        preset); ``preset("paper")`` for the paper's method.
    calibration : BiasCalibration or path, optional
        Bias calibration (``canopyblocks calibrate --method bias``) applied to hmax/h90
        (and top/z90); refused when fitted with other estimators.
    output : path-like, optional
        ``.gpkg`` (layer ``blocks``, plus ``photons`` with ``with_photons``),
        ``.parquet`` or ``.csv``; written atomically.
    profile : path-like, optional
        PNG profile plot of the first track (smallest block length).
    workers : int or None
        Processes reading and blocking the beams of an ATL03 granule in parallel
        (:mod:`canopyblocks.workflows.blocks_tracks`; same table as one process); None: the
        machine's cores, capped by the memory available.  ``tracks`` of the result are
        then kept only when the photon layer or the profile needs them.

    Returns
    -------
    BlocksResult
    """
    from ..arguments import check_instance, check_source
    from ..readers.remote import is_file_object, source_arg
    check_source(path, "blocks_from_file: path", "a photon file path or URL")
    if is_file_object(path):
        workers = 1  # an open file stays in this process
    params = BlockParams() if params is None else params
    check_instance(params, BlockParams, "blocks_from_file: params",
                   "a BlockParams (None: the defaults)")
    from ..atomic import check_writable
    from ..outputs.tables import check_output_path, write_layers

    if output is not None:
        check_output_path(output)  # fail before reading, not after an hour of work
    if profile is not None:
        check_writable(profile)
    prog = as_progress(progress)
    want_labels = with_photons or profile is not None
    # a box is read with the estimators' context along the track and its blocks whole, on
    # the full run's grid, then cut to it
    context = 0.0 if bbox is None else context_margin(estimators, params.lengths)
    selections = select_tracks(source_arg(path), tuple(beams), channel)
    n_workers, sizes = (1, []) if len(selections) < 2 else _workers_for(path, selections,
                                                                       workers)
    with small_pages():   # the workers are forked inside: they inherit it
        if n_workers > 1:
            from .blocks_tracks import blocks_in_workers

            blocks, ids, tracks, labels = blocks_in_workers(
                path, selections, params, workers=n_workers, sizes=sizes,
                estimators=estimators, atl08=atl08, bbox=bbox, crs=crs,
                min_signal_conf=params.min_signal_conf, labels=want_labels,
                keep_tracks=want_labels, context=context, progress=prog.sub(0.0, 0.85))
        else:
            tracks = read_tracks(path, beams=beams, channel=channel, atl08=atl08, bbox=bbox,
                                 crs=crs, min_signal_conf=params.min_signal_conf,
                                 context=context, estimators=estimators,
                                 progress=prog.sub(0.0, 0.3))
            blocks, labels = run_blocks(tracks, params, labels=want_labels,
                                        estimators=estimators, progress=prog.sub(0.3, 0.85))
            tracks = [box_photons(t) for t in tracks]
            ids = [t.track for t in tracks]
    if calibration is not None:
        blocks = calibrate_blocks(blocks, calibration, track_strengths(path, ids))
    result = BlocksResult(tracks=tracks, blocks=blocks, labels=labels, track_ids=ids)
    layers: dict[str, pd.DataFrame | Iterable[pd.DataFrame]] = {LAYER_BLOCKS: blocks}
    if output is not None and with_photons:
        if Path(output).suffix.lower() == ".gpkg":
            # one track at a time: the photon layer is never built whole
            layers[LAYER_PHOTONS] = (photon_layer([t], labels) for t in tracks)
        else:
            warnings.warn("--photons needs a .gpkg output; photon layer not written",
                          CanopyBlocksWarning, stacklevel=2)
    prog.update(0.9, "writing")  # the last point where cancelling stops the run
    new = [Path(p) for p in (output, profile) if p is not None and not Path(p).exists()]
    try:
        if output is not None:
            result.outputs.append(write_layers(layers, output))
        if profile is not None:
            from ..outputs.profile_plot import plot_profile

            t = tracks[0]
            result.outputs.append(plot_profile(t, blocks, profile, labels=labels.get(t.track)))
    except BaseException:  # e.g. Ctrl-C while plotting: no half set of outputs
        for p in new:
            p.unlink(missing_ok=True)
        raise
    prog.report(1.0, "done")  # outputs written: too late to cancel
    return result
