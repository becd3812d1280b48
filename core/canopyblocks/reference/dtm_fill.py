"""Filling the DTM's holes, and writing the rasters of a run with one CRS.

PDAL's cell rule (the mean of the ground points within ``resolution * sqrt(2) / 2`` of a
cell centre) leaves cells without a value where dense canopy hid the ground: 3-45 % of the
cells of the bundled tiles at 2 m.  :func:`fill_dtm_holes` gives them a value and says
which:

* **what is filled**: DTM cells without a value that either hold points (the DSM has a
  value there: the survey saw the cell, only not its ground) or are enclosed by such
  cells (a gap inside the survey).  Cells outside the survey stay nodata: nothing there
  to interpolate from.
* **how**: linear interpolation over a Delaunay triangulation (a TIN, as ground is
  usually interpolated) of the measured cells around the holes (their centres and means);
  a hole outside the triangulation (on the survey's edge) takes the value of the nearest
  measured cell.

Every filled cell is marked in the fill mask (``dtm_fill_mask.tif``: 1 filled, 0 measured,
255 no value), so a user can leave them out or judge them.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from ..errors import DependencyError
from ..geo import as_crs
from .raster_grid import NODATA, Grid, authority_crs

__all__ = ["fill_dtm_holes", "MASK_FILLED", "MASK_MEASURED", "MASK_NODATA"]

log = logging.getLogger(__name__)

MASK_MEASURED = 0
MASK_FILLED = 1
MASK_NODATA = 255
_RING = 3  # measured cells this many cells around a hole take part in its triangulation


def fill_dtm_holes(dtm: np.ndarray, support: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The DTM with its holes filled, and the mask of the filled cells.

    Parameters
    ----------
    dtm : ndarray, shape (rows, cols)
        Ground heights (m), NaN where the cell has no ground point.
    support : ndarray of bool, same shape
        True where the cell holds points of any class (where the DSM has a value).

    Returns
    -------
    filled : ndarray float64
        ``dtm`` with the holes inside the survey interpolated (see the module docstring).
    mask : ndarray bool
        True exactly where ``filled`` has a value that ``dtm`` had not.
    """
    from scipy import ndimage

    dtm = np.asarray(dtm, dtype=np.float64)
    support = np.asarray(support, dtype=bool)
    if dtm.shape != support.shape or dtm.ndim != 2:
        raise ValueError(f"dtm {dtm.shape} and support {support.shape} must be one 2-D grid")
    measured = np.isfinite(dtm)
    covered = ndimage.binary_fill_holes(support | measured)
    holes = covered & ~measured
    filled = dtm.copy()
    if not holes.any() or not measured.any():
        return filled, np.zeros(dtm.shape, dtype=bool)
    near = ndimage.binary_dilation(holes, structure=np.ones((3, 3), bool), iterations=_RING)
    src = np.nonzero(measured & near)
    dst = np.nonzero(holes)
    values = _linear(np.column_stack(src).astype(np.float64), dtm[src],
                     np.column_stack(dst).astype(np.float64))
    outside = ~np.isfinite(values)
    if outside.any():  # beyond the triangulation: the nearest measured cell
        idx = ndimage.distance_transform_edt(~measured, return_distances=False,
                                             return_indices=True)
        r, c = dst[0][outside], dst[1][outside]
        values[outside] = dtm[idx[0][r, c], idx[1][r, c]]
    filled[dst] = values
    return filled, holes


def _linear(points: np.ndarray, values: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Linear (TIN) interpolation; NaN outside the hull or when no triangle can be made."""
    if len(points) < 3:
        return np.full(len(targets), np.nan)
    from scipy.interpolate import LinearNDInterpolator

    try:
        return np.asarray(LinearNDInterpolator(points, values)(targets), dtype=np.float64)
    except Exception as exc:  # noqa: BLE001 - collinear cells: Qhull cannot triangulate
        log.debug("no triangulation of the measured cells (%s); nearest cell instead", exc)
        return np.full(len(targets), np.nan)


def rasterio_module() -> Any:
    """rasterio, or the project's error saying how to install it."""
    try:
        import rasterio
    except ImportError:
        raise DependencyError("writing reference rasters needs rasterio: "
                              "pip install 'canopyblocks[raster]'") from None
    return rasterio


def grid_crs(like: Path, grid: Grid) -> pyproj.CRS:
    """The CRS PDAL wrote into ``like`` with its authority codes (checked: same grid)."""
    rasterio = rasterio_module()
    with rasterio.open(like) as src:
        crs = src.crs
        if (src.width, src.height) != (grid.width, grid.height):
            raise RuntimeError(f"PDAL wrote a {src.width} x {src.height} raster, expected "
                               f"{grid.width} x {grid.height}")
    found = pyproj.CRS.from_wkt(crs.to_wkt()) if crs is not None else as_crs(grid.crs_wkt)
    return authority_crs(found)


def write_grid(path: Path, values: np.ndarray, grid: Grid, crs: pyproj.CRS,
               dtype: str = "float32", nodata: float = NODATA) -> None:
    """Write a (height, width) grid as a GeoTIFF on ``grid`` (non-finite -> ``nodata``)."""
    rasterio = rasterio_module()
    from rasterio.crs import CRS
    from rasterio.transform import Affine

    data = np.where(np.isfinite(values), values, nodata).astype(dtype)
    code = crs.srs if crs.srs.upper().startswith("EPSG:") else None
    profile = dict(driver="GTiff", width=grid.width, height=grid.height, count=1,
                   dtype=dtype, nodata=nodata,
                   crs=CRS.from_user_input(code) if code else CRS.from_wkt(crs.to_wkt()),
                   transform=Affine.from_gdal(*grid.transform))
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data, 1)


def fill_and_write_dtm(dtm_path: Path, mask_path: Path, support: np.ndarray, grid: Grid,
                       crs: pyproj.CRS) -> int:
    """Rewrite PDAL's DTM at ``dtm_path`` with its holes filled and ``crs``; write the fill
    mask to ``mask_path``.  Returns the number of filled cells."""
    rasterio = rasterio_module()
    with rasterio.open(dtm_path) as src:
        raw = src.read(1).astype(np.float64)
        nodata = src.nodata
    raw[(raw == NODATA) | (raw == nodata) | ~np.isfinite(raw)] = np.nan
    filled, mask = fill_dtm_holes(raw, support)
    write_grid(dtm_path, filled, grid, crs)
    codes = np.where(mask, MASK_FILLED, np.where(np.isfinite(filled), MASK_MEASURED,
                                                 MASK_NODATA))
    write_grid(mask_path, codes, grid, crs, dtype="uint8", nodata=MASK_NODATA)
    n = int(mask.sum())
    log.info("DTM: %d of %d cells filled by interpolation (%.1f %%)", n, mask.size,
             100.0 * n / mask.size)
    return n
