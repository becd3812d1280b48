"""Simulations from airborne tiles to sensor files: the workflows of ``canopyblocks
simulate`` and of the QGIS simulation algorithms.

:func:`simulate_photons_over_tiles` (the command: every diameter's realisations against
truth, the photon file, optional photon table and report), :func:`simulate_photon_file`
(the QGIS algorithm: one realisation as an ATL03-layout file) and
:func:`simulate_sensor_over_tiles` (GEDI, flash and dual-wavelength waveforms).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..progress import Progress, as_progress

if TYPE_CHECKING:
    from ..simulate import SimParams, SimTrack

__all__ = ["simulate_photons_over_tiles", "simulate_photon_file", "simulate_sensor_over_tiles",
           "track_from"]


def track_from(las: Sequence[str | os.PathLike[str]], *,
               vertices: Sequence[tuple[float, float]] | None = None,
               azimuth: float | None = None, centre: tuple[float, float] | None = None,
               inset: float = 0.0, bounds: tuple[float, float, float, float] | None = None
               ) -> SimTrack:
    """The simulated track: through ``vertices`` (metres in the tiles' CRS), else a line at
    ``azimuth`` degrees clockwise from grid north through ``centre`` (default the middle of
    the tiles' extent, ``bounds`` when known), ``inset`` metres inside it."""
    from ..readers.las import las_bounds
    from ..simulate import SimTrack, line_through

    if vertices is not None:
        return SimTrack(tuple((float(x), float(y)) for x, y in vertices))
    box = bounds if bounds is not None else las_bounds(list(las))
    return line_through(box, float(azimuth or 0.0), inset=inset, centre=centre)


def simulate_photons_over_tiles(
    las: Sequence[str | os.PathLike[str]], output: str | os.PathLike[str], params: SimParams,
    *, vertices: Sequence[tuple[float, float]] | None = None, azimuth: float | None = None,
    centre: tuple[float, float] | None = None, diameters: Sequence[float] = (),
    realisations: int = 100, seed: int = 0, crs: Any = None, layout: str = "atl03",
    photon_table: str | os.PathLike[str] | None = None,
    report: str | os.PathLike[str] | None = None, progress: Progress | None = None,
) -> tuple[Any, SimTrack]:
    """Photons simulated along a track over airborne tiles (``canopyblocks simulate``).

    Every output is checked before the work and written all or none after it: the photon
    file at ``output`` (``layout`` atl03 or mabel; the first diameter's first realisation),
    ``photon_table`` (every realisation's photons with truth) and the ``report`` folder.
    Only the corridor the footprints reach is read from the tiles (``crs``: the tiles' CRS
    when they state none). Returns the experiment (its ``table`` of errors against truth,
    its ``simulations`` by diameter) and the track.
    """
    from ..readers.cloud_checks import refuse_all_noise
    from ..readers.las import read_las
    from ..simulate import seed002_experiment
    from ..simulate.writers import check_simulation_outputs, write_simulation_outputs

    prog = as_progress(progress)
    diams = tuple(float(d) for d in diameters) or (float(params.diameter),)  # type: ignore[arg-type]
    out = Path(output)
    check_simulation_outputs(out, photon_table=photon_table, report=report)
    track = track_from(las, vertices=vertices, azimuth=azimuth, centre=centre,
                       inset=max(diams) / 2.0)
    reach = max(diams) / 2.0 + 1.0  # read only the corridor the footprints can reach
    vx, vy = zip(*track.vertices)
    bbox = (min(vx) - reach, min(vy) - reach, max(vx) + reach, max(vy) + reach)
    pts = read_las(list(las), crs=crs, bbox=bbox, progress=prog.sub(0.0, 0.2))
    refuse_all_noise(pts.classification, ", ".join(str(p) for p in las),
                     params.exclude_classes)
    result = seed002_experiment(pts, track, params, diameters=diams,
                                realisations=realisations, seed=seed,
                                progress=prog.sub(0.2, 0.9))
    write_simulation_outputs(result, out, layout=layout, diameter=diams[0],
                             photon_table=photon_table, report=report,
                             progress=prog.sub(0.9, 1.0))
    prog.report(1.0, "done")
    return result, track


def simulate_photon_file(
    las: Sequence[str | os.PathLike[str]], output: str | os.PathLike[str], params: SimParams,
    *, vertices: Sequence[tuple[float, float]] | None = None, azimuth: float = 0.0,
    seed: int = 0, progress: Progress | None = None,
) -> Any:
    """One realisation of photons over airborne tiles written as an ATL03-layout file at
    ``output`` (the QGIS algorithm); returns the simulation (``photon_track()`` gives its
    photons with truth). The track: ``vertices`` (tiles' CRS), else a line at ``azimuth``
    through the tiles' extent, half a footprint inside it."""
    from ..readers.las import read_las
    from ..simulate import simulate_photons
    from ..simulate.writers import write_simulation_atl03

    prog = as_progress(progress)
    points = read_las(list(las), progress=prog.sub(0.0, 0.3))
    track = track_from(las, vertices=vertices, azimuth=azimuth, bounds=points.bounds,
                       inset=float(params.diameter) / 2.0)  # type: ignore[arg-type]
    sim = simulate_photons(points, track, params, seed=seed, progress=prog.sub(0.3, 0.85))
    write_simulation_atl03(sim, output)
    return sim


def simulate_sensor_over_tiles(las: Sequence[str | os.PathLike[str]], sensor: str,
                               output: str | os.PathLike[str], *,
                               vertices: Sequence[tuple[float, float]] | None = None,
                               **kw: Any) -> tuple[SimTrack, dict[str, object]]:
    """GEDI, ESFL flash or dual-wavelength waveforms over airborne tiles as a file
    (``simulate --sensor gedi|esfl|dual`` and the QGIS algorithm): the simulator's
    :func:`~canopyblocks.simulate.sensor_files.simulate_sensor_over_tiles`, with the
    track given as ``vertices`` (metres in the tiles' CRS) or the keywords it takes."""
    from ..simulate import SimTrack
    from ..simulate.sensor_files import simulate_sensor_over_tiles as simulate

    if vertices is not None:
        kw["track"] = SimTrack(tuple((float(x), float(y)) for x, y in vertices))
    return simulate(list(las), sensor, output, **kw)
