"""Bias calibration from files: photons + reference -> a calibration JSON (DESIGN 1.10).

The one core call behind ``canopyblocks calibrate --method bias`` and the QGIS algorithm:
read every requested track, compute blocks with the chosen estimators, validate them
against the corridor rasters or the footprint-matched ALS reference, and fit
:func:`~canopyblocks.validation.bias_calibration.fit_bias_calibration` per block length
and beam strength, with its parity hold-out error.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..blocks import BlockParams
from ..errors import InputError
from ..progress import Progress, as_progress
from ..validation.bias_calibration import BiasCalibration, BiasKind, fit_bias_calibration
from ..validation.calibration import CutoffCalibration, calibrate_against_reference

if TYPE_CHECKING:
    from ..blocks.estimators import Estimators

__all__ = ["calibrate_bias_file", "calibrate_reference_rasters", "write_cutoff_calibration",
           "write_bias_calibration"]


def calibrate_bias_file(
    photons: str | os.PathLike[str],
    params: BlockParams,
    estimators: Estimators | None = None,
    *,
    dtm: str | os.PathLike[str] | None = None,
    dsm_max: str | os.PathLike[str] | None = None,
    dsm_p90: str | os.PathLike[str] | None = None,
    points: Sequence[str | os.PathLike[str]] = (),
    reference: str = "corridor",
    width: float | None = None,
    beams: Sequence[str] = (),
    channel: int | str | None = None,
    crs: Any = None,
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    photon_vertical_crs: Any = None,
    kind: BiasKind = "additive",
    by_strength: bool = True,
    progress: Progress | None = None,
) -> BiasCalibration:
    """Fit a bias calibration of hmax/h90 for blocks made with ``estimators``.

    Parameters
    ----------
    photons : path
        ATL03 / MABEL / photon table (every beam, or ``beams``).
    params : BlockParams
        Block lengths (one model per length).
    estimators : Estimators, optional
        The estimators the calibration is valid for (recorded; applying it to blocks made
        with others is refused); default the recommended ones (the ``atl08`` preset).
    dtm, dsm_max, dsm_p90 : path
        Corridor reference rasters (``reference="corridor"``).
    points : sequence of path
        Airborne tiles (``reference="footprint"``: footprint-matched reference).
    width : float, optional
        Corridor width (m) of the raster reference; recorded. Default the footprint of
        the photons' sensor (ICESat-2 13 m, MABEL 2 m).
    kind : "additive" or "linear"
    by_strength : bool
        One model per beam strength (ATL03 strong/weak); else one for all tracks.

    Returns
    -------
    BiasCalibration
        Write it with :func:`~canopyblocks.validation.bias_calibration.write_bias_calibration`.
    """
    from ..blocks.estimators import default_estimators
    from ..reference.sensor_width import corridor_width
    from ..validation.block_validation import raster_horizontal_crs, validate_blocks
    from .blocks import read_tracks, run_blocks, track_strengths

    prog = as_progress(progress)
    if reference not in ("corridor", "footprint"):
        raise InputError(f"reference must be 'corridor' or 'footprint'; got {reference!r}")
    if reference == "corridor" and (dtm is None or dsm_max is None or dsm_p90 is None):
        raise InputError("the corridor reference needs --dtm, --dsm-max and --dsm-p90")
    if reference == "footprint" and not points:
        raise InputError("the footprint reference needs the airborne tiles (--points)")
    if points:  # the survey as every command takes it (folders, patterns, .vpc, COPC, EPT)
        from .rasters import survey_tiles

        points = survey_tiles(points)
    if crs is None and dtm is not None:
        horizontal = raster_horizontal_crs(dtm)
        crs = None if horizontal is None else horizontal.to_wkt()
    tracks = read_tracks(photons, beams=beams, channel=channel, crs=crs,
                         min_signal_conf=params.min_signal_conf, progress=prog.sub(0.0, 0.2))
    if estimators is None:
        estimators = default_estimators()
    if reference == "corridor":
        width = corridor_width(width, [t.track for t in tracks], source=str(photons))
    blocks, _ = run_blocks(tracks, params, estimators=estimators, progress=prog.sub(0.2, 0.5))
    if reference == "footprint":
        from ..reference.footprint_params import FootprintReferenceParams
        from ..validation.footprints import validate_blocks_footprint

        val = validate_blocks_footprint(blocks, list(points),
                                        params=FootprintReferenceParams.icesat2(),
                                        geoid=geoid, offset=offset,
                                        photon_vertical_crs=photon_vertical_crs,
                                        progress=prog.sub(0.5, 0.9))
    else:
        val = validate_blocks(blocks, dtm=dtm, dsm_max=dsm_max,  # type: ignore[arg-type]
                              dsm_p90=dsm_p90, width=width,  # type: ignore[arg-type]
                              geoid=geoid, offset=offset,
                              photon_vertical_crs=photon_vertical_crs,
                              progress=prog.sub(0.5, 0.9))
    residuals = val.residuals
    if "estimators" not in residuals.columns:   # validation keeps the block columns it uses
        residuals = residuals.assign(estimators=estimators.label())
    strengths = track_strengths(photons, tracks) if by_strength else {}
    n_photons = float(np.nansum(blocks["n_photons"])) if len(blocks) else 0.0
    noise_share = (1.0 - float(np.nansum(blocks["n_kept"])) / n_photons) if n_photons else None
    cal = fit_bias_calibration(residuals, kind=kind, strengths=strengths or None,
                               preset=estimators.name, noise_level=noise_share,
                               corridor_width=width if reference == "corridor" else None,
                               reference=reference, sources=(Path(photons).name,))
    prog.update(1.0, "calibrated")
    return cal


def calibrate_reference_rasters(
    photons: str,
    params: BlockParams,
    *,
    dtm: str,
    dsm_max: str,
    dsm_p90: str,
    width: float | None = None,
    beam: str | None = None,
    channel: int | str | None = None,
    crs: object = None,
    geoid: str | None = None,
    offset: float | None = None,
    progress: Progress | None = None,
) -> CutoffCalibration:
    """Read one track, compute blocks with the paper's method, take reference values from
    the rasters, and calibrate the paper's cut-offs.

    Parameters
    ----------
    photons : path
        ATL03 / MABEL / table photon file; one track (``beam`` / ``channel``).
    params : BlockParams
        Lengths and everything but the cut-offs.
    dtm, dsm_max, dsm_p90 : path
        Reference GeoTIFFs on one grid (metres).
    width : float, optional
        Corridor width, metres; default the footprint of the photons' sensor (ICESat-2
        13 m, MABEL 2 m).
    crs : CRS-like, optional
        Metric CRS for the photons; default the DTM's horizontal CRS.
    """
    from ..blocks.estimators import preset
    from ..validation.block_validation import raster_horizontal_crs, validate_blocks
    from .blocks import read_tracks, run_blocks

    prog = as_progress(progress)
    if crs is None:  # the DTM's (refused with a clear message when missing or unreadable)
        horizontal = raster_horizontal_crs(dtm)
        crs = None if horizontal is None else horizontal.to_wkt()
    tracks = read_tracks(photons, beams=() if beam is None else (beam,), channel=channel,
                         crs=crs, min_signal_conf=params.min_signal_conf,
                         progress=prog.sub(0.0, 0.1))
    track = tracks[0]
    blocks, _ = run_blocks([track], params, estimators=preset("paper"),
                           progress=prog.sub(0.1, 0.2))
    val = validate_blocks(blocks, dtm=dtm, dsm_max=dsm_max, dsm_p90=dsm_p90, width=width,
                          geoid=geoid, offset=offset, progress=prog.sub(0.2, 0.5))
    return calibrate_against_reference(track, val.residuals, params, progress=prog.sub(0.5, 1.0))


def write_cutoff_calibration(cal: CutoffCalibration, output: str | os.PathLike[str]) -> None:
    """Write the fitted cut-offs table (``cal.table``) to ``output`` (.csv, .parquet, or
    .gpkg layer ``calibration``), atomically."""
    from ..outputs.tables import write_table

    write_table(cal.table, output, layer="calibration")


def write_bias_calibration(cal: BiasCalibration, output: str | os.PathLike[str]) -> None:
    """Write a bias calibration as JSON (what ``blocks --calibration`` reads), atomically."""
    from ..validation.bias_calibration import write_bias_calibration as write

    write(cal, output)
