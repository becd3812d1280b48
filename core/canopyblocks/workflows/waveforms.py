"""GEDI L1B file -> footprints layer: the one core call behind ``canopyblocks waveforms``,
the QGIS algorithm and ``run`` with GEDI input.

Reads the L1B beam by beam in chunks of shots (:func:`~canopyblocks.readers.gedi.iter_gedi_l1b`),
processes each chunk (:func:`~canopyblocks.waveforms.process.process_waveforms`), applies
the seed-003 terrain filter along each whole beam, and returns one GeoDataFrame with the
DESIGN 5 footprint columns and PointZ geometry (x, y, ground elevation) in a metric CRS
(the UTM zone of the data unless given). Optionally joins the official L2A (and L2B)
values of the same shots for comparison, and draws waveform plots of chosen shots.
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd

from ..errors import CanopyBlocksWarning, InputError, NoUsableDataError
from ..progress import Progress, as_progress
from ..readers.gedi import gedi_vertical_datum
from ..schema import LAYER_FOOTPRINTS
from .waveforms_beams import _plot, flag_invalid_shots

__all__ = ["FootprintRunSummary", "footprints_from_l1b", "footprints_to_file",
           "compare_with_l2a", "flag_invalid_shots", "GEDI_VERTICAL_DATUM"]

log = logging.getLogger(__name__)

#: GEDI elevations are heights above the WGS84 ellipsoid.
GEDI_VERTICAL_DATUM = "EPSG:4979"


@dataclass
class FootprintRunSummary:
    """What :func:`footprints_to_file` produced."""

    output: Path
    footprints: gpd.GeoDataFrame
    flags: dict[str, int]
    comparison: pd.DataFrame | None = None
    plots: list[Path] = field(default_factory=list)


def _refuse_if_all_invalid(path: Any, table: pd.DataFrame, problems: int) -> None:
    from ..errors import FileFormatError
    from ..readers.gedi_geometry import INVALID_SHOT, PROBLEM_NAMES

    if len(table) and (table["flag"].to_numpy(object) == INVALID_SHOT).all():
        kinds = [name for bit, name in PROBLEM_NAMES.items() if problems & bit] or \
            ["heights or position not finite"]
        raise FileFormatError(f"{path}: every shot read has impossible L1B values "
                              f"({', '.join(kinds)}); the file is damaged or not a GEDI "
                              "L1B product")


def _terrain_filter(table: pd.DataFrame) -> pd.DataFrame:
    """GEDI terrain outliers along one whole beam (time order), flagged."""
    from ..waveforms.gedi_outliers import gedi_outliers

    if table.empty:
        return table
    order = np.argsort(table["time"].to_numpy(float), kind="stable")
    flag = table["flag"].to_numpy(object)
    usable = (flag == "ok") | (flag == "too_many_modes")
    ground = table["ground"].to_numpy(float)
    height = table["top"].to_numpy(float) - ground
    z = np.where(usable, ground, np.nan)[order]
    h = np.where(usable, height, np.nan)[order]
    outlier = np.zeros(len(table), dtype=bool)
    lon, lat = table["lon"].to_numpy(float)[order], table["lat"].to_numpy(float)[order]
    outlier[order] = gedi_outliers(z, h, lon, lat)
    flag = flag.copy()
    flag[outlier & (flag == "ok")] = "terrain_outlier"
    return table.assign(flag=flag)


def footprints_from_l1b(
    path: str | os.PathLike[str],
    *,
    beams: Sequence[str] | str | None = None,
    params: Any = None,
    bbox: tuple[float, float, float, float] | None = None,
    crs: Any = None,
    quality: bool = False,
    chunk_shots: int = 4096,
    plot_shots: Sequence[int] | None = None,
    plots_dir: str | os.PathLike[str] | None = None,
    workers: int | None = 1,
    progress: Progress | None = None,
) -> tuple[gpd.GeoDataFrame, list[Path]]:
    """Footprints (ground, top, RH, cover, flags) of every shot of a GEDI L1B file.

    Parameters
    ----------
    path : path
        GEDI L1B granule or subset.
    beams : str or sequence, optional
        Default every beam.
    params : WaveformParams, optional
        Setting group (default a1), ``all_rh``, ``decompose``, ...; its terrain filter is
        applied per whole beam.
    bbox : (lon_min, lat_min, lon_max, lat_max), optional
        Degrees WGS84.
    crs : CRS-like, optional
        Metric CRS of the geometry (default the UTM zone of the footprints).
    quality : bool
        Drop stale/degraded shots instead of flagging them.
    plot_shots, plots_dir
        Waveform plots (PNG) of these shot numbers (default the first few ``ok`` shots of
        each beam) into ``plots_dir``.
    workers : int or None
        Processes reading and processing the beams in parallel
        (:mod:`canopyblocks.workflows.waveforms_beams`; the same table as one process); None: the
        machine's cores.

    Returns
    -------
    (GeoDataFrame, list of Path)
        The footprints layer (``attrs["vertical_datum"]`` EPSG:4979) and plots written.

    Raises
    ------
    FileFormatError, InputError, NoUsableDataError
    """
    from ..geo import as_crs, to_metric
    from ..readers.gedi import iter_gedi_l1b
    from ..waveforms.process import _footprint_table, shot_details
    from ..waveforms.settings import WaveformParams

    base = params if params is not None else WaveformParams()
    if not isinstance(base, WaveformParams):
        raise InputError(f"params must be a WaveformParams; got {type(base).__name__}")
    chunk_params = replace(base, terrain_filter=False)
    prog = as_progress(progress)
    wanted = None if plot_shots is None else {int(s) for s in plot_shots}
    per_beam: dict[str, list[pd.DataFrame]] = {}
    plots: list[Path] = []
    plotted: dict[str, int] = {}
    problems = 0
    reading = prog.sub(0.0, 0.9)
    from ..readers.remote import is_file_object
    from .waveforms_beams import BeamJob, beams_for_workers, beams_in_workers
    # (an open file object stays in this process; a URL is read by each worker itself)
    in_workers = [] if is_file_object(path) else beams_for_workers(path, beams, workers)
    if in_workers:
        jobs = [BeamJob(str(path), b, chunk_params, base, bbox, quality, chunk_shots,
                        None if wanted is None else tuple(sorted(wanted)),
                        None if plots_dir is None else str(plots_dir)) for b in in_workers]
        per_beam, problems, plots = beams_in_workers(jobs, workers, progress=reading,
                                                     check=reading.check)
    for batch in ([] if in_workers else
                  iter_gedi_l1b(path, beams, bbox=bbox, quality=quality,
                                chunk_shots=chunk_shots, progress=reading)):
        table = flag_invalid_shots(_footprint_table(batch, chunk_params), batch)
        problems |= int(np.bitwise_or.reduce(batch.extra.get("invalid_shot", [0]), initial=0))
        per_beam.setdefault(batch.beam, []).append(table)
        if plots_dir is not None:
            plots += _plot(batch, table, wanted, plotted, Path(plots_dir), base, shot_details)
        reading.check()
    if not per_beam:
        raise NoUsableDataError(f"{path}: no shot to process"
                                + (" inside the bbox" if bbox is not None else ""))
    frames = []
    for _beam, parts in per_beam.items():
        t = pd.concat(parts, ignore_index=True)
        frames.append(_terrain_filter(t) if base.terrain_filter else t)
    table = pd.concat(frames, ignore_index=True)
    _refuse_if_all_invalid(path, table, problems)
    prog.update(0.92, "footprint geometry")
    lon, lat = table["lon"].to_numpy(float), table["lat"].to_numpy(float)
    fin = np.isfinite(lon) & np.isfinite(lat)
    if not fin.any():
        raise NoUsableDataError(f"{path}: no footprint has a finite position")
    target = as_crs(crs, "crs") if crs is not None else None
    x = np.full(len(table), np.nan)
    y = np.full(len(table), np.nan)
    xf, yf, out_crs = to_metric(lon[fin], lat[fin], target)
    x[fin], y[fin] = xf, yf
    z = table["ground"].to_numpy(float)
    geom = gpd.points_from_xy(x, y, np.where(np.isfinite(z), z, np.nan), crs=out_crs)
    gdf = gpd.GeoDataFrame(table, geometry=geom, crs=out_crs)
    gdf.insert(len(gdf.columns) - 1, "time_utc", _utc(path, table["time"].to_numpy(float)))
    gdf.attrs["vertical_datum"] = gedi_vertical_datum(path)  # EPSG:4979 unless simulated
    prog.update(1.0, f"{len(gdf)} footprints")
    return gdf, plots


def _utc(path: str | os.PathLike[str], delta_time: np.ndarray) -> np.ndarray:
    """UTC of the shots (``time_utc``, beside ``time`` = delta_time), to the millisecond
    (a GeoPackage's precision: finer times were written as '08:21:60' by GDAL); NaT for a
    simulated file, whose clock starts at its first shot."""
    from ..readers.utc_time import file_counts_from_sdp_epoch, utc_from_delta_time

    if not file_counts_from_sdp_epoch(path):
        return np.full(len(delta_time), np.datetime64("NaT"), dtype="datetime64[ns]")
    return utc_from_delta_time(delta_time).astype("datetime64[ms]").astype("datetime64[ns]")


class UnmatchedShotsWarning(CanopyBlocksWarning):
    """Some footprints have no shot of the same number in the L2A/L2B file compared with."""


def _check_same_shots(ours: np.ndarray, theirs: np.ndarray, path: Any, product: str) -> None:
    """Refuse an L2A/L2B file that holds none of the footprints' shots; warn when it holds
    only some."""
    found = np.isin(ours, theirs)
    n = int(found.sum())
    if ours.size and n == 0:
        raise NoUsableDataError(
            f"{path}: none of the {ours.size} footprints' shot numbers is in this GEDI "
            f"{product} file (its {theirs.size} shots are others: another orbit, track or "
            f"subset); give the {product} granule of the same orbit as the L1B")
    if n < ours.size:
        warnings.warn(f"{path}: {ours.size - n} of {ours.size} footprints have no shot in "
                      f"this GEDI {product} file; they are left out of the comparison",
                      UnmatchedShotsWarning, stacklevel=3)


def compare_with_l2a(footprints: pd.DataFrame, l2a: str | os.PathLike[str] | None = None,
                     l2b: str | os.PathLike[str] | None = None, *,
                     setting: str = "a1") -> tuple[pd.DataFrame, pd.DataFrame]:
    """Footprints with the official L2A (and L2B) values of the same shots, and the
    agreement statistics.

    Adds ``l2a_ground``, ``l2a_rh50``, ``l2a_rh98``, ``l2a_top``, ``l2a_valid`` (L2A
    ``quality_flag`` 1, ``rx_algrunflag`` 1, not stale/degraded) and ``d_ground``,
    ``d_rh50``, ``d_rh98``, ``d_top`` (ours minus L2A, m); with ``l2b`` ``l2b_cover`` and
    ``d_cover``. Joined on ``shot_number`` (int64, exact).

    Returns
    -------
    (DataFrame, DataFrame)
        The joined table, and per beam and metric ``n``, ``left_out`` (the shots left
        out and why: not in the file, another algorithm selected, L2A quality 0, flagged
        here), ``bias``, ``rmse``, ``within_0.10`` (share of valid ok shots within 0.10 m).

    An L2A file holding only the selected algorithm's values (``elev_lowestmode``, ``rh``;
    what subsetting services keep) is compared on the shots whose selected algorithm
    (L2B ``selected_l2a_algorithm``, else L2A ``selected_algorithm``) is ``setting``.
    """
    from ..readers.gedi_l2 import l2a_has_setting, read_gedi_l2a, read_gedi_l2b

    out = footprints.copy()
    metrics = ["ground", "rh50", "rh98", "top"]
    sn = out["shot_number"].to_numpy(np.int64)
    cov = None
    if l2b is not None:
        cov = read_gedi_l2b(l2b).drop_duplicates("shot_number").set_index("shot_number")
        _check_same_shots(sn, cov.index.to_numpy(np.int64), l2b, "L2B")
    reasons: dict[str, np.ndarray] = {}
    if l2a is not None:
        every = l2a_has_setting(l2a, setting)
        ref = read_gedi_l2a(l2a, setting=setting if every else None)
        ref = ref.drop_duplicates("shot_number").set_index("shot_number")
        _check_same_shots(sn, ref.index.to_numpy(np.int64), l2a, "L2A")
        for m in metrics:
            out[f"l2a_{m}"] = ref[m].reindex(sn).to_numpy(float)
            out[f"d_{m}"] = out[m].to_numpy(float) - out[f"l2a_{m}"].to_numpy(float)
        there = np.isin(sn, ref.index.to_numpy(np.int64))
        reasons["not in the L2A file"] = ~there
        quality = ((ref["quality_flag"].reindex(sn).to_numpy() == 1)
                   & (ref["algrunflag"].reindex(sn).to_numpy() == 1))
        if not every:  # only the selected algorithm's values: those of our setting count
            algo = _selected_algorithm(ref, cov, sn, l2a, setting)
            reasons[f"L2A selected another algorithm than {setting}"] = \
                there & (algo != int(setting[1:]))
        reasons["L2A quality_flag 0"] = there & ~quality
    flag = out["flag"].to_numpy(object)
    for name in sorted(set(flag.tolist()) - {"ok"}):
        reasons[f"flagged {name} here"] = flag == name
    if l2a is not None:
        out["l2a_valid"] = ~np.logical_or.reduce([np.zeros(len(out), bool),
                                                  *reasons.values()])
    if cov is not None:
        out["l2b_cover"] = cov["cover"].reindex(out["shot_number"].to_numpy(np.int64)) \
            .to_numpy(float)
        out["d_cover"] = out["cover"].to_numpy(float) - out["l2b_cover"].to_numpy(float)
        metrics.append("cover")
    rows = []
    if "l2a_valid" in out or "d_cover" in out:
        use = out["l2a_valid"].to_numpy(bool) if "l2a_valid" in out else \
            (out["flag"].to_numpy(object) == "ok")
        for beam in ["all", *sorted(out["beam"].unique())]:
            sel = use & ((out["beam"] == beam).to_numpy() if beam != "all" else True)
            for m in metrics:
                if f"d_{m}" not in out:
                    continue
                d = out[f"d_{m}"].to_numpy(float)[sel]
                d = d[np.isfinite(d)]
                rows.append({"beam": beam, "metric": m,
                             "product": "L2B" if m == "cover" else "L2A", "n": int(d.size),
                             "left_out": _left_out(reasons, np.ones(len(out), bool)
                                                   if beam == "all" else
                                                   (out["beam"] == beam).to_numpy()),
                             "bias": float(d.mean()) if d.size else np.nan,
                             "rmse": float(np.sqrt(np.mean(d * d))) if d.size else np.nan,
                             "within_0.10": float(np.mean(np.abs(d) <= 0.10)) if d.size
                             else np.nan})
    return out, pd.DataFrame(rows)


def _selected_algorithm(ref: pd.DataFrame, l2b: pd.DataFrame | None, sn: np.ndarray,
                        path: Any, setting: str) -> np.ndarray:
    """Per footprint, the L2A setting group (1..6) whose values an L2A file holding only
    the selected algorithm's values gives: L2B's ``selected_l2a_algorithm``, else L2A's
    ``selected_algorithm``; -1 where neither says."""
    for table, col in ((l2b, "selected_l2a_algorithm"), (ref, "selected_algorithm")):
        if table is not None and col in table:
            a = pd.to_numeric(table[col].reindex(sn), errors="coerce").to_numpy(float)
            return np.where(np.isfinite(a), a, -1).astype(np.int64)
    raise InputError(f"{path}: this GEDI L2A file holds only the selected algorithm's values "
                     f"(no geolocation/elev_lowestmode_{setting}) and does not say which "
                     "algorithm each shot used (selected_algorithm); give the L2B file of the "
                     "same orbit (--l2b: selected_l2a_algorithm) or an L2A with every setting")


def _left_out(reasons: dict[str, np.ndarray], scope: np.ndarray) -> str:
    """Shots of ``scope`` left out of a comparison, counted per reason (a shot counts under
    its first reason): e.g. ``'flagged terrain_outlier here 16; L2A quality_flag 0 3'``."""
    taken = ~np.asarray(scope, bool)
    parts = []
    for name, r in reasons.items():
        k = int(np.count_nonzero(r & ~taken))
        taken = taken | r
        if k:
            parts.append(f"{name} {k}")
    return "; ".join(parts) if parts else "none"


def footprints_to_file(
    path: str | os.PathLike[str],
    output: str | os.PathLike[str],
    *,
    beams: Sequence[str] | str | None = None,
    params: Any = None,
    bbox: tuple[float, float, float, float] | None = None,
    crs: Any = None,
    quality: bool = False,
    l2a: str | os.PathLike[str] | None = None,
    l2b: str | os.PathLike[str] | None = None,
    plots_dir: str | os.PathLike[str] | None = None,
    plot_shots: Sequence[int] | None = None,
    workers: int | None = 1,
    options: Any = None,
    progress: Progress | None = None,
) -> FootprintRunSummary:
    """Process a GEDI L1B file, flash-lidar (ESFL) cubes or dual-wavelength pairs and
    write the footprints layer (atomically).

    ``output``: ``.gpkg`` (layer ``footprints``, plus ``l2a_comparison`` with ``l2a``, and
    for ESFL ``pixels``), ``.parquet`` or ``.csv``. See :func:`footprints_from_l1b` and
    :func:`compare_with_l2a`; ESFL and dual files (told apart by
    :func:`~canopyblocks.readers.flash_dual.waveform_product`) go through
    :mod:`~canopyblocks.workflows.waveforms_flash_dual` with ``options``
    (:class:`~canopyblocks.workflows.waveforms_flash_dual.SensorOptions`).
    """
    from ..atomic import check_writable, new_files_removed_on_failure
    from ..outputs.tables import check_output_path, write_layers
    from ..readers.flash_dual import flash_dual_sensor, refuse_unlabelled
    from ..readers.remote import is_url

    check_output_path(output)
    sensor = flash_dual_sensor(path)   # anything else goes to the GEDI reader, which says why
    if sensor is None:
        refuse_unlabelled(path)  # ESFL/dual data without its sensor attribute: named so
    if sensor is not None:
        product = "ESFL" if sensor == "esfl" else "dual"
        return _sensor_file(path, output, product, options=options, crs=crs,
                            gedi_only={"--beam": bool(beams), "--l2a": l2a is not None,
                                       "--l2b": l2b is not None, "--bbox": bbox is not None,
                                       "--quality": quality, "--plots": plots_dir is not None,
                                       "--shot": bool(plot_shots),
                                       "--setting/--decompose/--all-rh":
                                           _not_default_gedi(params)},
                            progress=progress)
    given = [] if options is None else options.given()
    if given and (is_url(path) or Path(path).is_file()):  # a missing file: the reader says so
        raise InputError(f"{path} is GEDI L1B: {', '.join(given)} "
                         f"{'applies' if len(given) == 1 else 'apply'} to flash-lidar (ESFL) "
                         "and dual-wavelength files only; leave "
                         f"{'it' if len(given) == 1 else 'them'} out")
    if plots_dir is not None:
        check_writable(plots_dir, folder=True)
        Path(plots_dir).mkdir(parents=True, exist_ok=True)
    prog = as_progress(progress)
    setting = params.setting if params is not None else "a1"
    ctx = new_files_removed_on_failure(plots_dir) if plots_dir is not None else None
    if ctx is not None:
        ctx.__enter__()
    try:
        gdf, plots = footprints_from_l1b(path, beams=beams, params=params, bbox=bbox,
                                         crs=crs, quality=quality, plot_shots=plot_shots,
                                         plots_dir=plots_dir, workers=workers,
                                         progress=prog.sub(0.0, 0.9))
        comparison = None
        if l2a is not None or l2b is not None:
            joined, comparison = compare_with_l2a(gdf, l2a, l2b, setting=setting)
            datum = gdf.attrs["vertical_datum"]
            gdf = gpd.GeoDataFrame(joined, geometry="geometry", crs=gdf.crs)
            gdf.attrs["vertical_datum"] = datum
        if plots:
            from ..outputs.waveform_plot import plots_index

            plots.append(plots_index(plots, Path(plots_dir) / "waveforms.html"))  # type: ignore[arg-type]
        prog.update(0.95, "writing")
        layers: dict[str, pd.DataFrame] = {LAYER_FOOTPRINTS: gdf}
        if comparison is not None and Path(output).suffix.lower() == ".gpkg":
            layers["l2a_comparison"] = comparison
        out = write_layers(layers, output)
    except BaseException as exc:
        if ctx is not None:
            ctx.__exit__(type(exc), exc, exc.__traceback__)
        raise
    if ctx is not None:
        ctx.__exit__(None, None, None)
    flags = {str(k): int(v) for k, v in gdf["flag"].value_counts().items()}
    prog.update(1.0, "done")
    return FootprintRunSummary(output=out, footprints=gdf, flags=flags,
                               comparison=comparison, plots=plots)


def _not_default_gedi(params: Any) -> bool:
    from ..waveforms.settings import WaveformParams

    return params is not None and params != WaveformParams()


def _sensor_file(path: Any, output: Any, product: str, *, options: Any, crs: Any,
                 gedi_only: dict[str, bool], progress: Progress | None
                 ) -> FootprintRunSummary:
    """An ESFL or dual file -> its layers (footprints; pixels for ESFL), written."""
    from ..outputs.tables import write_layers
    from .waveforms_flash_dual import LAYER_PIXELS, sensor_footprints

    given = [k for k, on in gedi_only.items() if on]
    if given:
        verb = "applies" if len(given) == 1 else "apply"
        raise InputError(f"{path} holds {product} data, not GEDI L1B: {', '.join(given)} "
                         f"{verb} to GEDI only; leave it out")
    prog = as_progress(progress)
    layers = sensor_footprints(path, product, options=options, crs=crs,
                               progress=prog.sub(0.0, 0.9))
    prog.update(0.95, "writing")
    if Path(output).suffix.lower() == ".gpkg" or LAYER_PIXELS not in layers:
        out = write_layers(layers, output)
    else:   # a table format holds one layer: the pixels go beside it
        from ..atomic import atomic_outputs

        with atomic_outputs():
            out = write_layers({LAYER_FOOTPRINTS: layers[LAYER_FOOTPRINTS]}, output)
            write_layers({LAYER_PIXELS: layers[LAYER_PIXELS]}, pixels_path(output))
    gdf = layers[LAYER_FOOTPRINTS]
    flags = {str(k): int(v) for k, v in gdf["flag"].value_counts().items()}
    prog.update(1.0, "done")
    return FootprintRunSummary(output=out, footprints=gdf, flags=flags)


def pixels_path(output: str | os.PathLike[str]) -> Path:
    """Where the ESFL pixels layer of a ``.parquet``/``.csv`` footprints table goes:
    ``<stem>_pixels<suffix>`` beside it."""
    p = Path(output)
    return p.with_name(f"{p.stem}_{'pixels'}{p.suffix}")
