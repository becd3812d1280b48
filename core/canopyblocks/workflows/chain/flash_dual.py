"""The whole chain for flash-lidar (ESFL) cubes and dual-wavelength pairs: simulated (or
given) file and airborne tiles -> footprints -> validation against the airborne points ->
layers, maps and an HTML report that leads with the answer (what ``canopyblocks run
--sensor esfl|dual`` does, and ``run --photons FILE`` with such a file).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from ...atomic import check_writable, new_files_removed_on_failure
from ...errors import InputError
from ...progress import Progress, as_progress

__all__ = ["run_sensor_chain", "waveform_chain", "SENSOR_NAMES"]

log = logging.getLogger(__name__)

#: ``run --sensor`` value -> (product, words for a user).
SENSOR_NAMES = {"esfl": ("ESFL", "flash-lidar (ESFL) cubes"),
                "dual": ("dual", "dual-wavelength waveform pairs")}


_SENSOR_WORDS = {"height": "canopy height", "ground": "ground elevation",
                 "top": "canopy top elevation"}


#: The dual pair's independent comparison: the points' own values under the footprint.
_DUAL_POINTS = {"ground": "ref_ground_points", "height": "ref_height_points",
                "top": "ref_top_points"}
_ESFL_REF = ("the independent airborne points under each 5 m cell's pixels (ground = the "
             "class-2 TIN averaged over the pixel centres, top = the highest point)")
_DUAL_POINTS_WORDS = ("the independent airborne points under each footprint (ground = the "
                      "footprint-weighted mean of the class-2 ground points; height = the "
                      "footprint-weighted RH98 of all points above them)")
_DUAL_FORMED = ("the airborne points formed into the noise-free waveform pair the sensor "
                "would record (22 m Gaussian footprint) and read by the same ground finder")


def _sensor_summary(val: Any, product: str, out: Path, source: str, *,
                    simulated: tuple[float, int] | None, words: str,
                    warned: Sequence[str] = ()) -> tuple[pd.DataFrame, list[str], Any]:
    """The facts of an ESFL/dual run (``facts.csv``), its terminal lines and its
    report's summary section, all from the one table: the independent airborne points
    first, then (dual) the pair formed from them and read alike."""
    from ...outputs.report import ReportSection
    from .waveform_report import (
        FORMED,
        INTERVAL_WORDS,
        POINTS,
        facts_lines,
        facts_sentence,
        footprint_counts,
        footprint_facts,
        own_reference_label,
        simulated_words,
        warnings_paragraph,
    )

    res = val.residuals
    pairs = {m: f"ref_{m}" for m in ("height", "ground", "top")
             if m in res.columns and f"ref_{m}" in res.columns}
    diameter = float(val.stats["length"].iloc[0]) if "length" in val.stats and \
        len(val.stats) else float("nan")
    esfl = product == "ESFL"
    facts = footprint_facts(res, pairs=pairs, metrics=tuple(pairs), diameter=diameter,
                            estimators=product, layer="stats_footprints", out=out,
                            reference=POINTS if esfl else FORMED,
                            points=None if esfl else {m: c for m, c in _DUAL_POINTS.items()
                                                      if c in res},
                            size_name="cell_size" if esfl else "footprint_diameter")
    ind, own = facts[facts["reference"] == POINTS], facts[facts["reference"] != POINTS]
    formed = own_reference_label(simulated is not None, "waveform") + ": " + _DUAL_FORMED
    lines = [*facts_lines(ind, _SENSOR_WORDS, _ESFL_REF if esfl else _DUAL_POINTS_WORDS),
             *facts_lines(own, _SENSOR_WORDS, ("the round trip (not an independent check), "
                                               if simulated is not None else "")
                          + _DUAL_FORMED)]
    paras = [] if simulated is None else [simulated_words(words, source,
                                                          azimuth=simulated[0],
                                                          seed=simulated[1])]
    paras.append(warnings_paragraph(warned))
    said = facts_sentence(ind, _SENSOR_WORDS)
    if said:
        paras.append(f"Against {_ESFL_REF if esfl else _DUAL_POINTS_WORDS}: {said}.")
    own_said = facts_sentence(own, _SENSOR_WORDS)
    if own_said:
        paras.append(f"{formed}: {own_said}.")
    if not (said or own_said):
        paras.append("No footprint could be compared with the airborne reference.")
    paras.append(footprint_counts(ind if esfl else own, "height"))
    paras.append(INTERVAL_WORDS.replace("waveform value", "value") + " facts.csv holds "
                 "every number of this summary.")
    return facts, lines, ReportSection("Summary", [p for p in paras if p])


def _simulate_file(las_paths: Sequence[Any], out: Path, sensor: str, *, azimuth: float,
                   seed: int, noise: float | None, progress: Progress) -> Path:
    """An ESFL or dual file simulated over the tiles (``noise``: sd as a share of the
    peak; default the simulator's), ``out/<sensor>.h5``."""
    from ...simulate.sensor_files import simulate_sensor_over_tiles

    params: Any = None
    if noise is not None:
        if sensor == "esfl":
            from ...simulate.flash_cubes import FlashSimParams

            params = FlashSimParams(noise_sd=float(noise))
        else:
            from ...simulate.sensor_files import DualAlsParams

            params = DualAlsParams(noise=float(noise))
    path = out / f"{sensor}.h5"
    simulate_sensor_over_tiles(list(las_paths), sensor, path, azimuth=azimuth, seed=seed,
                               params=params, progress=progress)
    return path


def _esfl_words(p: Any, noise: float | None) -> tuple[str, str]:
    """The ESFL reading's settings (``p``: EsflParams) and its simulation's, in words."""
    from ...simulate.flash_cubes import FlashSimParams

    s = FlashSimParams() if noise is None else FlashSimParams(noise_sd=float(noise))
    return (f"Reading: energy fraction f = {p.fraction:g} of the brightest pixel; grid "
            f"cell {p.cell:g} m; noise fit {p.noise_fit}; threshold = noise mean + "
            f"{p.k:g} sd.",
            f"noise sd {s.noise_sd:g} of the mean brightest-pixel peak, per pixel and bin; "
            f"footprints {s.footprint:g} m across, every {s.spacing:g} m; {s.pixels} x "
            f"{s.pixels} pixels of {s.pixel_size:g} m; {s.bin_size:g} m bins; a "
            f"{s.pulse_ns:g} ns pulse.")


def _dual_words(d: Any, noise: float | None) -> tuple[str, str]:
    """The dual reading's settings (``d``: DualParams) and its simulation's, in words."""
    from ...simulate.sensor_files import DualAlsParams

    a = DualAlsParams() if noise is None else DualAlsParams(noise=float(noise))
    return (f"Reading: the dual-wavelength method '{d.method}'; threshold = noise mean + "
            f"{d.k:g} sd.",
            f"noise sd {a.noise:g} of each pair's near-infrared peak; reflectances "
            f"(visible, near-infrared) of leaves {a.leaf[0]:g}, {a.leaf[1]:g} and of soil "
            f"{a.soil[0]:g}, {a.soil[1]:g}; a Gaussian footprint of sigma {a.sigma:g} m, "
            f"every {a.spacing:g} m; {a.bin_size:g} m bins.")


def sensor_settings(product: str, options: Any, path: Any, noise: float | None,
                    simulated: bool) -> str:
    """The simulation's and the reading's settings, in words, for the report's Inputs."""
    from ..waveforms_flash_dual import SensorOptions

    opts = options or SensorOptions()
    reading, sim = (_esfl_words(opts.esfl_params(path), noise) if product == "ESFL"
                    else _dual_words(opts.dual_params(path), noise))
    return f"Simulation settings: {sim} {reading}" if simulated else reading


def run_sensor_chain(
    las_paths: Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    path: str | os.PathLike[str] | None = None,
    sensor: str | None = None,
    azimuth: float = 0.0,
    seed: int = 0,
    noise: float | None = None,
    options: Any = None,
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    progress: Progress | None = None,
) -> Any:
    """ESFL or dual file (simulated over the tiles when ``path`` is None) -> footprints
    -> validation -> report.

    Parameters
    ----------
    las_paths : sequence of path
        Airborne LAS/LAZ tiles (metric CRS; class 2 = ground).
    out_dir : path
        Output folder: ``<sensor>.h5`` (when simulated), ``footprints.gpkg`` (layers
        ``footprints``, and ``pixels`` for ESFL), ``validation.gpkg`` (layers
        ``residuals_footprints``, ``stats_footprints``), ``stats.csv``, ``plots/`` and
        ``report.html``.
    path : path, optional
        An ESFL or dual file; None simulates one with ``sensor``.
    sensor : {"esfl", "dual"}, optional
        What to simulate (``path`` None).
    azimuth : float
        Simulated track direction, degrees clockwise from north, through the tiles' centre.
    seed : int
        Simulation seed.
    noise : float, optional
        Simulated noise sd as a share of the peak (ESFL: per pixel and bin, of the mean
        brightest-pixel peak; dual: of each pair's near-infrared peak); default the
        simulator's (0.05).
    options : SensorOptions, optional
        The chain's options (:class:`~canopyblocks.workflows.waveforms_flash_dual.SensorOptions`).
    geoid, offset
        Vertical conversion of the footprint heights to the tiles' datum (a simulated file
        keeps the tiles' own: none needed).

    Returns
    -------
    ChainResult
    """
    from ...arguments import check_paths
    from ...outputs.footprint_maps import plot_footprint_map
    from ...outputs.report import write_report
    from ...outputs.tables import write_layers, write_table
    from ...readers.flash_dual import waveform_product
    from ...readers.las import las_crs
    from ...schema import LAYER_FOOTPRINTS
    from ...validation.flash_footprints import validate_sensor_footprints
    from ...validation.footprints import LAYER_RESIDUALS_FOOTPRINTS, LAYER_STATS_FOOTPRINTS
    from ..waveforms_flash_dual import LAYER_PIXELS, sensor_footprints
    from .result import ChainResult

    check_paths(las_paths, "run_sensor_chain: las_paths", "a LAS/LAZ path or a list of them")
    if path is None and sensor not in SENSOR_NAMES:
        raise InputError(f"sensor must be one of {', '.join(SENSOR_NAMES)} to simulate; got "
                         f"{sensor!r}")
    prog = as_progress(progress)
    out = check_writable(out_dir, folder=True)
    tiles = [Path(p) for p in las_paths]
    from .waveform_report import input_warnings, without_unsupported

    with new_files_removed_on_failure(out), input_warnings() as warned:
        out.mkdir(parents=True, exist_ok=True)
        simulated = path is None
        if path is None:
            path = _simulate_file(las_paths, out, str(sensor), azimuth=azimuth, seed=seed,
                                  noise=noise, progress=prog.sub(0.0, 0.3))
            if geoid is None and offset is None:
                offset = 0.0   # simulated heights are the tiles' own: one datum by construction
        elif noise is not None:
            raise InputError("the noise level is a simulation's: give it without a file")
        product = waveform_product(path)
        if product not in ("ESFL", "dual"):
            raise InputError(f"{path} is {product}: this chain takes ESFL cubes or "
                             "dual-wavelength pairs")
        prog.update(0.3, "footprints")
        layers = sensor_footprints(path, product, options=options, crs=las_crs(tiles[0]),
                                   progress=prog.sub(0.3, 0.55))
        footprints = write_layers(layers, out / "footprints.gpkg")
        fp = layers[LAYER_FOOTPRINTS]
        prog.update(0.55, "validation")
        val = validate_sensor_footprints(fp, tiles, pixels=layers.get(LAYER_PIXELS),
                                         geoid=geoid, offset=offset,
                                         progress=prog.sub(0.55, 0.9))
        validation = write_layers({LAYER_RESIDUALS_FOOTPRINTS: val.residuals,
                                   LAYER_STATS_FOOTPRINTS: val.stats},
                                  out / "validation.gpkg")
        write_table(val.stats.rename(columns={"length": "cell_size" if product == "ESFL"
                                              else "footprint_diameter"}),
                    out / "stats.csv", layer="stats")
        plots_dir = out / "plots"
        plots_dir.mkdir(exist_ok=True)
        maps = [plot_footprint_map(val.residuals, c, plots_dir / f"footprints_{c}.png")
                for c in ("res_height", "res_ground")]
        prog.update(0.95, "report")
        words = SENSOR_NAMES["esfl" if product == "ESFL" else "dual"][1]
        facts, lines, summary = _sensor_summary(val, product, out, Path(path).name,
                                                simulated=(azimuth, seed) if simulated
                                                else None, words=words, warned=warned())
        from ..waveform_report import sensor_report_sections
        from .glossary import gedi_glossary_section

        sections = [summary, *sensor_report_sections(
            fp, val, product=product, source=Path(path).name, simulated=simulated,
            tiles=[t.name for t in tiles], words=words, maps=maps,
            stats=without_unsupported(val.stats),
            settings=sensor_settings(product, options, path, noise if simulated else None,
                                     simulated)),
            gedi_glossary_section(["independent airborne quantities",
                                   *(["round trip"] if simulated and product == "dual"
                                     else []), "bias", "RMSE", "95 % interval", "R² (heights only)",
                                   "random seed", "reference outside"], reference="")]
        report = write_report(out / "report.html", f"canopyblocks: {words} against the "
                              "airborne lidar",
                              sections)
        prog.update(1.0, "done")
        return ChainResult(out_dir=out, photons=Path(path), blocks=footprints, rasters={},
                           validation=validation, report=report, plots=maps,
                           stats=val.stats, simulated=simulated, summary=lines)


def waveform_chain(las_paths: Sequence[Any], out_dir: Any, photons: Any, sensor: str, *,
                   beams: Sequence[str], azimuth: float, seed: int, geoid: Any,
                   offset: float | None, options: Any, noise: float | None,
                   progress: Progress) -> Any:
    """What ``run`` does with waveforms: the GEDI chain for a GEDI L1B file (or
    ``sensor="gedi"``, simulated), :func:`run_sensor_chain` for an ESFL or dual file (or
    ``sensor="esfl"|"dual"``); None for photons (the photon chain's)."""
    if sensor not in ("icesat2", "gedi", "esfl", "dual"):
        raise InputError(f"sensor must be icesat2, gedi, esfl or dual; got {sensor!r}")
    if photons is not None and sensor != "icesat2":
        raise InputError("give either a file to process or a sensor to simulate, not both")
    if sensor in ("esfl", "dual"):
        return run_sensor_chain(las_paths, out_dir, sensor=sensor, azimuth=azimuth,
                                seed=seed, noise=noise, options=options, geoid=geoid,
                                offset=offset, progress=progress)
    if noise is not None or options is not None:
        raise InputError("the noise level and the flash-lidar / dual-wavelength options "
                         "apply to --sensor esfl and dual (or their files) only")
    from .waveforms import run_waveform_chain

    if sensor == "gedi":
        from ...simulate.sensor_files import simulate_sensor_over_tiles

        out = check_writable(out_dir, folder=True)
        out.mkdir(parents=True, exist_ok=True)
        l1b = out / "gedi_l1b.h5"
        simulate_sensor_over_tiles(list(las_paths), "gedi", l1b, azimuth=azimuth, seed=seed,
                                   progress=progress.sub(0.0, 0.2))
        return run_waveform_chain(las_paths, out_dir, l1b, progress=progress.sub(0.2, 1.0),
                                  simulated=(azimuth, seed))
    if photons is not None and str(photons).lower().endswith((".h5", ".hdf5")):
        from ...readers.flash_dual import flash_dual_sensor
        from ...readers.gedi import is_gedi_l1b

        if flash_dual_sensor(photons) is not None:
            return run_sensor_chain(las_paths, out_dir, path=photons, geoid=geoid,
                                    offset=offset, options=options, progress=progress)
        if is_gedi_l1b(photons):   # full-waveform lidar: footprints, not blocks
            return run_waveform_chain(las_paths, out_dir, photons, beams=beams,
                                      geoid=geoid, offset=offset, progress=progress)
    return None   # photons (or not a file at all: the photon reader says why)
