"""Validation of a block table against reference rasters or ATL08 (orchestration).

``validate_blocks``: corridors -> vertical datum check/conversion -> reference values
-> terrain -> residuals -> statistics.  ``validate_atl08``: the same with ATL08 land
segments as reference (no terrain classes).
"""

from __future__ import annotations

import logging
import os
import warnings
from dataclasses import dataclass

import geopandas as gpd
import numpy as np
import pandas as pd
import pyproj

from ..errors import CanopyBlocksWarning, CoverageError, FileFormatError, InputError
from ..geo import require_metric_crs
from ..progress import Progress, as_progress
from ..reference.atl08 import atl08_reference_values, read_atl08_segments
from ..reference.corridor import block_corridors
from ..reference.datum import apply_vertical_offset, check_vertical_datums
from ..reference.terrain import block_terrain
from ..reference.zonal import block_reference_values
from .residuals import compute_residuals
from .stats import block_stats

__all__ = ["ValidationResult", "validate_blocks", "validate_atl08", "PHOTON_VERTICAL_CRS"]

log = logging.getLogger(__name__)

#: Photon heights of ATL03/MABEL: WGS84 ellipsoidal.
PHOTON_VERTICAL_CRS = "EPSG:4979"


@dataclass(frozen=True, eq=False)
class ValidationResult:
    """Residuals per block (corridor polygons) and statistics per length/metric/group."""

    residuals: gpd.GeoDataFrame
    stats: pd.DataFrame
    datum: str = "unknown"


def _raster_crs(path: str | os.PathLike[str]) -> pyproj.CRS | None:
    try:
        import rasterio
    except ImportError:
        return None
    if not os.path.exists(path):
        raise FileFormatError(f"DTM raster {path}: no such file")
    try:
        with rasterio.open(path) as src:
            return None if src.crs is None else pyproj.CRS.from_user_input(src.crs.to_wkt())
    except rasterio.errors.RasterioIOError as exc:
        raise FileFormatError(f"DTM raster {path}: cannot read ({exc})") from None


def raster_horizontal_crs(dtm: str | os.PathLike[str]) -> pyproj.CRS | None:
    """The horizontal CRS of the DTM (None when it has none), checked to be metric.

    Raises
    ------
    FileFormatError
        The DTM is missing or unreadable.
    CRSError
        Its CRS is geographic or not in metres (slope, aspect and corridors need metres).
    """
    crs = _raster_crs(dtm)
    if crs is None:
        return None
    horizontal = crs.sub_crs_list[0] if crs.is_compound and crs.sub_crs_list else crs
    return require_metric_crs(horizontal, f"the rasters' CRS (DTM {dtm}):")


def _check_blocks(blocks: pd.DataFrame) -> None:
    if not isinstance(blocks, pd.DataFrame) or len(blocks) == 0:
        raise InputError("the block table is empty; nothing to validate")


def _require_reference(ref: pd.DataFrame,
                       rasters: dict[str, tuple[str, str | os.PathLike[str]]]) -> None:
    """Refuse a raster that gives no block a value (all nodata under the corridors).

    A result with every block unusable would look like a validation with nothing to
    say; the user must learn that the raster (not the photons) is the problem.
    """
    for col, (what, path) in rasters.items():
        if col in ref.columns and len(ref) and not np.isfinite(
                ref[col].to_numpy(dtype=float)).any():
            raise CoverageError(
                f"{what} raster {path} holds only nodata under all {len(ref)} block "
                "corridors; give a raster with values along the track (check its nodata "
                "value, extent and the tiles' ground classes)")


MAX_MEDIAN_RESIDUAL_M = 100.0
"""A median |residual| above this (m) is not a measurement error but a reference in other
units, of another datum, or without heights: the validation is refused."""


def require_plausible_reference(residuals: pd.DataFrame,
                                rasters: dict[str, tuple[str, str, object]]) -> None:
    """Refuse references that cannot describe the photons' surface; warn on constant ones.

    Parameters
    ----------
    residuals : DataFrame
        With ``use`` and, per entry of ``rasters``, the residual and reference columns.
    rasters : dict
        ``residual column -> (reference column, what, path)``.

    Raises
    ------
    InputError
        Median |residual| above :data:`MAX_MEDIAN_RESIDUAL_M` over the usable rows: a
        raster in feet, holding zeros, or on another vertical datum.
    """
    use = residuals["use"].to_numpy(bool)
    for res_col, (ref_col, what, path) in rasters.items():
        if res_col not in residuals.columns or ref_col not in residuals.columns:
            continue
        res = residuals[res_col].to_numpy(float)
        ref = residuals[ref_col].to_numpy(float)
        ok = use & np.isfinite(res) & np.isfinite(ref)
        if not ok.any():
            continue
        med = float(np.median(res[ok]))
        if abs(med) > MAX_MEDIAN_RESIDUAL_M:
            raise InputError(
                f"{what} raster {path}: the photons differ from it by a median of {med:+.0f} m "
                f"over {int(ok.sum())} blocks (raster median {np.median(ref[ok]):.1f} m); it "
                "cannot be the same surface: check that it holds heights in metres (not feet, "
                "not zeros, nodata declared) on the photons' vertical datum (a geoid or "
                "vertical offset may be missing)")
        if int(ok.sum()) >= 3 and float(np.ptp(ref[ok])) == 0.0:
            warnings.warn(
                f"{what} raster {path} gives the same value ({ref[ok][0]:g} m) under all "
                f"{int(ok.sum())} blocks; check that it holds heights", CanopyBlocksWarning,
                stacklevel=3)


