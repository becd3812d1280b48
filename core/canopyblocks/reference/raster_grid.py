"""The grid, parameters, result and CRS rules of the reference rasters.

:class:`Grid` is the one north-up grid all rasters of a run share (writers.gdal's options
put PDAL's raster exactly on it); :class:`RasterParams` validates the user's choices once;
:class:`ReferenceRasters` is what :func:`~canopyblocks.reference.rasters.make_reference_rasters`
returns.  CRS rules: a tile's CRS is PDAL's reading, else laspy's, else the one given; the
rasters are written with the CRS's authority codes (:func:`authority_crs`: e.g.
``EPSG:3005+5713`` for NAD83 / BC Albers + CGVD28 height, the horizontal code alone when
the vertical part is "unknown"), so GIS software identifies them.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyproj

from ..errors import CRSError, InputError
from ..geo import as_crs, require_metre_units
from .pdal import TileInfo

__all__ = ["NODATA", "GroundMethod", "Grid", "RasterParams", "ReferenceRasters",
           "check_tile_crs", "crs_label", "authority_crs", "horizontal_crs"]

log = logging.getLogger(__name__)

NODATA = -9999.0
GroundMethod = Literal["class2", "smrf"]


@dataclass(frozen=True)
class Grid:
    """A north-up raster grid.

    Attributes
    ----------
    origin_x, origin_y : float
        West and **south** edges, metres (writers.gdal's origin is the lower-left corner).
    width, height : int
        Columns and rows.
    resolution : float
        Cell size, metres.
    crs_wkt : str
        The grid's CRS (WKT).
    """

    origin_x: float
    origin_y: float
    width: int
    height: int
    resolution: float
    crs_wkt: str

    def __post_init__(self) -> None:
        if not (self.width > 0 and self.height > 0):
            raise InputError(f"grid must have at least one cell, got {self.width} x {self.height}")
        if not (self.resolution > 0 and math.isfinite(self.resolution)):
            raise InputError(f"grid resolution must be > 0 m, got {self.resolution}")

    @classmethod
    def from_bounds(cls, bounds: Sequence[float], resolution: float, crs_wkt: str) -> Grid:
        """The smallest grid with edges on multiples of ``resolution`` covering ``bounds``."""
        from ..arguments import check_array, check_number

        b = check_array(bounds, "Grid.from_bounds: bounds",
                        what="(minx, miny, maxx, maxy) in metres", size=4)
        resolution = check_number(resolution, "Grid.from_bounds: resolution", above=0.0,
                                  unit=" m")
        if not (bool(np.isfinite(b).all()) and b[2] >= b[0] and b[3] >= b[1]):
            raise InputError(f"Grid.from_bounds: bounds must be finite (minx, miny, maxx, "
                             f"maxy) in metres; got {tuple(b.tolist())}")
        minx, miny, maxx, maxy = (float(v) for v in b)
        x0 = math.floor(minx / resolution) * resolution
        y0 = math.floor(miny / resolution) * resolution
        width = max(1, math.ceil(round((maxx - x0) / resolution, 9)))
        height = max(1, math.ceil(round((maxy - y0) / resolution, 9)))
        return cls(x0, y0, int(width), int(height), float(resolution), crs_wkt)

    @property
    def top_y(self) -> float:
        """North edge, metres."""
        return self.origin_y + self.height * self.resolution

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(minx, miny, maxx, maxy)`` in metres."""
        return (self.origin_x, self.origin_y,
                self.origin_x + self.width * self.resolution, self.top_y)

    @property
    def transform(self) -> tuple[float, float, float, float, float, float]:
        """GDAL geotransform ``(x0, res, 0, top, 0, -res)``."""
        return (self.origin_x, self.resolution, 0.0, self.top_y, 0.0, -self.resolution)

    @property
    def radius(self) -> float:
        """The cell rule's radius, ``resolution * sqrt(2) / 2`` (metres)."""
        return self.resolution * math.sqrt(2.0) / 2.0

    def writer_options(self) -> dict[str, object]:
        """writers.gdal overrides putting PDAL's raster exactly on this grid."""
        return {
            "writers.gdal.resolution": self.resolution,
            "writers.gdal.radius": self.radius,
            "writers.gdal.origin_x": self.origin_x,
            "writers.gdal.origin_y": self.origin_y,
            "writers.gdal.width": self.width,
            "writers.gdal.height": self.height,
            "writers.gdal.nodata": NODATA,
        }


@dataclass(frozen=True)
class RasterParams:
    """Parameters of :func:`make_reference_rasters`, validated once.

    Attributes
    ----------
    resolution : float
        Cell size in metres (> 0).
    ground : {"class2", "smrf"}
        Ground points: the file's class 2, or re-classified by PDAL's SMRF.
    bounds : tuple of float or None
        ``(minx, miny, maxx, maxy)`` in the output CRS, metres.
    """

    resolution: float = 2.0
    ground: GroundMethod = "class2"
    bounds: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.resolution, (int, float)) and math.isfinite(self.resolution)
                and self.resolution > 0):
            raise InputError(f"resolution must be a positive number of metres, "
                             f"got {self.resolution!r}")
        if self.ground not in ("class2", "smrf"):
            raise InputError(f"ground must be 'class2' or 'smrf', got {self.ground!r}")
        if self.bounds is not None:
            b = tuple(float(v) for v in self.bounds)
            if len(b) != 4 or not all(math.isfinite(v) for v in b) or b[0] >= b[2] \
                    or b[1] >= b[3]:
                raise InputError(f"bounds must be (minx, miny, maxx, maxy) with min < max, "
                                 f"got {self.bounds!r}")
            object.__setattr__(self, "bounds", b)


