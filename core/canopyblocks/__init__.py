"""canopyblocks: canopy height and ground per along-track block from lidar profiles.

Data flow: readers -> photons -> blocks|waveforms -> reference -> validation -> outputs
-> workflows (one module per command) -> cli|qgis_plugin.
Public functions are re-exported here; see ``docs/ARCHITECTURE.md``.
"""

from __future__ import annotations

import importlib
import logging
from typing import TYPE_CHECKING, Any

from . import _aliases
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

_aliases.install()  # old module paths (canopyblocks.track_blocks, ...) keep working

if TYPE_CHECKING:  # loaded on first use, see __getattr__
    from .atomic import atomic_output
    from .blocks import (
        BlockParams,
        CalibrationResult,
        calibrate_cutoffs,
        compute_blocks,
        default_cutoffs,
    )
    from .blocks.atl08_classify import classify_photons
    from .blocks.atl08_segments import atl08_segments
    from .blocks.estimators import (
        PRESETS,
        RECOMMENDED_PRESET,
        Estimators,
        estimate_blocks,
        preset,
    )
    from .blocks.uncertainty import left_out_summary, sigma_model
    from .geo import utm_crs_for
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
    from .validation import (
        BiasCalibration,
        CoregParams,
        CoregResult,
        FootprintValidation,
        ValidationResult,
        apply_bias_calibration,
        apply_offset,
        block_stats,
        compute_residuals,
        coregister,
        error_stats,
        fit_bias_calibration,
        read_bias_calibration,
        validate_atl08,
        validate_blocks,
        validate_footprints,
        write_bias_calibration,
    )
    from .waveforms import WaveformBatch, WaveformParams, process_waveforms
    from .waveforms.dual_wavelength import DualParams, dual_wavelength_ground
    from .waveforms.esfl import EsflCubes, EsflParams, esfl_chain
    from .workflows.batch import BatchConfig, BatchResult, run_batch
    from .workflows.blocks import BlocksResult, blocks_from_file, read_tracks
    from .workflows.calibrate import calibrate_bias_file
    from .workflows.chain.result import ChainResult
    from .workflows.chain.run import run_chain
    from .workflows.coregister import coregister_file, write_offsets
    from .workflows.segments import segments_from_file
    from .workflows.validate import FileValidation, validate_file

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

# Everything but the exceptions loads on first use: ``import canopyblocks`` and the
# command line start in a fraction of a second, and the heavy imports (numpy, geopandas,
# pyproj, ...) happen inside a command, where Ctrl-C or SIGTERM end it with one line.
_LAZY: dict[str, str] = {
    "BlockParams": ".blocks",
    "CalibrationResult": ".blocks",
    "calibrate_cutoffs": ".blocks",
    "compute_blocks": ".blocks",
    "default_cutoffs": ".blocks",
    "utm_crs_for": ".geo",
    "atomic_output": ".atomic",
    "Atl03BeamData": ".outputs.h5_layouts",
    "MabelChannelData": ".outputs.h5_layouts",
    "write_atl03": ".outputs.h5_layouts",
    "write_mabel": ".outputs.h5_layouts",
    "read_blocks": ".outputs.tables",
    "read_layer": ".outputs.tables",
    "write_layers": ".outputs.tables",
    "write_table": ".outputs.tables",
    "PhotonTrack": ".photons",
    "along_track_distance": ".photons",
    "Progress": ".progress",
    "BeamInfo": ".readers",
    "atl03_beams": ".readers",
    "file_info": ".readers",
    "mabel_channels": ".readers",
    "open_track": ".readers",
    "read_atl03": ".readers",
    "read_las": ".readers",
    "read_mabel": ".readers",
    "read_table": ".readers",
    "FootprintReferenceParams": ".reference",
    "Grid": ".reference",
    "ReferenceRasters": ".reference",
    "atl08_reference_values": ".reference",
    "block_corridors": ".reference",
    "block_footprint_reference": ".reference",
    "block_reference_values": ".reference",
    "block_terrain": ".reference",
    "check_vertical_datums": ".reference",
    "find_pdal": ".reference",
    "footprint_reference": ".reference",
    "horn_slope_aspect": ".reference",
    "make_reference_rasters": ".reference",
    "read_atl08_segments": ".reference",
    "run_pipeline": ".reference",
    "SimParams": ".simulate",
    "SimTrack": ".simulate",
    "Simulation": ".simulate",
    "line_through": ".simulate",
    "seed002_experiment": ".simulate",
    "simulate_photons": ".simulate",
    "BlocksResult": ".workflows.blocks",
    "blocks_from_file": ".workflows.blocks",
    "read_tracks": ".workflows.blocks",
    "BiasCalibration": ".validation",
    "CoregParams": ".validation",
    "CoregResult": ".validation",
    "FileValidation": ".workflows.validate",
    "FootprintValidation": ".validation",
    "ValidationResult": ".validation",
    "apply_bias_calibration": ".validation",
    "apply_offset": ".validation",
    "block_stats": ".validation",
    "calibrate_bias_file": ".workflows.calibrate",
    "compute_residuals": ".validation",
    "coregister": ".validation",
    "coregister_file": ".workflows.coregister",
    "error_stats": ".validation",
    "fit_bias_calibration": ".validation",
    "read_bias_calibration": ".validation",
    "validate_atl08": ".validation",
    "validate_blocks": ".validation",
    "validate_file": ".workflows.validate",
    "validate_footprints": ".validation",
    "write_bias_calibration": ".validation",
    "write_offsets": ".workflows.coregister",
    "ChainResult": ".workflows.chain.result",
    "run_chain": ".workflows.chain.run",
    "Estimators": ".blocks.estimators",
    "PRESETS": ".blocks.estimators",
    "preset": ".blocks.estimators",
    "estimate_blocks": ".blocks.estimators",
    "RECOMMENDED_PRESET": ".blocks.estimators",
    "classify_photons": ".blocks.atl08_classify",
    "atl08_segments": ".blocks.atl08_segments",
    "sigma_model": ".blocks.uncertainty",
    "left_out_summary": ".blocks.uncertainty",
    "segments_from_file": ".workflows.segments",
    "BatchConfig": ".workflows.batch",
    "BatchResult": ".workflows.batch",
    "run_batch": ".workflows.batch",
    "WaveformBatch": ".waveforms",
    "WaveformParams": ".waveforms",
    "process_waveforms": ".waveforms",
    "EsflCubes": ".waveforms.esfl",
    "EsflParams": ".waveforms.esfl",
    "esfl_chain": ".waveforms.esfl",
    "DualParams": ".waveforms.dual_wavelength",
    "dual_wavelength_ground": ".waveforms.dual_wavelength",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


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
    "RECOMMENDED_PRESET",
    "classify_photons",
    "atl08_segments",
    "sigma_model",
    "left_out_summary",
    "segments_from_file",
    # waveforms (GEDI and the seed-003/004 instruments)
    "WaveformBatch",
    "WaveformParams",
    "process_waveforms",
    "EsflCubes",
    "EsflParams",
    "esfl_chain",
    "DualParams",
    "dual_wavelength_ground",
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
