"""Many granules against many airborne tiles (DESIGN 6): units of work, backends
(serial, local processes, Dask), partitions, manifest and the final reduce."""

from __future__ import annotations

from .backends import BACKENDS, run_items
from .runner import BatchResult, run_batch
from .units import Tile, Unit, find_units, tile_index
from .work import BatchConfig, run_unit

__all__ = ["BACKENDS", "BatchConfig", "BatchResult", "Tile", "Unit", "find_units",
           "run_batch", "run_items", "run_unit", "tile_index"]
