"""canopyblocks.reference: what photon blocks are judged against.

PDAL rasters from airborne lidar (``pdal``, ``rasters``, ``lidar_points``), the corridor
polygons cut at block edges (``corridor``), zonal block values (``zonal``), terrain slope
and aspect (``terrain``), vertical datums (``datum``), ATL08 land segments (``atl08``),
the footprint-matched ALS reference (``footprint``) and raster sampling (``raster_sampling``).
"""

from __future__ import annotations

from .atl08 import atl08_reference_values, read_atl08_segments
from .corridor import block_corridors
from .datum import apply_vertical_offset, check_vertical_datums, vertical_part
from .footprint import FootprintCloud, density_weights, footprint_reference
from .footprint_blocks import block_footprint_reference
from .footprint_params import FootprintReferenceParams
from .lidar_points import cell_percentile, crop_corridor
from .pdal import PIPELINES, TileInfo, find_pdal, pdal_version, run_pipeline, tile_info
from .raster_sampling import RasterSurface, read_surface
from .rasters import NODATA, Grid, RasterParams, ReferenceRasters, make_reference_rasters
from .terrain import aspect_class, block_terrain, horn_slope_aspect, slope_class
from .zonal import block_reference_values

__all__ = [
    "atl08_reference_values",
    "read_atl08_segments",
    "block_corridors",
    "apply_vertical_offset",
    "check_vertical_datums",
    "vertical_part",
    "cell_percentile",
    "crop_corridor",
    "PIPELINES",
    "TileInfo",
    "find_pdal",
    "pdal_version",
    "run_pipeline",
    "tile_info",
    "NODATA",
    "Grid",
    "RasterParams",
    "ReferenceRasters",
    "make_reference_rasters",
    "aspect_class",
    "block_terrain",
    "horn_slope_aspect",
    "slope_class",
    "block_reference_values",
    "FootprintReferenceParams",
    "FootprintCloud",
    "footprint_reference",
    "block_footprint_reference",
    "density_weights",
    "RasterSurface",
    "read_surface",
]
