"""One unit of batch work, run in any process: photons of one beam over its tiles ->
blocks -> the survey's corridor rasters (as ``run`` makes them) -> validation -> partition
files.

Pure function of its arguments (picklable, no shared state), so serial, process-pool
and Dask runs write identical partitions.
"""

from __future__ import annotations

import logging
import traceback
import warnings
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pyproj

from ...blocks.estimators import RECOMMENDED_PRESET
from ...errors import CanopyBlocksError, NoUsableDataError
from ...reference.sensor_width import sensor_width
from .units import Tile, Unit

if TYPE_CHECKING:
    from ...photons import PhotonTrack

__all__ = ["BatchConfig", "run_unit", "raster_paths", "corridor_reach"]

log = logging.getLogger(__name__)

RASTER_NAMES = ("dtm", "dsm_max", "dsm_p90")


@dataclass(frozen=True)
class BatchConfig:
    """What every unit computes (metres unless stated).

    Attributes
    ----------
    lengths : tuple of float
        Block lengths.
    width : float
        Corridor width for the validation; default the footprint of the granules'
        sensor (ICESat-2, 13 m: :mod:`canopyblocks.reference.sensor_width`).
    preset : str
        Block estimators (``atl08``, the default and recommended; ``paper``, the paper's
        method; ``icesat2``; ``mabel``).
    min_signal_conf : int or None
        ATL03 land confidence kept before the noise filter (the estimators that use it:
        not ``atl08``, which refuses it).
    offset : float or None
        Constant ``h_photon - H_reference`` (m); or ``geoid`` raster path.
    photon_vcrs, reference_vcrs : str or None
        Vertical datums (see ``reference.datum``).
    resolution : float
        Raster cell size.
    """

    lengths: tuple[float, ...] = (25.0,)
    width: float = field(default_factory=lambda: sensor_width("ICESat-2"))
    preset: str = RECOMMENDED_PRESET
    min_signal_conf: int | None = None
    offset: float | None = None
    geoid: str | None = None
    photon_vcrs: str = "EPSG:4979"
    reference_vcrs: str | None = None
    resolution: float = 2.0

    def __post_init__(self) -> None:
        from ...arguments import check_fields
        check_fields(self)
        from ...blocks import BlockParams
        from ...blocks.estimators import preset
        from ...errors import InputError

        BlockParams(lengths=self.lengths)  # validates the lengths
        est = preset(self.preset)  # an unknown name is refused here
        if self.min_signal_conf is not None and est.noise == "atl08":
            raise InputError(f"--min-signal-conf {self.min_signal_conf} is not used by the "
                             f"{self.preset} estimators (their classifier, like ATL08's, finds "
                             "the signal among all photons); drop it, or use --preset "
                             "icesat2 to filter on signal confidence")
        if not (np.isfinite(self.width) and self.width > 0):
            raise InputError(f"corridor width must be a positive number of metres, got "
                             f"{self.width!r}")
        if self.offset is not None and self.geoid is not None:
            raise InputError("give either a geoid raster or a constant offset, not both")


def raster_paths(raster_root: Path, unit: Unit) -> dict[str, Path]:
    """Where a unit's three corridor rasters live (``rasters/<granule>/<beam>/``)."""
    d = raster_root / unit.partition
    return {n: d / f"{n}.tif" for n in RASTER_NAMES}


def corridor_reach(config: BatchConfig) -> float:
    """Metres from a track within which a tile's points enter its corridor rasters (as
    ``run`` reads them: half the corridor, half the longest block and the margin)."""
    from ..rasters import CORRIDOR_MARGIN

    return 0.5 * config.width + 0.5 * max(config.lengths) + CORRIDOR_MARGIN


def _block_tile(blocks: pd.DataFrame, tiles: tuple[Tile, ...], crs: pyproj.CRS) -> np.ndarray:
    """Index of the tile holding each block centre (the first in order), -1 for none."""
    x = blocks["x"].to_numpy(float)
    y = blocks["y"].to_numpy(float)
    tcrs = pyproj.CRS.from_wkt(tiles[0].crs_wkt)
    if crs != tcrs:
        x, y = pyproj.Transformer.from_crs(crs, tcrs, always_xy=True).transform(x, y)
    out = np.full(len(blocks), -1)
    for i, t in reversed(list(enumerate(tiles))):
        inside = (x >= t.bounds[0]) & (x < t.bounds[2]) & (y >= t.bounds[1]) & (y < t.bounds[3])
        out[inside] = i
    return out


def run_unit(unit: Unit, config: BatchConfig, out_dir: str, raster_root: str) -> dict:
    """Compute and write one unit; never raises: failures come back in the summary.

    Returns
    -------
    dict
        ``key``, ``status`` (``ok``/``empty``/``failed``), ``error``, ``n_blocks``,
        ``n_validated``, ``files`` (relative to ``out_dir``), ``warnings``.
    """
    summary: dict = {"key": unit.key, "granule": unit.granule, "beam": unit.beam,
                     "tiles": [t.path for t in unit.tiles], "status": "failed", "error": "",
                     "n_blocks": 0, "n_validated": 0, "files": [], "warnings": []}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            _work(unit, config, Path(out_dir), Path(raster_root), summary)
        except NoUsableDataError as exc:
            summary.update(status="empty", error=str(exc))
        except CanopyBlocksError as exc:
            summary.update(status="failed", error=f"{type(exc).__name__}: {exc}")
        except Exception as exc:  # noqa: BLE001 - a bug in one unit must not stop the batch
            tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
            summary.update(status="failed", error=f"unexpected error (a bug): {tb}")
    summary["warnings"] = sorted({str(w.message) for w in caught})
    return summary


