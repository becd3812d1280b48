"""Write simulated photons: ATL03- and MABEL-layout HDF5, GeoParquet/GeoPackage/CSV.

The HDF5 layouts come from :mod:`canopyblocks.outputs.h5_layouts` (shared with every
other writer), so ``read_atl03``/``read_mabel`` read the files like real granules.
Positions are converted from the cloud's CRS to WGS84 lat/lon; heights are written
as simulated, i.e. **in the airborne cloud's vertical datum**, not the WGS84
ellipsoid a real granule uses.  Keep track of that datum (``Simulation.vertical_datum``,
e.g. ``EPSG:5713`` for CGVD28) when comparing the photons with other data.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..geo import from_metric
from ..outputs.atomic import atomic_outputs, check_writable
from ..outputs.h5_layouts import Atl03BeamData, MabelChannelData, write_atl03, write_mabel
from ..outputs.tables import check_output_path, write_table
from ..progress import Progress, as_progress
from ..schema import LAYER_PHOTONS
from .engine import PHOTON_TRUTH_COLUMNS, Simulation

if TYPE_CHECKING:
    from .analysis import Seed002Result

__all__ = ["atl03_beam_data", "write_simulation_atl03", "write_simulation_mabel",
           "write_photon_table", "truth_extra", "write_seed002_report",
           "check_simulation_outputs", "write_simulation_outputs", "PHOTON_SUFFIXES"]

PHOTON_SUFFIXES = (".h5", ".hdf5", ".parquet", ".geoparquet", ".gpkg", ".csv")
"""Suffixes of a simulated photon file: HDF5 (ATL03/MABEL layout) or a table."""

log = logging.getLogger(__name__)

_ATL03_BEAMS = ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")


def truth_extra(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per-photon truth columns for a file (booleans stored as int8 0/1)."""
    out = {}
    for k in PHOTON_TRUTH_COLUMNS:
        v = np.asarray(cols[k])
        out[k] = v.astype(np.int8) if v.dtype == bool else v
    return out


def atl03_beam_data(sim: Simulation, realisation: int = 0) -> Atl03BeamData:
    """One realisation as :class:`~canopyblocks.outputs.h5_layouts.Atl03BeamData`.

    ``delta_time`` = shot index / pulse rate (seconds from the first shot), ``s`` =
    distance along the simulated track (metres), lat/lon = the reported footprint
    centre in WGS84, ``signal_conf`` = 4 for every photon (no signal finding is
    simulated; the ``noise`` truth column tells noise photons apart).
    """
    c = sim.photon_columns(realisation)
    lon, lat = from_metric(c["x"], c["y"], sim.crs)
    return Atl03BeamData(delta_time=c["time"], lat=lat, lon=lon, h=c["h"], s=c["s"],
                         signal_conf=None, extra=truth_extra(c), strength=sim.params.beam)


def write_simulation_atl03(sim: Simulation, path: str | os.PathLike[str], *,
                           realisations: Sequence[int] = (0,),
                           beams: Sequence[str] | None = None) -> Path:
    """Write realisations as beams of an ATL03-layout HDF5 file (atomically).

    Parameters
    ----------
    sim : Simulation
    path : path-like
        Output ``.h5``.
    realisations : sequence of int
        Which realisations to write (default the first), one beam each.
    beams : sequence of str, optional
        Beam names, one per realisation; default the track's name for the first
        (``gt1r``) and the remaining ATL03 beams in order for the others.

    The file is byte-identical for the same simulation (no timestamps are stored).
    """
    reals = list(realisations)
    if not reals:
        raise InputError("give at least one realisation to write")
    if beams is None:
        first = sim.track.name if sim.track.name in _ATL03_BEAMS else "gt1r"
        names = [first] + [b for b in _ATL03_BEAMS if b != first]
        if len(reals) > len(names):
            raise InputError(f"an ATL03 file holds at most 6 beams; got {len(reals)} "
                             "realisations: write several files")
        beams = names[:len(reals)]
    if len(beams) != len(reals):
        raise InputError(f"{len(beams)} beam names for {len(reals)} realisations")
    data = {b: atl03_beam_data(sim, r) for b, r in zip(beams, reals)}
    out = write_atl03(path, data, sc_orient=0 if sim.params.beam == "strong" else 1)
    log.info("wrote simulated ATL03-layout photons to %s", out)
    return out


def write_simulation_mabel(sim: Simulation, path: str | os.PathLike[str], *,
                           realisations: Sequence[int] = (0,),
                           channels: Sequence[int] | None = None) -> Path:
    """Write realisations as channels of a MABEL L2A-layout HDF5 file (atomically).

    Channels default to 1, 2, ...; ``shot_num`` numbers the shots from 1.
    """
    reals = list(realisations)
    chans = list(channels) if channels is not None else list(range(1, len(reals) + 1))
    if not reals or len(chans) != len(reals):
        raise InputError(f"{len(chans)} channels for {len(reals)} realisations")
    data = {}
    for ch, r in zip(chans, reals):
        c = sim.photon_columns(r)
        lon, lat = from_metric(c["x"], c["y"], sim.crs)
        shot = c["shot"]
        new = np.concatenate([[True], shot[1:] != shot[:-1]]) if shot.size else np.zeros(0, bool)
        first = np.maximum.accumulate(np.where(new, np.arange(shot.size), 0))
        pid = np.arange(shot.size) - first + 1
        data[int(ch)] = MabelChannelData(delta_time=c["time"], lat=lat, lon=lon, elev=c["h"],
                                         shot_num=shot + 1, photon_id=pid,
                                         extra=truth_extra(c))
    return write_mabel(path, data)


