"""GEDI L2A-style processing of a batch of waveforms into the footprint table (DESIGN 4.3-4.6).

Steps, each vectorised over the shots of a chunk (one module each):

1. one pass over the raw samples (:mod:`.scan`): unusable shots, the search window
   (samples above ``mean + 4 sd``, L2A's ``search_start`` / ``search_end``) and the part
   of it where a signal top or bottom can lie at all;
2. linear interpolation to the 0.25-sample grid and Gaussian smoothing, once for the
   signal locations (6.5 samples) and once for the mode search (:mod:`.smoothing`);
3. signal top / bottom from the front / back thresholds (:mod:`.extent`);
4. the signal alone, bottom first (:mod:`.profile`): modes, ground = lowest mode
   (:mod:`.modes`);
5. cumulative energy -> RH0..RH100 (:mod:`.rh`), cover and penetration (:mod:`.cover`);
6. flags, and GEDI's terrain-outlier criteria along the beam (:mod:`.gedi_outliers`).

Only the part of each shot's search window where a signal can lie (plus the kernels'
reach) is smoothed -- results there are those of smoothing the whole waveform -- and
shots are processed in chunks of similar width, so a few tall or long waveforms do not
widen every row. The only Python loop is over chunks of ``CHUNK_SHOTS`` shots.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import pandas as pd
import pyproj

from ..errors import CanopyBlocksWarning, DependencyError, InputError
from ..geo import require_metric_crs, to_metric
from ..progress import Progress, as_progress
from ..schema import FOOTPRINT_COLUMNS
from .batch import WaveformBatch
from .cover import cover_and_penetration
from .details import ShotDetails
from .extent import signal_extent
from .gedi_outliers import gedi_outliers
from .modes import energetic_modes, lowest_mode, mode_mask
from .profile import bottom_first
from .rh import energy_positions, signal_energy, truncate_cm
from .scan import Scan, scan_shots
from .settings import WaveformParams
from .smoothing import smooth_subsampled
from .waveform_checks import check_waveform_args

if TYPE_CHECKING:
    import geopandas as gpd
    from geopandas.array import GeometryArray

__all__ = ["process_waveforms", "shot_details", "RH_TABLE", "FLAG_CODES", "CHUNK_SHOTS",
           "UnusableWaveformWarning"]

log = logging.getLogger(__name__)

#: RH percentiles of the footprint table (all of 0..100 with ``all_rh``).
RH_TABLE: tuple[int, ...] = (25, 50, 75, 90, 95, 98, 100)
ALL_RH: tuple[int, ...] = tuple(range(101))
#: Footprint flag codes. One flag per footprint, by precedence: stale, degraded,
#: no_signal, too_many_modes, terrain_outlier, else ok.
FLAG_CODES: tuple[str, ...] = ("ok", "stale", "degraded", "no_signal", "too_many_modes",
                               "terrain_outlier")
_OK, _STALE, _DEGRADED, _NO_SIGNAL, _TOO_MANY, _TERRAIN = range(6)
#: Shots per chunk: bounds memory (about 30 MB per 1,000-sample shot-chunk array).
CHUNK_SHOTS = 512


class UnusableWaveformWarning(CanopyBlocksWarning):
    """Some shots had unusable noise statistics (non-finite, sd <= 0) or non-finite
    samples; they are flagged ``no_signal``."""


@dataclass
class _Chunk:
    """Per-shot results of one chunk (positions in sub-samples, -1 where none)."""

    found: npt.NDArray[np.bool_]
    top: npt.NDArray[np.int64]
    bottom: npt.NDArray[np.int64]
    ground: npt.NDArray[np.int64]
    n_modes: npt.NDArray[np.int64]
    rh_pos: npt.NDArray[np.int64]
    cover: npt.NDArray[np.float64]
    penetration: npt.NDArray[np.float64]


@dataclass
class _Intermediate:
    """Modes of one chunk (for :func:`shot_details`)."""

    modes: npt.NDArray[np.bool_]   # bottom first
    offset: npt.NDArray[np.int64]  # sub-sample of the whole waveform at column 0


def _reach(params: WaveformParams) -> int:
    """Samples of raw waveform the smoothing kernels reach on either side."""
    halves = [params.kernel_shape(params.location_smoothing)[1],
              params.kernel_shape(params.group.mode_smoothing)[1]]
    f = params.subsamples
    return -(-(max(halves) + f) // f) + 1


def _scan(batch: WaveformBatch, params: WaveformParams) -> Scan:
    """Usability, search window and signal bounds of every shot (:mod:`.scan`)."""
    group = params.group
    return scan_shots(batch, params.preprocessor_threshold, params.search_size,
                      min(group.front_threshold, group.back_threshold),
                      group.back_threshold, _reach(params))


def _cropped_residuals(batch: WaveformBatch, rows: npt.NDArray[np.intp],
                       first: npt.NDArray[np.int64], width: int) -> npt.NDArray[np.float64]:
    """Residual waveforms of ``rows`` from sample ``first`` on, ``width`` samples, 0 outside."""
    wf = batch.waveforms
    m = wf.shape[1]
    idx = first[:, None] + np.arange(width)[None, :]
    count = batch.n_samples[rows]
    clipped = (first < 0) | (first + width > count)
    if m == 0:
        return np.zeros((len(rows), width))
    cols = np.clip(idx, 0, m - 1) if clipped.any() else idx
    if wf.flags.c_contiguous:
        values = wf.ravel().take(cols + (rows.astype(np.int64) * m)[:, None])
    else:
        values = wf[rows[:, None], cols]
    resid = np.subtract(values, np.asarray(batch.noise_mean)[rows][:, None], dtype=np.float64)
    if clipped.any():
        sub = np.nonzero(clipped)[0]
        inside = (idx[sub] >= 0) & (idx[sub] < count[sub][:, None])
        resid[sub] = np.where(inside, resid[sub], 0.0)
    return resid


def _process_chunk(batch: WaveformBatch, rows: npt.NDArray[np.intp], window_start:
                   npt.NDArray[np.int64], window_end: npt.NDArray[np.int64],
                   params: WaveformParams, percents: tuple[int, ...], keep: bool = False
                   ) -> tuple[_Chunk, _Intermediate | None]:
    """Process the shots ``rows`` on their cropped windows.

    ``window_start`` .. ``window_end`` (samples, inclusive) is where the signal top and
    bottom are searched: the search window, or the part of it where a signal can lie
    (:mod:`.scan`). Only that plus the kernels' reach is smoothed: the results inside
    are the same as smoothing the whole waveform. The modes, energies and RH then work
    on the signal alone (top - 1 .. bottom + 1). Positions returned are sub-sample
    indices of the whole waveform.
    """
    f = params.subsamples
    group = params.group
    reach = _reach(params)
    first = window_start - reach
    width = int((window_end - window_start).max(initial=0)) + 1 + 2 * reach
    resid = _cropped_residuals(batch, rows, first, width)
    sd = batch.noise_sd[rows].astype(np.float64)
    loc_kernel = params.kernel_shape(params.location_smoothing)
    mode_kernel = params.kernel_shape(group.mode_smoothing)
    if loc_kernel == mode_kernel:
        located = smooth_subsampled(resid, f, [loc_kernel])[0]
        searched = located
    else:
        located, searched = smooth_subsampled(resid, f, [loc_kernel, mode_kernel])

    front = group.front_threshold * sd
    back = group.back_threshold * sd
    lo = np.full(len(rows), reach * f, dtype=np.int64)
    hi = (window_end - first) * f
    top, bottom, found = signal_extent(located, lo, hi, front, back)
    # the signal alone, bottom first: column j is sub-sample bottom + 1 - j
    span = np.where(found, bottom - top, -1)
    profile = bottom_first(searched, np.where(found, bottom, 0), int(span.max(initial=0)) + 3)
    modes = mode_mask(profile, span, back)
    ground_col, n_modes = lowest_mode(modes)
    from_bottom, total = signal_energy(profile, span)
    if group.ground_min_energy > 0:
        ground_col, _ = lowest_mode(energetic_modes(modes, from_bottom, total,
                                                    group.ground_min_energy))
    found &= (ground_col >= 0) & (total > 0)
    total = np.where(found, total, 0.0)
    shift = first * f
    bottom = bottom + shift
    ground = np.where(found, bottom + 1 - ground_col, -1)
    rh_pos = energy_positions(from_bottom, total, bottom, span, percents)
    denom = np.maximum(batch.n_samples[rows] - 1, 1).astype(np.float64)
    spacing = np.abs(batch.elev_bin0[rows] - batch.elev_lastbin[rows]) / denom / f
    cover, penetration = cover_and_penetration(
        from_bottom, total, ground, bottom, span, spacing, params.rho_ratio,
        params.penetration_height)
    chunk = _Chunk(found, np.where(found, top + shift, -1), np.where(found, bottom, -1),
                   ground, n_modes, np.where(found[:, None], rh_pos, -1), cover, penetration)
    inter = _Intermediate(modes, bottom + 1) if keep else None
    return chunk, inter


def _chunks(widths: npt.NDArray[np.int64], size: int) -> list[npt.NDArray[np.intp]]:
    order = np.argsort(widths, kind="stable")
    return [order[i:i + size] for i in range(0, len(order), size)]


def _shot_numbers(batch: WaveformBatch) -> npt.NDArray[np.int64]:
    sn = np.asarray(batch.shot_number)
    if sn.dtype.kind == "u" and len(sn) and sn.max() > np.iinfo(np.int64).max:
        raise InputError(f"{batch.source or 'batch'}: shot_number {int(sn.max())} does not fit "
                         "in int64; the footprint table stores shot numbers as int64")
    return sn.astype(np.int64)


def _ground_gauss(batch: WaveformBatch, progress: Progress) -> npt.NDArray[np.float64]:
    try:
        from .decompose import decompose_waveforms  # noqa: PLC0415 (optional step)
    except ImportError as exc:
        raise DependencyError(
            "decompose=True needs canopyblocks.waveforms.decompose (Gaussian "
            "decomposition), which this installation lacks; run without decomposition "
            "or update canopyblocks") from exc
    result = decompose_waveforms(batch, progress=progress)
    if isinstance(result, pd.DataFrame):
        values = result["ground_gauss"].to_numpy()
    elif hasattr(result, "ground_gauss"):
        values = np.asarray(result.ground_gauss)
    else:
        values = np.asarray(result)
    values = np.asarray(values, dtype=np.float64)
    if values.shape != (len(batch),):
        raise InputError(f"decompose_waveforms returned {values.shape} values for "
                         f"{len(batch)} shots")
    return values


def process_waveforms(batch: WaveformBatch, params: WaveformParams | None = None, *,
                      crs: Any = None, progress: Progress | None = None) -> gpd.GeoDataFrame:
    """Ground, top, RH, cover and flags of every shot of a batch (one beam).

    Parameters
    ----------
    batch : WaveformBatch
        Waveforms of one beam (GEDI L1B or the simulator), with noise statistics.
    params : WaveformParams, optional
        Setting group and options (default: a1).
    crs : CRS-like, optional
        Metric projected CRS of the geometry (EPSG code, ``"EPSG:32618"``, WKT or
        ``pyproj.CRS``). Default: the WGS84 UTM zone of the batch's footprints (the
        zone of their centre), as the photon readers and ``canopyblocks waveforms``.
    progress : Progress, optional
        Progress and cancellation.

    Returns
    -------
    geopandas.GeoDataFrame
        One row per shot in the batch's order, the columns of
        :data:`canopyblocks.schema.FOOTPRINT_COLUMNS`: ``lon``/``lat`` (degrees WGS84) of
        the footprint at the ground elevation (at the last bin where there is no
        ground), ``ground``/``top`` (m, the batch's vertical datum), ``rh*`` (m above
        ground, truncated to cm as L2A), ``cover``, ``penetration`` (0..1),
        ``n_modes``, ``setting``, ``flag``; ``rh0`` .. ``rh100`` with
        ``params.all_rh``; ``ground_gauss`` (m) with ``params.decompose``. Values of
        ``no_signal`` shots are NaN; ``stale``/``degraded`` shots keep their values.
        ``geometry``: PointZ at ``lon``/``lat`` projected to ``crs`` (x, y in metres)
        with z = ``ground`` (NaN without a ground), as the ``footprints`` layer of
        ``canopyblocks waveforms``; an empty point where ``lon``/``lat`` is not finite.
        The GeoDataFrame's CRS is ``crs`` (None only when no shot has a position and
        no ``crs`` is given).

    Raises
    ------
    InputError, CRSError
        A bad batch or parameters; a ``crs`` that is not metric and projected.
    """
    import geopandas as gpd  # noqa: PLC0415 (workers read tables without geometry)

    target = require_metric_crs(crs, "crs") if crs is not None else None
    columns = _footprint_columns(batch, params, progress)
    # one frame built from the columns (not a DataFrame wrapped again: half the cost)
    columns["geometry"] = _points(columns, target)
    return gpd.GeoDataFrame(columns, geometry="geometry")


def _points(columns: dict[str, npt.NDArray[Any]], crs: pyproj.CRS | None) -> GeometryArray:
    """PointZ at ``lon``/``lat`` in ``crs`` (default the UTM zone of the points),
    z = ``ground``; empty points where the position is not finite."""
    import shapely  # noqa: PLC0415
    from geopandas.array import from_shapely  # noqa: PLC0415

    lon, lat = columns["lon"], columns["lat"]
    fin = np.isfinite(lon) & np.isfinite(lat)
    geom = shapely.empty(len(lon), geom_type=shapely.GeometryType.POINT)
    if fin.any():
        x, y, crs = to_metric(lon[fin], lat[fin], crs)
        geom[fin] = shapely.points(x, y, columns["ground"][fin])
    return from_shapely(geom, crs=crs)


def _footprint_table(batch: WaveformBatch, params: WaveformParams | None = None, *,
                     progress: Progress | None = None) -> pd.DataFrame:
    """:func:`process_waveforms`' columns without the geometry (for readers that add
    their own over a whole beam: :mod:`canopyblocks.workflows.waveforms`)."""
    return pd.DataFrame(_footprint_columns(batch, params, progress))


def _footprint_columns(batch: WaveformBatch, params: WaveformParams | None,
                       progress: Progress | None) -> dict[str, npt.NDArray[Any]]:
    """The footprint table's columns, in order (see :func:`process_waveforms`)."""
    check_waveform_args(batch, params, "process_waveforms")
    params = params if params is not None else WaveformParams()
    prog = as_progress(progress)
    n = len(batch)
    f = params.subsamples
    percents = ALL_RH if params.all_rh else RH_TABLE
    found = np.zeros(n, dtype=bool)
    top = np.full(n, -1, dtype=np.int64)
    ground = np.full(n, -1, dtype=np.int64)
    n_modes = np.zeros(n, dtype=np.int64)
    rh_pos = np.full((n, len(percents)), -1, dtype=np.int64)
    cover = np.full(n, np.nan)
    penetration = np.full(n, np.nan)
    span = 0.8 if params.decompose else 1.0
    scan = _scan(batch, params)
    unusable = scan.unusable
    if unusable.any():
        warnings.warn(
            f"{batch.source or batch.beam}: {int(unusable.sum())} of {n} shots of "
            f"{batch.beam} have non-finite or non-positive noise statistics or non-finite "
            "samples; they are flagged no_signal", UnusableWaveformWarning, stacklevel=2)
    w_start, w_end = scan.bound_start, scan.bound_end
    candidates = np.nonzero(scan.may_have_signal)[0]
    chunks = [candidates[c] for c in _chunks((w_end - w_start)[candidates], CHUNK_SHOTS)]
    done = 0
    for rows in chunks:
        prog.update(span * done / max(n, 1), f"waveforms {batch.beam}: {done}/{n} shots")
        res, _ = _process_chunk(batch, rows, w_start[rows], w_end[rows], params, percents)
        found[rows] = res.found
        top[rows] = res.top
        ground[rows] = res.ground
        n_modes[rows] = res.n_modes
        rh_pos[rows] = res.rh_pos
        cover[rows] = res.cover
        penetration[rows] = res.penetration
        done += len(rows)

    g_samples = np.where(found, ground / f, np.maximum(batch.n_samples - 1, 0))
    ground_elev = np.where(found, batch.elevation(g_samples), np.nan)
    top_elev = np.where(found, batch.elevation(np.where(found, top / f, 0.0)), np.nan)
    lon, lat = batch.lonlat(g_samples)
    rh_elev = batch.elevation(np.where(rh_pos >= 0, rh_pos / f, 0.0).T).T
    rh = np.where(found[:, None], truncate_cm(rh_elev - ground_elev[:, None]), np.nan)

    code = np.full(n, _OK, dtype=np.int8)
    code[~found] = _NO_SIGNAL
    code[found & (n_modes > params.max_modes)] = _TOO_MANY
    code[batch.degraded] = _DEGRADED
    code[batch.stale] = _STALE
    if params.terrain_filter and n:
        order = np.argsort(batch.time, kind="stable")
        usable = (code == _OK) | (code == _TOO_MANY)
        z = np.where(usable, ground_elev, np.nan)[order]
        height = np.where(usable, top_elev - ground_elev, np.nan)[order]
        dem = batch.extra.get("digital_elevation_model")
        outlier = np.zeros(n, dtype=bool)
        outlier[order] = gedi_outliers(z, height, lon[order], lat[order],
                                       dem=None if dem is None else np.asarray(dem)[order])
        code[outlier & (code == _OK)] = _TERRAIN

    table: dict[str, object] = {
        "beam": np.full(n, batch.beam, dtype=object),
        "shot_number": _shot_numbers(batch),
        "time": np.asarray(batch.time, dtype=np.float64),
        "lon": lon, "lat": lat,
        "ground": ground_elev, "top": top_elev,
    }
    rh_names = [f"rh{p}" for p in percents]
    for j, name in enumerate(rh_names):
        table[name] = rh[:, j]
    table["cover"] = cover
    table["penetration"] = penetration
    table["n_modes"] = n_modes
    table["setting"] = np.full(n, params.setting, dtype=object)
    if params.decompose:
        table["ground_gauss"] = _ground_gauss(batch, prog.sub(span, 1.0))
    table["flag"] = np.asarray(FLAG_CODES, dtype=object)[code]
    log.debug("%s: %d shots, setting %s, %d ok", batch.beam, n, params.setting,
              int((code == _OK).sum()))
    columns = [c for c in FOOTPRINT_COLUMNS if not c.startswith("rh") and c != "flag"]
    first_rh = columns.index("cover")
    columns[first_rh:first_rh] = rh_names
    if params.decompose:
        columns.append("ground_gauss")
    columns.append("flag")
    prog.update(1.0, f"waveforms {batch.beam}: {n} shots")
    return {c: np.asarray(table[c]) for c in columns}


