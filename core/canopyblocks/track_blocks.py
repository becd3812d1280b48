"""File-to-layer orchestration shared by the CLI and the QGIS plugin.

``read_tracks`` (file -> PhotonTracks) and ``blocks_from_file`` (file -> block
table, optional photon layer and profile plot, written atomically).
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import geopandas as gpd
import numpy as np
import pandas as pd

from .blocks import BlockParams, compute_blocks
from .errors import CanopyBlocksWarning, NoUsableDataError
from .photons import PhotonTrack
from .progress import Progress, as_progress
from .schema import BLOCK_COLUMNS, LABEL_NAMES, LAYER_BLOCKS, LAYER_PHOTONS

if TYPE_CHECKING:
    from .blocks.estimators import Estimators

__all__ = ["BlocksResult", "select_tracks", "read_tracks", "run_blocks", "blocks_from_file",
           "photon_layer", "track_strengths", "calibrate_blocks"]

log = logging.getLogger(__name__)


@dataclass
class BlocksResult:
    """What :func:`blocks_from_file` produced.

    Attributes
    ----------
    tracks : list of PhotonTrack
        One per beam/channel read, all in the same metric CRS.
    blocks : GeoDataFrame
        The block table of all tracks (DESIGN section 5 columns).
    labels : dict
        ``labels[track_id][length]`` -> per-photon int8 labels.
    outputs : list of Path
        Files written.
    """

    tracks: list[PhotonTrack]
    blocks: gpd.GeoDataFrame
    labels: dict[str, dict[float, np.ndarray]] = field(default_factory=dict)
    outputs: list[Path] = field(default_factory=list)


def select_tracks(path: str, beams: tuple[str, ...], channel: int | str | None) -> list[dict]:
    """The list of ``open_track`` keyword sets to read: one per beam/channel.

    ATL03 without ``--beam``: every beam that holds photons.  MABEL without
    ``--channel``: the channel with the most photons (as seed 001 picked channel 49).
    """
    from .readers import atl03_beams, detect_product

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
    progress: Progress | None = None,
) -> list[PhotonTrack]:
    """Read the tracks of a photon file: the given ATL03 beams (default every beam
    with photons), a MABEL channel (default the one with most photons), or a table.

    All tracks are projected to one metric CRS (``crs`` or the UTM zone of the
    first track).  Beams without usable photons are skipped with a warning.

    Raises
    ------
    NoUsableDataError
        When no requested beam/channel holds usable photons (e.g. a sea-ice granule
        with ``min_signal_conf`` set: its land confidence is -1 everywhere).
    """
    from .readers import open_track

    prog = as_progress(progress)
    selections = select_tracks(str(path), tuple(beams), channel)
    tracks: list[PhotonTrack] = []
    problems: list[str] = []
    for i, sel in enumerate(selections):
        prog.update(i / max(1, len(selections)), f"reading {sel or Path(path).name}")
        try:
            t = open_track(path, bbox=bbox, atl08=atl08, crs=crs, **sel)
        except NoUsableDataError as exc:
            problems.append(str(exc))
            continue
        if min_signal_conf is not None:
            _require_signal(t, min_signal_conf)
        if len(t) == 0:
            problems.append(f"{t.track} of {path}: no photons")
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
    the noise filter, ground and top estimators; None runs the paper's engine as it is
    (no ``estimators`` column), bit for bit.
    """
    prog = as_progress(progress)
    frames: list[gpd.GeoDataFrame] = []
    all_labels: dict[str, dict[float, np.ndarray]] = {}
    for i, t in enumerate(tracks):
        sub = prog.sub(i / len(tracks), (i + 1) / len(tracks))
        if estimators is not None:
            from .blocks.estimators import estimate_blocks

            if labels:
                b, lab = estimate_blocks(t, params, estimators, labels=True, progress=sub)
                all_labels[t.track] = lab
            else:
                b = estimate_blocks(t, params, estimators, progress=sub)
        elif labels:
            b, lab = compute_blocks(t, params, labels=True, progress=sub)
            all_labels[t.track] = lab
        else:
            b = compute_blocks(t, params, progress=sub)
        frames.append(b)
    crs = tracks[0].crs if tracks else None
    if not frames:
        return gpd.GeoDataFrame(columns=[*BLOCK_COLUMNS, "geometry"], geometry="geometry",
                                crs=crs), all_labels
    out = gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), geometry="geometry", crs=crs)
    return out, all_labels


