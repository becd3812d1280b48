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

import numpy as np

from ..errors import InputError
from ..geo import from_metric
from ..outputs.h5_layouts import Atl03BeamData, MabelChannelData, write_atl03, write_mabel
from ..outputs.tables import write_table
from ..schema import LAYER_PHOTONS
from .engine import PHOTON_TRUTH_COLUMNS, Simulation

__all__ = ["atl03_beam_data", "write_simulation_atl03", "write_simulation_mabel",
           "write_photon_table", "truth_extra"]

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