def shot_details(batch: WaveformBatch, index: int, params: WaveformParams | None = None
                 ) -> ShotDetails:
    """Everything a waveform plot draws for shot ``index`` of ``batch``.

    ``smoothed`` is the mode-search smoothing (the one the modes, RH and cover use) of
    the whole waveform, in counts, on the sub-sample grid. The flag ignores the terrain
    filter (which needs the neighbours).
    """
    params = params if params is not None else WaveformParams()
    n = len(batch)
    if not (isinstance(index, (int, np.integer)) and -n <= index < n):
        raise InputError(f"shot index {index!r} is outside the batch of {n} shots")
    i = int(index) % n
    f = params.subsamples
    rows = np.array([i], dtype=np.intp)
    one = batch.subset(rows)
    scan = _scan(one, params)
    has_window = scan.may_have_signal
    w_start, w_end = scan.bound_start, scan.bound_end
    res, inter = _process_chunk(batch, rows, w_start, w_end, params, ALL_RH, keep=True)
    if inter is None:  # pragma: no cover - keep=True always returns them
        raise RuntimeError("internal: intermediates missing")
    res.found &= has_window
    m = int(batch.n_samples[i])
    mean = float(batch.noise_mean[i])
    sd = float(batch.noise_sd[i])
    raw_elev = one.elevation(np.arange(m)[None, :].astype(np.float64).T).T[0]
    k = f * (m - 1) + 1 if m else 0
    sub_elev = one.elevation((np.arange(k) / f)[None, :].T).T[0]
    found = bool(res.found[0])
    mode_idx = inter.offset[0] - np.nonzero(inter.modes[0])[0][::-1]

    def elev(pos: float) -> float:
        return float(one.elevation(np.array([pos / f]))[0])

    ground = elev(res.ground[0]) if found else float("nan")
    rh: dict[int, float] = {}
    if found:
        rh_elev = one.elevation((res.rh_pos[0] / f)[None, :].T).T[0]
        rh = {p: float(v) for p, v in zip(ALL_RH, truncate_cm(rh_elev - ground))}
    if batch.stale[i]:
        flag = "stale"
    elif batch.degraded[i]:
        flag = "degraded"
    elif not found:
        flag = "no_signal"
    elif res.n_modes[0] > params.max_modes:
        flag = "too_many_modes"
    else:
        flag = "ok"
    group = params.group
    return ShotDetails(
        beam=batch.beam,
        shot_number=int(batch.shot_number[i]),
        setting=params.setting,
        elevation=raw_elev,
        raw=np.asarray(batch.waveforms[i, :m], dtype=np.float64),
        smoothed_elevation=sub_elev,
        smoothed=smooth_subsampled(
            _cropped_residuals(batch, rows, np.zeros(1, dtype=np.int64), max(m, 1)), f,
            [params.kernel_shape(group.mode_smoothing)])[0][0, :k] + mean,
        noise_mean=mean,
        noise_sd=sd,
        front_threshold=mean + group.front_threshold * sd,
        back_threshold=mean + group.back_threshold * sd,
        top=elev(res.top[0]) if found else float("nan"),
        bottom=elev(res.bottom[0]) if found else float("nan"),
        ground=ground,
        modes=(one.elevation((mode_idx / f)[:, None]).ravel() if found
               else np.array([], dtype=np.float64)),
        rh=rh,
        flag=flag,
    )