def _block_time(track: PhotonTrack, s_start: np.ndarray, s_end: np.ndarray) -> np.ndarray:
    """``delta_time`` (s) at each block's centre, interpolated along the track's photons
    (the photons' ``s`` in m, sorted; NaN for a track without finite photons)."""
    s = np.asarray(track.s, float)
    t = np.asarray(track.time, float)
    ok = np.isfinite(s) & np.isfinite(t)
    if not ok.any():
        return np.full(s_start.size, np.nan)
    order = np.argsort(s[ok], kind="stable")
    return np.interp(0.5 * (s_start + s_end), s[ok][order], t[ok][order])


def _utc(granule: str, delta_time: np.ndarray) -> np.ndarray:
    """UTC of ``delta_time`` (to the ms, as the photon layer); NaT for a simulated granule,
    whose clock starts at its first shot."""
    from ...readers.utc_time import file_counts_from_sdp_epoch, utc_from_delta_time

    if not file_counts_from_sdp_epoch(granule):
        return np.full(delta_time.size, np.datetime64("NaT"), dtype="datetime64[ns]")
    return utc_from_delta_time(delta_time).astype("datetime64[ms]").astype("datetime64[ns]")


def _lonlat_box(unit: Unit, tcrs: pyproj.CRS, reach: float
                ) -> tuple[float, float, float, float]:
    """The unit's tiles' union widened by ``reach`` metres, in degrees (lon/lat box)."""
    b = np.array([t.bounds for t in unit.tiles])
    x0, y0 = b[:, 0].min() - reach, b[:, 1].min() - reach
    x1, y1 = b[:, 2].max() + reach, b[:, 3].max() + reach
    to_ll = pyproj.Transformer.from_crs(tcrs, "EPSG:4326", always_xy=True)
    lon, lat = to_ll.transform(np.array([x0, x1, x0, x1]), np.array([y0, y0, y1, y1]))
    return float(np.min(lon)), float(np.min(lat)), float(np.max(lon)), float(np.max(lat))


def _work(unit: Unit, config: BatchConfig, out_dir: Path, raster_root: Path,
          summary: dict) -> None:
    """One unit as ``run`` does it: the beam's blocks, the survey's corridor rasters
    around them (every tile of the unit together, so blocks over a seam between tiles
    see both), the blocks validated against them."""
    from ...blocks import BlockParams
    from ...blocks.estimators import preset
    from ...errors import CoverageError
    from ...outputs.tables import write_table
    from ...validation.block_validation import validate_blocks
    from ..blocks import read_tracks
    from ..blocks_tracks import blocks_of_track
    from ..box_context import blocks_in_box, context_margin
    from ..rasters import corridor_area, make_survey_rasters

    tcrs = pyproj.CRS.from_wkt(unit.tiles[0].crs_wkt)
    est = preset(config.preset)
    params = BlockParams(lengths=config.lengths, min_signal_conf=config.min_signal_conf)
    # as blocks --bbox: read with the estimators' context, on the whole track's block grid,
    # the blocks meeting the tiles' box kept whole
    tracks = read_tracks(unit.granule, beams=[unit.beam],
                         bbox=_lonlat_box(unit, tcrs, corridor_reach(config)), crs=tcrs,
                         min_signal_conf=config.min_signal_conf,
                         context=context_margin(est, params.lengths), estimators=est)
    blocks, _ = blocks_in_box(tracks[0], params, est, partial(blocks_of_track, tracks[0]))
    summary["n_blocks"] = int(len(blocks))
    r = raster_paths(raster_root, unit)
    try:
        make_survey_rasters([t.path for t in unit.tiles], r["dtm"].parent,
                            resolution=config.resolution, crs=blocks.crs,
                            polygon=corridor_area(blocks, config.width), backend="serial")
    except CoverageError as exc:
        raise NoUsableDataError(f"{unit.key}: no block lies on its tiles ({exc})") from None
    res = validate_blocks(blocks, dtm=r["dtm"], dsm_max=r["dsm_max"], dsm_p90=r["dsm_p90"],
                          width=config.width, offset=config.offset, geoid=config.geoid,
                          photon_vertical_crs=config.photon_vcrs,
                          reference_vertical_crs=config.reference_vcrs)
    where = _block_tile(res.residuals, unit.tiles, blocks.crs)
    names = np.array([Path(t.path).name for t in unit.tiles] + [""], dtype=object)
    residuals = res.residuals.assign(tile=names[where])
    residuals.insert(0, "granule", Path(unit.granule).name)
    if "time" not in residuals.columns and {"s_start", "s_end"} <= set(residuals.columns):
        residuals["time"] = _block_time(tracks[0], residuals["s_start"].to_numpy(float),
                                        residuals["s_end"].to_numpy(float))
    if "time" in residuals.columns and "time_utc" not in residuals.columns:
        residuals.insert(residuals.columns.get_loc("time") + 1, "time_utc",
                         _utc(unit.granule, residuals["time"].to_numpy(float)))
    summary["n_validated"] = int(residuals["use"].sum())
    folder = out_dir / "parts" / unit.partition
    folder.mkdir(parents=True, exist_ok=True)
    blocks = blocks.assign(granule=Path(unit.granule).name)
    write_table(blocks, folder / "blocks.parquet", layer="blocks")
    write_table(residuals, folder / "residuals.parquet", layer="residuals")
    summary["files"] = [f"parts/{unit.partition}/blocks.parquet",
                        f"parts/{unit.partition}/residuals.parquet"]
    summary["status"] = "ok"