def write_photon_table(sim: Simulation, path: str | os.PathLike[str], *,
                       realisation: int | None = None) -> Path:
    """Photons with truth as GeoParquet/GeoPackage/CSV (by suffix), in the cloud's CRS.

    ``realisation=None`` writes every realisation (column ``realisation``).
    """
    gdf = sim.photon_frame(realisation)
    return write_table(gdf, path, layer=LAYER_PHOTONS)


def write_seed002_report(folder: str | os.PathLike[str], result: Seed002Result) -> list[Path]:
    """The seed-002 report files in ``folder``, all or none.

    ``seed002_table.csv`` (one row per footprint diameter), ``residuals_by_cover.csv``,
    ``residuals_by_cover.png`` and ``truth_<d>m.csv`` (per-footprint truth, metres in
    the cloud's CRS and vertical datum) per diameter.
    """
    from .plots import plot_cover_residuals

    out = Path(folder)
    check_writable(out, folder=True)
    written = []
    with atomic_outputs():
        written.append(write_table(result.table, out / "seed002_table.csv"))
        written.append(write_table(result.cover, out / "residuals_by_cover.csv"))
        written.append(plot_cover_residuals(result, out / "residuals_by_cover.png"))
        for d, sim in result.simulations.items():
            frame = sim.truth_frame().drop(columns="geometry")
            written.append(write_table(frame, out / f"truth_{d:g}m.csv"))
    return written


def check_simulation_outputs(output: str | os.PathLike[str], *,
                             photon_table: str | os.PathLike[str] | None = None,
                             report: str | os.PathLike[str] | None = None) -> None:
    """Refuse unusable output paths of :func:`write_simulation_outputs` before simulating.

    Raises
    ------
    InputError
        ``output`` has no photon-file suffix (:data:`PHOTON_SUFFIXES`), ``photon_table``
        no table suffix, or two outputs are the same file.
    FileFormatError
        A path cannot be written (folder missing rights, a file where a folder is).
    """
    out = Path(output)
    if out.suffix.lower() not in PHOTON_SUFFIXES:
        raise InputError(f"output {out}: use .h5 (ATL03/MABEL layout) or .parquet/.gpkg/.csv")
    check_writable(out)
    if photon_table is not None:
        check_output_path(photon_table)
        if Path(photon_table).absolute() == out.absolute():
            raise InputError(f"--photons {photon_table} is also the main output; give "
                             "another file name")
    if report is not None:
        check_writable(report, folder=True)


def write_simulation_outputs(result: Seed002Result, output: str | os.PathLike[str], *,
                             layout: str = "atl03",
                             diameter: float | None = None,
                             photon_table: str | os.PathLike[str] | None = None,
                             report: str | os.PathLike[str] | None = None,
                             progress: Progress | None = None) -> list[Path]:
    """Every output of ``canopyblocks simulate``, written all or none.

    Parameters
    ----------
    result : Seed002Result
    output : path-like
        The photons of the first realisation: ``.h5``/``.hdf5`` in the ATL03 or MABEL
        layout (``layout``), or a ``.parquet``/``.gpkg``/``.csv`` table with truth.
    layout : {"atl03", "mabel"}
    diameter : float, optional
        Which simulation (footprint diameter, metres) goes to the files; default the
        first.
    photon_table : path-like, optional
        Every realisation's photons with truth (a table).
    report : path-like, optional
        Folder for :func:`write_seed002_report`.
    progress : Progress, optional
        Checked between the files and once more before they are renamed into place: a
        cancellation while writing leaves none of them.

    Returns
    -------
    list of Path
        The files written.
    """
    prog = as_progress(progress)
    check_simulation_outputs(output, photon_table=photon_table, report=report)
    if not result.simulations:
        raise InputError("the simulation result holds no simulation to write")
    d = next(iter(result.simulations)) if diameter is None else float(diameter)
    if d not in result.simulations:
        raise InputError(f"no simulation with a {d:g} m footprint; the result has "
                         f"{', '.join(f'{k:g}' for k in result.simulations)} m")
    sim = result.simulations[d]
    out = Path(output)
    written: list[Path] = []
    n_steps = 1 + (photon_table is not None) + (report is not None)
    with atomic_outputs(progress=prog):
        prog.update(0.0, f"writing {out.name}")
        if out.suffix.lower() in (".h5", ".hdf5"):
            if layout == "mabel":
                written.append(write_simulation_mabel(sim, out))
            elif layout == "atl03":
                written.append(write_simulation_atl03(sim, out))
            else:
                raise InputError(f"layout must be 'atl03' or 'mabel'; got {layout!r}")
        else:
            written.append(write_photon_table(sim, out, realisation=0))
        step = 1
        if photon_table is not None:
            prog.update(step / n_steps, f"writing {Path(photon_table).name}")
            written.append(write_photon_table(sim, photon_table, realisation=None))
            step += 1
        if report is not None:
            prog.update(step / n_steps, "writing the report")
            written.extend(write_seed002_report(report, result))
    prog.report(1.0, "written")  # committed: too late to cancel
    return written