def photon_layer(tracks: Sequence[PhotonTrack],
                 labels: dict[str, dict[float, np.ndarray]]) -> gpd.GeoDataFrame:
    """Photons of all tracks as points, with a ``label_<L>m`` column per block length."""
    frames = []
    for t in tracks:
        g = t.to_geodataframe()
        for length, lab in sorted(labels.get(t.track, {}).items()):
            names = np.array([LABEL_NAMES.get(i, "outside") for i in range(-1, 4)], dtype=object)
            g[f"label_{length:g}m"] = names[np.asarray(lab, dtype=np.int64) + 1]
        frames.append(g)
    return gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), geometry="geometry",
                            crs=tracks[0].crs)


def track_strengths(path: str | os.PathLike[str], tracks: Sequence[PhotonTrack]
                    ) -> dict[str, str]:
    """Beam strength (``strong``/``weak``) of each ATL03 track; ``{}`` for other files
    (one calibration model for all their tracks)."""
    from .readers import atl03_beams, detect_product

    if detect_product(str(path)) != "ATL03":
        return {}
    info = {b.name: b.strength for b in atl03_beams(path)}
    return {t.track: info[t.track] for t in tracks if t.track in info}


def calibrate_blocks(blocks: gpd.GeoDataFrame, calibration: Any,
                     strengths: dict[str, str]) -> gpd.GeoDataFrame:
    """Blocks with a bias calibration (a BiasCalibration or its JSON file) applied."""
    from .validation.bias_calibration import (
        BiasCalibration,
        apply_bias_calibration,
        read_bias_calibration,
    )

    source = str(calibration)
    cal = (calibration if isinstance(calibration, BiasCalibration)
           else read_bias_calibration(calibration))
    out = apply_bias_calibration(blocks, cal, strengths=strengths or None, source=source)
    return gpd.GeoDataFrame(out, geometry="geometry", crs=blocks.crs)


def blocks_from_file(
    path: str | os.PathLike[str],
    params: BlockParams,
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
    progress: Progress | None = None,
) -> BlocksResult:
    """Read a photon file, compute the block table, and write the requested outputs.

    Parameters
    ----------
    path : path-like
        ATL03 granule, MABEL L2A file, or a CSV/Parquet photon table.
    params : BlockParams
        Block lengths, noise filter, cut-offs.
    estimators : Estimators, optional
        Estimators beyond the paper's (DESIGN 1.10), e.g. the ``icesat2`` preset.
    calibration : BiasCalibration or path, optional
        Bias calibration (``canopyblocks calibrate --method bias``) applied to hmax/h90
        (and top/z90); refused when fitted with other estimators.
    output : path-like, optional
        ``.gpkg`` (layer ``blocks``, plus ``photons`` with ``with_photons``),
        ``.parquet`` or ``.csv``; written atomically.
    profile : path-like, optional
        PNG profile plot of the first track (smallest block length).

    Returns
    -------
    BlocksResult
    """
    from .outputs.atomic import check_writable
    from .outputs.tables import check_output_path, write_layers

    if output is not None:
        check_output_path(output)  # fail before reading, not after an hour of work
    if profile is not None:
        check_writable(profile)
    prog = as_progress(progress)
    tracks = read_tracks(path, beams=beams, channel=channel, atl08=atl08, bbox=bbox, crs=crs,
                         min_signal_conf=params.min_signal_conf, progress=prog.sub(0.0, 0.3))
    want_labels = with_photons or profile is not None
    blocks, labels = run_blocks(tracks, params, labels=want_labels, estimators=estimators,
                                progress=prog.sub(0.3, 0.85))
    if calibration is not None:
        blocks = calibrate_blocks(blocks, calibration, track_strengths(path, tracks))
    result = BlocksResult(tracks=tracks, blocks=blocks, labels=labels)
    layers: dict[str, pd.DataFrame] = {LAYER_BLOCKS: blocks}
    if output is not None and with_photons:
        if Path(output).suffix.lower() == ".gpkg":
            layers[LAYER_PHOTONS] = photon_layer(tracks, labels)
        else:
            warnings.warn("--photons needs a .gpkg output; photon layer not written",
                          CanopyBlocksWarning, stacklevel=2)
    prog.update(0.9, "writing")  # the last point where cancelling stops the run
    new = [Path(p) for p in (output, profile) if p is not None and not Path(p).exists()]
    try:
        if output is not None:
            result.outputs.append(write_layers(layers, output))
        if profile is not None:
            from .outputs.profile_plot import plot_profile

            t = tracks[0]
            result.outputs.append(plot_profile(t, blocks, profile, labels=labels.get(t.track)))
    except BaseException:  # e.g. Ctrl-C while plotting: no half set of outputs
        for p in new:
            p.unlink(missing_ok=True)
        raise
    prog.report(1.0, "done")  # outputs written: too late to cancel
    return result
