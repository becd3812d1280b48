"""Terrain slope and aspect from the DTM (Horn's method) and per-block classes (DESIGN 2.5).

Conventions (those of ``gdaldem slope/aspect``):

* slope in degrees, ``atan(|grad z|)``;
* aspect in degrees clockwise from north, the compass direction the slope FACES
  (downhill), in [0, 360); NaN where the gradient is exactly zero (GDAL writes
  -9999 there) and on the raster's outer ring and next to nodata (no 3x3 window).

Per block (the corridor polygon's cells, ``all_touched`` as for the reference values):

* ``slope`` = mean of the cells' slopes, degrees;
* ``aspect`` = circular mean ``atan2(mean sin, mean cos)`` of the aspects of the cells
  whose slope is at least ``slope_threshold`` (flatter cells have noise aspects and
  are skipped; unweighted);
* ``aspect_class`` = ``flat`` when the block slope is below ``slope_threshold``
  (default 2 degrees) or no cell is steep enough, else the 45-degree sector centred
  on N, NE, E, SE, S, SW, W, NW (N = [337.5, 22.5)); ``unknown`` without valid cells;
* ``slope_class`` = ``0-5``, ``5-10``, ``10-20``, ``20-30``, ``>30`` degrees (lower bound
  inclusive), ``unknown`` without valid cells.
"""

from __future__ import annotations

import logging
import os

import geopandas as gpd
import numpy as np
import pandas as pd

from ..errors import InputError
from ..progress import Progress
from .zonal import RasterGrid, zonal_reduce

__all__ = [
    "horn_slope_aspect",
    "aspect_class",
    "slope_class",
    "block_terrain",
    "ASPECT_CLASSES",
    "SLOPE_CLASSES",
    "SLOPE_BREAKS",
    "CLASS_FLAT",
    "CLASS_UNKNOWN",
]

log = logging.getLogger(__name__)

ASPECT_CLASSES: tuple[str, ...] = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")
CLASS_FLAT = "flat"
CLASS_UNKNOWN = "unknown"
#: Lower bounds (degrees) of the slope classes; the last class is open-ended.
SLOPE_BREAKS: tuple[float, ...] = (0.0, 5.0, 10.0, 20.0, 30.0)
SLOPE_CLASSES: tuple[str, ...] = ("0-5", "5-10", "10-20", "20-30", ">30")


