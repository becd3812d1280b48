"""The whole chain in one call: photons (read or simulated) and airborne tiles ->
block heights -> PDAL reference rasters -> validation -> layers, plots, HTML report.

This is what ``canopyblocks run`` and the README's demo execute.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ...atomic import check_writable, new_files_removed_on_failure
from ...blocks import BlockParams
from ...blocks.estimators import RECOMMENDED_PRESET
from ...errors import InputError
from ...progress import Progress, as_progress
from .result import ChainResult

__all__ = ["ChainResult", "run_chain"]

log = logging.getLogger(__name__)


def run_chain(
    las_paths: Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    photons: str | os.PathLike[str] | None = None,
    beams: Sequence[str] = (),
    channel: int | str | None = None,
    atl08: str | os.PathLike[str] | None = None,
    azimuth: float = 0.0,
    diameter: float = 13.0,
    photon_rate: str = "temperate",
    seed: int = 0,
    params: BlockParams | None = None,
    width: float | None = None,
    resolution: float = 2.0,
    ground: str = "class2",
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    calibrate: bool = False,
    realisations: int = 100,
    estimators: Any = None,
    calibration: Any = None,
    compare_preset: str | None = RECOMMENDED_PRESET,
    coregister: bool = False,
    footprint_reference: bool = True,
    progress: Progress | None = None,
    preset: str | None = None,
    sensor: str = "icesat2",
    sensor_options: Any = None,
    noise: float | None = None,
) -> ChainResult:
    """Run photons -> blocks -> reference rasters -> validation -> report.

    Parameters
    ----------
    las_paths : sequence of path
        Airborne LAS/LAZ tiles (metric CRS) covering the track.
    out_dir : path
        Output folder: ``photons_atl03.h5`` (when simulated), ``blocks.gpkg``,
        ``rasters/{dtm,dsm_max,dsm_p90}.tif``, ``validation.gpkg`` (layers ``residuals``,
        ``stats``), ``stats.csv``, ``plots/*.png``, ``report.html``.
    photons : path, optional
        ATL03 / MABEL / table photon file, or a GEDI L1B file (then the chain is
        :func:`~canopyblocks.workflows.chain.waveforms.run_waveform_chain`: footprints validated
        against the tiles).  When None, ICESat-2 photons are simulated
        over the tiles along a line at ``azimuth`` degrees through the survey centre,
        with ``diameter`` m footprints and the ``photon_rate`` (``boreal``, ``temperate``,
        ``tropical``; as ``simulate(..., preset=)`` of the simulation parameters).
    preset : str, optional
        Deprecated name of ``photon_rate`` (a FutureWarning; it will be removed).
    params : BlockParams, optional
        Default: lengths 10, 25 and 50 m (seed 001).
    width : float, optional
        Corridor width, m; default the footprint of the photons' sensor (ICESat-2 13 m,
        MABEL 2 m: :mod:`canopyblocks.reference.sensor_width`; a photon table of no known
        sensor needs it) and ``diameter`` for simulated photons.
    resolution : float
        Reference raster cell size, m.
    geoid, offset
        Vertical conversion of real photon heights (ellipsoidal) to the tiles' datum.
    realisations : int
        Simulated runs only: photon draws per footprint diameter (13 and 17 m) for the
        study of the photon classification against truth (``truth_residuals.csv``,
        ``plots/truth_residuals_by_cover.png``); 0 skips it.
    calibrate : bool
        Also fit the cut-offs to the reference (DESIGN.md 1.7; first track), recompute the
        blocks with them and validate again: layers ``residuals_calibrated`` and
        ``stats_calibrated``, table ``calibration.csv`` with held-out RMSEs.
    estimators : Estimators, optional
        Block estimators (DESIGN 1.10); default the recommended ones (the ``atl08``
        preset); ``preset("paper")`` for the paper's method.
    calibration : path or BiasCalibration, optional
        Bias calibration applied to the blocks.
    compare_preset : str, optional
        With other estimators than the recommended ones: also compute the blocks with this
        preset (default the recommended one,
        :data:`~canopyblocks.blocks.estimators.RECOMMENDED_PRESET`); with the recommended
        ones: also the paper's method, for its own section. Validated like the user's
        (layers ``residuals_<preset>``, ``stats_<preset>``, with the footprint reference
        also ``residuals_footprint_<preset>``, ``stats_footprint_<preset>``). The report
        leads with the recommended estimators against the footprint-matched reference;
        their bias calibration, fitted against that reference, is written
        (``bias_calibration_<preset>.json``) and offered only when it improves the
        held-out error. None skips the second set.
    coregister : bool
        Search the joint geolocation offset of the blocks against the DTM/DSM and
        validate the horizontally shifted blocks (DESIGN 2.8); ``offsets.json``, layer
        ``stats_uncorrected``.
    footprint_reference : bool
        Validate also against the footprint-matched airborne reference (DESIGN 2.7; the
        default): the like-with-like reference the report and the summary lead with
        (ground = mean footprint ground, top = ground + RH98 of footprints of
        ``diameter`` m over the airborne points); layers ``residuals_footprint``,
        ``stats_footprint``.  False leads with the corridor maximum.
    sensor : {"icesat2", "gedi", "esfl", "dual"}
        What to simulate without ``photons``: ICESat-2 photons (default), GEDI waveforms,
        flash-lidar (ESFL) cubes or dual-wavelength pairs; the waveform sensors go
        through :func:`~canopyblocks.workflows.chain.waveforms.run_waveform_chain` or
        :func:`~canopyblocks.workflows.chain.flash_dual.run_sensor_chain` (as does an
        ESFL or dual file given as ``photons``).
    sensor_options : SensorOptions, optional
        ESFL and dual: the chain's options (``canopyblocks waveforms``'s).
    noise : float, optional
        ESFL and dual simulations: noise sd as a share of the peak (default 0.05).
    """
    from ...arguments import check_path, check_paths
    check_paths(las_paths, "run_chain: las_paths", "a LAS/LAZ path or a non-empty list of them")
    check_path(out_dir, "run_chain: out_dir", "a folder path")
    from ...outputs.profile_plot import plot_profile  # noqa: F401  (fails early without matplotlib)
    from .stages import (
        RunState,
        blocks_stage,
        calibration_stage,
        photons_stage,
        rasters_stage,
        report_stage,
        validation_stage,
        write_stage,
    )

    if preset is not None:
        import warnings

        warnings.warn("run_chain(preset=) is deprecated; use photon_rate=", FutureWarning,
                      stacklevel=2)
        photon_rate = preset
    prog = as_progress(progress)
    from ...readers.las import refuse_urls
    from .flash_dual import waveform_chain

    tiles = [las_paths] if isinstance(las_paths, (str, os.PathLike)) else list(las_paths)
    refuse_urls(tiles)  # the chain reads local tiles: a URL is named, never mangled

    waveform = waveform_chain(las_paths, out_dir, photons, sensor, beams=beams,
                               azimuth=azimuth, seed=seed, geoid=geoid, offset=offset,
                               options=sensor_options, noise=noise, progress=prog)
    if waveform is not None:
        return waveform
    out = check_writable(out_dir, folder=True)
    for name, value in (("width", width), ("resolution", resolution),
                        ("diameter", diameter)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a positive number of metres; got {value!r}")
    options = {"photons": photons, "beams": beams, "channel": channel, "atl08": atl08,
               "azimuth": azimuth, "diameter": diameter, "photon_rate": photon_rate,
               "seed": seed, "width": width, "resolution": resolution, "ground": ground,
               "geoid": geoid, "offset": offset, "calibrate": calibrate,
               "realisations": realisations, "estimators": estimators,
               "calibration": calibration, "compare_preset": compare_preset,
               "coregister": coregister, "footprint_reference": footprint_reference}
    with new_files_removed_on_failure(out):
        out.mkdir(parents=True, exist_ok=True)
        st = RunState(out=out, tiles=[Path(p) for p in tiles],
                      params=params or BlockParams(lengths=(10.0, 25.0, 50.0)),
                      options=options, prog=prog)
        for stage in (photons_stage, blocks_stage, rasters_stage, validation_stage,
                      calibration_stage, write_stage):
            stage(st)
        return report_stage(st)
