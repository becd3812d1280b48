"""canopyblocks: canopy height and ground per along-track block from lidar profiles.

Data flow: readers -> photons -> blocks -> reference -> validation -> outputs.
Public functions are re-exported here; see ``docs/ARCHITECTURE.md``.
"""

from __future__ import annotations

import logging

from .blocks import (
    BlockParams,
    CalibrationResult,
    calibrate_cutoffs,
    compute_blocks,
    default_cutoffs,
)
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
from .outputs.h5_layouts import Atl03BeamData, MabelChannelData, write_atl03, write_mabel
from .outputs.tables import read_blocks, read_layer, write_layers, write_table
from .photons import PhotonTrack, along_track_distance
from .progress import Progress
from .readers import (
    BeamInfo,
    atl03_beams,
    file_info,
    mabel_channels,
    open_track,
    read_atl03,
    read_las,
    read_mabel,
    read_table,
)
from .reference import (
    FootprintReferenceParams,
    Grid,
    ReferenceRasters,
    atl08_reference_values,
    block_corridors,
    block_footprint_reference,
    block_reference_values,
    block_terrain,
    check_vertical_datums,
    find_pdal,
    footprint_reference,
    horn_slope_aspect,
    make_reference_rasters,
    read_atl08_segments,
    run_pipeline,
)
from .simulate import (
    SimParams,
    SimTrack,
    Simulation,
    line_through,
    seed002_experiment,
    simulate_photons,
)
from .track_blocks import BlocksResult, blocks_from_file, read_tracks
from .validation import (
    BiasCalibration,
    CoregParams,
    CoregResult,
    FileValidation,
    FootprintValidation,
    ValidationResult,
    apply_bias_calibration,
    apply_offset,
    block_stats,
    calibrate_bias_file,
    compute_residuals,
    coregister,
    coregister_file,
    error_stats,
    fit_bias_calibration,
    read_bias_calibration,
    validate_atl08,
    validate_blocks,
    validate_file,
    validate_footprints,
    write_bias_calibration,
    write_offsets,
)
from .whole_chain import ChainResult, run_chain

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

# Parts with heavy imports (scipy.stats, the batch runner, the waveform package) load on
# first use, so that the command line starts quickly.
_LAZY = {
    "Estimators": ".blocks.estimators", "PRESETS": ".blocks.estimators",
    "preset": ".blocks.estimators", "estimate_blocks": ".blocks.estimators",
    "BatchConfig": ".batch", "BatchResult": ".batch", "run_batch": ".batch",
    "WaveformBatch": ".waveforms", "WaveformParams": ".waveforms",
    "process_waveforms": ".waveforms",
}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

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
    # readers
    "BeamInfo",
    "atl03_beams",
    "file_info",
    "mabel_channels",
    "open_track",
    "read_atl03",
    "read_las",
    "read_mabel",
    "read_table",
    # layouts (writers of ATL03 / MABEL-shaped files)
    "Atl03BeamData",
    "MabelChannelData",
    "write_atl03",
    "write_mabel",
    # blocks
    "BlockParams",
    "CalibrationResult",
    "calibrate_cutoffs",
    "compute_blocks",
    "default_cutoffs",
    "Estimators",
    "PRESETS",
    "preset",
    "estimate_blocks",
    # waveforms (GEDI and the seed-003/004 instruments)
    "WaveformBatch",
    "WaveformParams",
    "process_waveforms",
    # many granules
    "BatchConfig",
    "BatchResult",
    "run_batch",
    # file -> layers
    "BlocksResult",
    "blocks_from_file",
    "read_tracks",
    # reference
    "Grid",
    "ReferenceRasters",
    "atl08_reference_values",
    "block_corridors",
    "block_reference_values",
    "block_terrain",
    "check_vertical_datums",
    "find_pdal",
    "FootprintReferenceParams",
    "footprint_reference",
    "block_footprint_reference",
    "horn_slope_aspect",
    "make_reference_rasters",
    "read_atl08_segments",
    "run_pipeline",
    # validation
    "ValidationResult",
    "FileValidation",
    "validate_file",
    "FootprintValidation",
    "validate_footprints",
    "CoregParams",
    "CoregResult",
    "coregister",
    "coregister_file",
    "write_offsets",
    "apply_offset",
    "BiasCalibration",
    "fit_bias_calibration",
    "apply_bias_calibration",
    "read_bias_calibration",
    "write_bias_calibration",
    "calibrate_bias_file",
    "block_stats",
    "compute_residuals",
    "error_stats",
    "validate_atl08",
    "validate_blocks",
    # simulator
    "SimParams",
    "Simulation",
    "SimTrack",
    "line_through",
    "seed002_experiment",
    "simulate_photons",
    # whole chain
    "ChainResult",
    "run_chain",
]