def horn_slope_aspect(dem: np.ndarray, xres: float, yres: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Slope and aspect of a north-up grid by Horn's (1981) 3x3 finite differences.

    Parameters
    ----------
    dem : ndarray (rows, cols)
        Heights, metres; row 0 is the northern edge; NaN = nodata.
    xres, yres : float
        Cell width and height, metres (positive).

    Returns
    -------
    slope, aspect : ndarray (rows, cols) of float64, degrees
        NaN on the outer ring, next to NaN cells, and (aspect only) where the
        gradient is zero.
    """
    from ..arguments import check_array, check_number
    check_array(dem, "horn_slope_aspect: dem", ndim=2)
    check_number(xres, "horn_slope_aspect: xres", above=0.0, unit=" m")
    check_number(yres, "horn_slope_aspect: yres", unit=" m")
    z = np.asarray(dem, dtype=np.float64)
    if z.ndim != 2:
        raise InputError(f"the DEM must be 2-D, got shape {z.shape}")
    slope = np.full(z.shape, np.nan)
    aspect = np.full(z.shape, np.nan)
    if z.shape[0] < 3 or z.shape[1] < 3:
        return slope, aspect
    a, b, c = z[:-2, :-2], z[:-2, 1:-1], z[:-2, 2:]
    d, f = z[1:-1, :-2], z[1:-1, 2:]
    g, h, i = z[2:, :-2], z[2:, 1:-1], z[2:, 2:]
    dzdx = ((c + 2 * f + i) - (a + 2 * d + g)) / (8.0 * xres)   # eastwards
    dzdy = ((a + 2 * b + c) - (g + 2 * h + i)) / (8.0 * yres)   # northwards
    slope[1:-1, 1:-1] = np.degrees(np.arctan(np.hypot(dzdx, dzdy)))
    asp = np.degrees(np.arctan2(-dzdx, -dzdy)) % 360.0  # downhill direction, from north
    asp[(dzdx == 0) & (dzdy == 0)] = np.nan
    aspect[1:-1, 1:-1] = asp
    centre_nan = np.isnan(z)  # Horn ignores the centre cell; nodata there stays nodata (GDAL)
    slope[centre_nan] = np.nan
    aspect[centre_nan] = np.nan
    return slope, aspect


def aspect_class(aspect: np.ndarray | float, slope: np.ndarray | float,
                 slope_threshold: float = 2.0) -> np.ndarray:
    """Aspect classes (N..NW, ``flat``, ``unknown``) of aspects/slopes in degrees."""
    asp = np.atleast_1d(np.asarray(aspect, dtype=float))
    slo = np.atleast_1d(np.asarray(slope, dtype=float))
    sector = (np.floor(((np.nan_to_num(asp) % 360.0) + 22.5) / 45.0).astype(int)) % 8
    out = np.asarray(ASPECT_CLASSES, dtype=object)[sector]
    out[~np.isfinite(asp) | (slo < slope_threshold)] = CLASS_FLAT
    out[~np.isfinite(slo)] = CLASS_UNKNOWN
    return out


def slope_class(slope: np.ndarray | float) -> np.ndarray:
    """Slope classes (``0-5`` ... ``>30``, ``unknown`` for NaN) of slopes in degrees."""
    slo = np.atleast_1d(np.asarray(slope, dtype=float))
    k = np.clip(np.searchsorted(SLOPE_BREAKS, np.nan_to_num(slo), side="right") - 1, 0,
                len(SLOPE_CLASSES) - 1)
    out = np.asarray(SLOPE_CLASSES, dtype=object)[k]
    out[~np.isfinite(slo)] = CLASS_UNKNOWN
    return out


def block_terrain(corridors: gpd.GeoDataFrame, dtm: str | os.PathLike[str], *,
                  slope_threshold: float = 2.0, all_touched: bool = True,
                  progress: Progress | None = None) -> pd.DataFrame:
    """Mean slope, circular-mean aspect and their classes per corridor polygon.

    Parameters
    ----------
    corridors : GeoDataFrame
        Corridor polygons (see :func:`~canopyblocks.reference.corridor.block_corridors`).
    dtm : path
        Terrain GeoTIFF in a metric CRS (cell sizes in metres).
    slope_threshold : float
        Degrees; below it a block's aspect class is ``flat`` (default 2).

    Returns
    -------
    DataFrame
        Index of ``corridors``; ``track, length, block`` (when present), ``slope``,
        ``aspect`` (degrees), ``aspect_class``, ``slope_class``.
    """
    from ..arguments import check_frame, check_path
    check_frame(corridors, "block_terrain: corridors", "corridor polygons (GeoDataFrame)")
    check_path(dtm, "block_terrain: dtm", "a raster path")
    thr = float(slope_threshold)
    if not np.isfinite(thr) or thr < 0:
        raise InputError(f"slope_threshold must be >= 0 degrees, got {slope_threshold!r}")

    def derive(win: dict[str, np.ndarray], grid: RasterGrid) -> dict[str, np.ndarray]:
        slope, aspect = horn_slope_aspect(win["dtm"], *grid.res)
        return {"slope": slope, "aspect": aspect}

    def reduce(cells: dict[str, np.ndarray], n_touched: int) -> dict[str, float]:
        s, a = cells["slope"], cells["aspect"]
        ok = np.isfinite(s)
        if not ok.any():
            return {"slope": np.nan, "aspect": np.nan}
        steep = ok & np.isfinite(a) & (s >= thr)
        if steep.any():
            r = np.radians(a[steep])
            asp = float(np.degrees(np.arctan2(np.mean(np.sin(r)), np.mean(np.cos(r)))) % 360.0)
        else:
            asp = np.nan
        return {"slope": float(np.mean(s[ok])), "aspect": asp}

    res = zonal_reduce(corridors, {"dtm": dtm}, reduce, all_touched=all_touched,
                       derive=derive, halo=1, progress=progress)
    out = pd.DataFrame(index=corridors.index)
    for c in ("track", "length", "block"):
        if c in corridors.columns:
            out[c] = corridors[c].to_numpy()
    slope = res["slope"].to_numpy(float) if "slope" in res else np.full(len(out), np.nan)
    aspect = res["aspect"].to_numpy(float) if "aspect" in res else np.full(len(out), np.nan)
    out["slope"] = slope
    out["aspect"] = aspect
    out["aspect_class"] = aspect_class(aspect, slope, thr) if len(out) else []
    out["slope_class"] = slope_class(slope) if len(out) else []
    return out
