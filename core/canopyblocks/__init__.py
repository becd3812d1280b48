"""canopyblocks: canopy height and ground per along-track block from lidar profiles.

Data flow: readers -> photons -> blocks -> reference -> validation -> outputs.
Public functions are re-exported here; see ``docs/ARCHITECTURE.md``.
"""

from __future__ import annotations

import logging

from .errors import (
    CancelledError,
    CanopyBlocksError,
    CanopyBlocksWarning,
    CoverageError,
    CRSError,
    DatumError,
    DependencyError,
    FileFormatError,
    InputError,
    NoUsableDataError,
    PdalError,
    SparseBlockWarning,
)
from .geo import utm_crs_for
from .outputs.atomic import atomic_output
from .outputs.tables import read_blocks, read_layer, write_layers, write_table
from .photons import PhotonTrack, along_track_distance
from .progress import Progress

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "__version__",
    "CancelledError",
    "CanopyBlocksError",
    "CanopyBlocksWarning",
    "CoverageError",
    "CRSError",
    "DatumError",
    "DependencyError",
    "FileFormatError",
    "InputError",
    "NoUsableDataError",
    "PdalError",
    "SparseBlockWarning",
    "PhotonTrack",
    "along_track_distance",
    "Progress",
    "atomic_output",
    "read_blocks",
    "read_layer",
    "write_layers",
    "write_table",
    "utm_crs_for",
]