def validate_blocks(blocks: gpd.GeoDataFrame, *, dtm: str | os.PathLike[str],
                    dsm_max: str | os.PathLike[str], dsm_p90: str | os.PathLike[str],
                    width: float | None = None,
                    geoid: str | os.PathLike[str] | None = None,
                    offset: float | None = None, reference_vertical_crs: object = None,
                    photon_vertical_crs: object = None, slope_threshold: float = 2.0,
                    all_touched: bool = True, ground_stat: str = "mean",
                    top_stat: str = "max", top90_stat: str = "max",
                    progress: Progress | None = None) -> ValidationResult:
    """Validate photon blocks against reference lidar rasters (DESIGN section 2).

    Parameters
    ----------
    blocks : GeoDataFrame
        Block table in the track's metric CRS.
    dtm, dsm_max, dsm_p90 : path
        Reference GeoTIFFs on one grid (metres).
    width : float, optional
        Corridor width, metres; default the footprint of the blocks' sensor (ICESat-2
        13 m, MABEL 2 m: :func:`~canopyblocks.reference.sensor_width.corridor_width`).
    geoid, offset
        Vertical conversion of the photon heights (see ``reference.datum``).
    reference_vertical_crs : CRS-like, optional
        Vertical (or compound/3-D) CRS of the rasters' heights; default the DTM's CRS
        (a horizontal-only CRS means "unknown": warned, not refused).
    photon_vertical_crs : CRS-like, optional
        Default ``blocks.attrs["vertical_datum"]`` or EPSG:4979 (WGS84 ellipsoid).
    slope_threshold : float
        Degrees below which the aspect class is ``flat``.

    Raises
    ------
    DatumError, CoverageError, CRSError, InputError, FileFormatError
    """
    from ..arguments import check_frame
    check_frame(blocks, "validate_blocks: blocks", "a block table (GeoDataFrame)")
    _check_blocks(blocks)
    prog = as_progress(progress)
    dtm_crs = _raster_crs(dtm)
    raster_horizontal_crs(dtm)  # slope and aspect need cell sizes in metres
    ref_crs = reference_vertical_crs if reference_vertical_crs is not None else dtm_crs
    pv = photon_vertical_crs or blocks.attrs.get("vertical_datum") or PHOTON_VERTICAL_CRS
    decision = check_vertical_datums(pv, ref_crs, geoid=geoid, offset=offset)
    prog.update(0.0, "corridors")
    corridors = block_corridors(blocks, width=width)
    work = apply_vertical_offset(blocks, geoid=geoid, offset=offset)
    ref = block_reference_values(corridors, dtm=dtm, dsm_max=dsm_max, dsm_p90=dsm_p90,
                                 ground_stat=ground_stat, top_stat=top_stat,
                                 top90_stat=top90_stat, all_touched=all_touched,
                                 progress=prog.sub(0.02, 0.6))
    _require_reference(ref, {"ref_ground": ("DTM", dtm), "ref_top": ("DSM max", dsm_max),
                             "ref_top90": ("DSM p90", dsm_p90)})
    terrain = block_terrain(corridors, dtm, slope_threshold=slope_threshold,
                            all_touched=all_touched, progress=prog.sub(0.6, 0.95))
    residuals = compute_residuals(work, ref, terrain, corridors=corridors)
    require_plausible_reference(residuals, {"res_ground": ("ref_ground", "DTM", str(dtm)),
                                            "res_top": ("ref_top", "DSM max", str(dsm_max))})
    stats = block_stats(residuals)
    prog.update(1.0, "validation done")
    return ValidationResult(residuals, stats, decision)


def validate_atl08(blocks: gpd.GeoDataFrame, atl08: str | os.PathLike[str], *,
                   width: float | None = None, max_distance: float | None = None,
                   progress: Progress | None = None) -> ValidationResult:
    """Validate photon blocks against ATL08 land segments (heights stay ellipsoidal).

    The residual layer's geometry is the block corridor (``width`` metres; default the
    footprint of the blocks' sensor).
    """
    _check_blocks(blocks)
    prog = as_progress(progress)
    segs = read_atl08_segments(atl08)
    ref = atl08_reference_values(blocks, segs, max_distance=max_distance)
    prog.update(0.5, "ATL08 matched")
    corridors = block_corridors(blocks, width=width)
    residuals = compute_residuals(blocks, ref, None, corridors=corridors)
    stats = block_stats(residuals)
    prog.update(1.0, "validation done")
    return ValidationResult(residuals, stats, "same")