@dataclass(frozen=True)
class ReferenceRasters:
    """The three rasters of one run, their shared grid, and the DTM's fill mask.

    ``dtm_fill_mask`` is a uint8 GeoTIFF on the same grid: 1 where the DTM value was
    interpolated (a cell with points but no ground point, or a hole enclosed by the
    survey), 0 where it is the mean of ground points, 255 where the DTM has no value.
    ``stats`` holds cell counts (``cells``, ``dtm`` measured, ``dtm_filled``, ``dsm_max``).
    """

    dtm: Path
    dsm_max: Path
    dsm_p90: Path
    grid: Grid
    crs: pyproj.CRS
    tiles: tuple[Path, ...]
    ground: GroundMethod
    pdal_version: str = ""
    dtm_fill_mask: Path | None = None
    stats: dict[str, Any] = field(default_factory=dict, compare=False)

    @property
    def crs_label(self) -> str:
        """The horizontal CRS's name and EPSG code, for messages."""
        return crs_label(self.crs)


def check_tile_crs(info: TileInfo, assigned: pyproj.CRS | None) -> tuple[pyproj.CRS, bool]:
    """A tile's CRS, checked: metric horizontal and vertical units.

    Returns
    -------
    crs : pyproj.CRS
        The tile's CRS as :func:`~canopyblocks.readers.las_crs.las_file_crs` reads it (the
        one reading every command uses: WKT or GeoTIFF keys, vertical part and units),
        else PDAL's reading, else ``assigned``.
    override : bool
        True when PDAL did not see this CRS (PDAL 2.2 ignores GeoTIFF keys in LAS 1.4
        files), so the pipeline must set it on the reader (``spatialreference``).

    Raises
    ------
    CRSError
        No CRS and nothing assigned; a CRS in feet (horizontal or vertical).
    """
    from ..readers.las_crs import las_file_crs

    stated = las_file_crs(info.path)
    stated.require_metres()
    wkt, override = info.crs_wkt, False
    stated_crs = stated.crs  # parsed once (a survey's tiles state one CRS: see _checked)
    if stated_crs is not None:
        if wkt is None:
            log.info("PDAL read no CRS in %s; using the one its header states", info.path)
        wkt, override = _wkt(stated_crs), wkt is None
    if wkt is None:
        if assigned is None:
            raise CRSError(f"tile {info.path} has no CRS; give the CRS its coordinates are in "
                           "(--crs EPSG:XXXX in rasters, crs=... in Python) or write it into "
                           "the file (pdal translate with writers.las.a_srs) for `run`")
        log.warning("tile %s has no CRS; reading it as %s (the given crs)", info.path,
                    assigned.to_string())
        return assigned, True
    return _checked(wkt, str(info.path)), override


@lru_cache(maxsize=64)
def _wkt(crs: pyproj.CRS) -> str:
    return crs.to_wkt()


@lru_cache(maxsize=64)
def _checked(wkt: str, path: str) -> pyproj.CRS:
    """A tile's CRS from its WKT, checked metric (once per CRS and tile name)."""
    crs = as_crs(wkt, f"CRS of tile {path}")
    require_metre_units(crs, f"tile {path}")
    return crs


def _horizontal(crs: pyproj.CRS) -> pyproj.CRS:
    if crs.is_compound and crs.sub_crs_list:
        return crs.sub_crs_list[0]
    return crs


def crs_label(crs: pyproj.CRS) -> str:
    """A short name for messages: the horizontal CRS's name and EPSG code when known."""
    h = _horizontal(crs)
    code = h.to_epsg(min_confidence=70)
    return f"{h.name} (EPSG:{code})" if code else h.name


def fmt_bounds(bounds: Sequence[float]) -> tuple[float, ...]:
    return tuple(round(float(v), 2) for v in bounds)




def horizontal_crs(crs: pyproj.CRS) -> pyproj.CRS:
    """The horizontal part of a compound CRS (the CRS itself otherwise)."""
    return _horizontal(crs)


def authority_crs(crs: pyproj.CRS) -> pyproj.CRS:
    """``crs`` rebuilt from its EPSG codes, so GIS software identifies it.

    A compound CRS whose parts both have codes becomes ``EPSG:h+v`` (e.g. EPSG:3005+5713,
    NAD83 / BC Albers + CGVD28 height); one whose vertical part has no code (PDAL writes
    ``COMPD_CS["unknown", ..., VERT_CS["unknown"]]`` for LAS files without a vertical
    CRS, which QGIS names "unknown") keeps that vertical part under the name
    "<horizontal name> + unknown height", with the horizontal part from its code; a CRS
    with a code becomes ``EPSG:code``.  The vertical part is never dropped or changed (the
    vertical datum rules read it).  Anything else is returned unchanged.
    """
    h = _horizontal(crs)
    h_code = h.to_epsg(min_confidence=90)
    if h_code is None:
        return crs
    if not crs.is_compound or len(crs.sub_crs_list) < 2:
        return pyproj.CRS.from_epsg(h_code)
    v = crs.sub_crs_list[1]
    v_code = v.to_epsg(min_confidence=90)
    if v_code is not None:
        return pyproj.CRS.from_user_input(f"EPSG:{h_code}+{v_code}")
    h_auth = pyproj.CRS.from_epsg(h_code)
    v_name = v.name if v.name.lower() not in ("unknown", "unnamed", "") else "unknown height"
    return pyproj.crs.CompoundCRS(name=f"{h_auth.name} + {v_name}", components=[h_auth, v])
