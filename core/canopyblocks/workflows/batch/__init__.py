"""Many granules against many airborne tiles (DESIGN 6): units of work, backends
(serial, local processes, Dask), partitions, manifest and the final reduce.

Names are imported on first use: ``batch.backends`` (the process pool every command
shares) must not pull in pandas and the readers.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..backends import BACKENDS, run_items
    from .runner import BatchResult, run_batch
    from .units import Tile, Unit, find_units, tile_index
    from .work import BatchConfig, run_unit

_WHERE = {"BACKENDS": "..backends", "run_items": "..backends", "BatchResult": ".runner",
          "run_batch": ".runner", "Tile": ".units", "Unit": ".units", "find_units": ".units",
          "tile_index": ".units", "BatchConfig": ".work", "run_unit": ".work"}

__all__ = ["BACKENDS", "BatchConfig", "BatchResult", "Tile", "Unit", "find_units",
           "run_batch", "run_items", "run_unit", "tile_index"]


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
