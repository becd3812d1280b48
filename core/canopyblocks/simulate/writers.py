"""Write simulated photons: ATL03- and MABEL-layout HDF5, GeoParquet/GeoPackage/CSV.

The HDF5 layouts come from :mod:`canopyblocks.outputs.h5_layouts` (shared with every
other writer), so ``read_atl03``/``read_mabel`` read the files like real granules.
Positions are converted from the cloud's CRS to WGS84 lat/lon; heights are written
as simulated, i.e. **in the airborne cloud's vertical datum**, not the WGS84
ellipsoid a real granule uses.  The ATL03-layout file says so: ``h_ph``'s description
and the file attribute ``canopyblocks_height_crs`` name that datum
(``Simulation.vertical_datum``, e.g. ``EPSG:5713`` for CGVD28).

ATL03-layout files also carry, as real granules do, ``orbit_info/sc_orient`` chosen so
that the beams carry the simulated strength under the real layout's rule (backward:
left beams strong; forward: right beams strong), ``signal_conf_ph`` graded from the
photons alone (:mod:`~canopyblocks.simulate.confidence`) and ``bckgrd_atlas`` with the
background rate per 50-shot span.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..atomic import atomic_outputs, check_writable
from ..errors import InputError
from ..geo import from_metric
from ..outputs.h5_layouts import (
    Atl03Background,
    Atl03BeamData,
    MabelChannelData,
    write_atl03,
    write_mabel,
)
from ..outputs.tables import check_output_path, write_table
from ..progress import Progress, as_progress
from ..schema import LAYER_PHOTONS
from .confidence import signal_confidence
from .engine import PHOTON_TRUTH_COLUMNS, SHOTS_PER_BACKGROUND_SUM, Simulation

if TYPE_CHECKING:
    from .analysis import Seed002Result

__all__ = ["atl03_beam_data", "write_simulation_atl03", "write_simulation_mabel",
           "write_photon_table", "truth_extra", "write_seed002_report",
           "check_simulation_outputs", "write_simulation_outputs", "PHOTON_SUFFIXES"]

PHOTON_SUFFIXES = (".h5", ".hdf5", ".parquet", ".geoparquet", ".gpkg", ".csv")
"""Suffixes of a simulated photon file: HDF5 (ATL03/MABEL layout) or a table."""

log = logging.getLogger(__name__)

_ATL03_BEAMS = ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")

def sc_orient_for(beam: str, strength: str) -> int:
    """``orbit_info/sc_orient`` under which ``beam`` has ``strength`` in real granules
    (0 backward: left beams strong; 1 forward: right beams strong)."""
    return 1 if (strength == "strong") == beam.endswith("r") else 0


def background_of(sim: Simulation, realisation: int = 0) -> Atl03Background:
    """The ``bckgrd_atlas`` rows of one realisation: per 50 shots, the start time, the
    rate (photons/s), the background photons counted and the telemetry window."""
    k = SHOTS_PER_BACKGROUND_SUM
    first = np.arange(0, sim.n_shots, k)
    known = sim.background_rate()
    c = sim.photon_columns(realisation)
    noisy = np.asarray(c["noise"], bool)
    counts = np.bincount(c["shot"][noisy] // k, minlength=first.size)[:first.size]
    top = height = None
    if sim.telemetry_top is not None and sim.telemetry_bottom is not None:
        ok = np.isfinite(sim.telemetry_top)
        shots = np.flatnonzero(ok)
        if shots.size:  # spans before/after the cloud keep the nearest window
            top = np.interp(first, shots, sim.telemetry_top[ok])
            height = np.interp(first, shots, (sim.telemetry_top - sim.telemetry_bottom)[ok])
    return Atl03Background(delta_time=known.time, rate=known.rate, counts=counts,
                           tlm_top=top, tlm_height=height)


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
    centre in WGS84, ``signal_conf`` graded from the photons alone
    (:func:`~canopyblocks.simulate.confidence.signal_confidence`, never the truth;
    the ``noise`` truth column tells noise photons apart), ``background`` the
    background rate per 50 shots (:func:`background_of`).
    """
    c = sim.photon_columns(realisation)
    lon, lat = from_metric(c["x"], c["y"], sim.crs)
    return Atl03BeamData(delta_time=c["time"], lat=lat, lon=lon, h=c["h"], s=c["s"],
                         signal_conf=signal_confidence(c["s"], c["h"]),
                         extra=truth_extra(c), strength=sim.params.beam,
                         background=background_of(sim, realisation))


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
        (``gt1r``), then the other beams of the same side (which carry the same
        strength in a real granule), then the rest.

    ``orbit_info/sc_orient`` is chosen so that the first beam carries the simulated
    strength under the real layout's rule (a strong ``gt1r``: forward, 1). Beams of
    the other side hold photons of the same simulated strength: ``atlas_beam_type``
    states that strength and a log warning says the layout rule is broken for them.
    The file is byte-identical for the same simulation (no timestamps are stored).
    """
    reals = list(realisations)
    if not reals:
        raise InputError("give at least one realisation to write")
    strength = sim.params.beam
    if beams is None:
        first = sim.track.name if sim.track.name in _ATL03_BEAMS else "gt1r"
        side = first[-1]
        names = ([first] + [b for b in _ATL03_BEAMS if b != first and b[-1] == side]
                 + [b for b in _ATL03_BEAMS if b[-1] != side])
        if len(reals) > len(names):
            raise InputError(f"an ATL03 file holds at most 6 beams; got {len(reals)} "
                             "realisations: write several files")
        beams = names[:len(reals)]
    if len(beams) != len(reals):
        raise InputError(f"{len(beams)} beam names for {len(reals)} realisations")
    data = {b: atl03_beam_data(sim, r) for b, r in zip(beams, reals)}
    orient = sc_orient_for(beams[0], strength) if beams[0] in _ATL03_BEAMS else 0
    other = [b for b in beams if b in _ATL03_BEAMS and sc_orient_for(b, strength) != orient]
    if other:
        log.warning("%s: %s hold %s-beam photons although a real granule of this "
                    "orientation has %s beams there", path, ", ".join(other), strength,
                    "weak" if strength == "strong" else "strong")
    out = write_atl03(path, data, sc_orient=orient, height_crs=sim.vertical_datum)
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

    ``truth_residuals.csv`` (one row per footprint diameter), ``residuals_by_cover.csv``,
    ``residuals_by_cover.png`` and ``truth_<d>m.csv`` (per-footprint truth, metres in
    the cloud's CRS and vertical datum) per diameter.
    """
    from .plots import plot_cover_residuals

    out = Path(folder)
    check_writable(out, folder=True)
    written = []
    with atomic_outputs():
        written.append(write_table(result.table, out / "truth_residuals.csv"))
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
