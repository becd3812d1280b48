"""The whole chain for full-waveform lidar: GEDI L1B and airborne tiles -> footprints ->
footprint-matched validation -> layers, plots, HTML report (what ``canopyblocks run``
does when ``--photons`` is a GEDI L1B file).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ...atomic import check_writable, new_files_removed_on_failure
from ...progress import Progress, as_progress
from ...readers.remote import is_url

__all__ = ["run_waveform_chain"]

log = logging.getLogger(__name__)


def run_waveform_chain(
    las_paths: Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    l1b: str | os.PathLike[str],
    *,
    beams: Sequence[str] = (),
    params: Any = None,
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    photon_vertical_crs: Any = None,
    progress: Progress | None = None,
    simulated: tuple[float, int] | None = None,
) -> Any:
    """GEDI L1B + airborne tiles -> ``footprints.gpkg``, ``validation.gpkg`` (layers
    ``residuals_footprints``, ``stats_footprints``), ``stats.csv``, ``plots/`` (footprint
    maps over the tiles, scatter, waveform plots) and ``report.html`` in ``out_dir``.

    Parameters
    ----------
    las_paths : sequence of path
        Airborne LAS/LAZ tiles under the footprints (metric CRS).
    l1b : path
        GEDI L1B granule or subset (or a simulated one).
    params : WaveformParams, optional
    geoid, offset, photon_vertical_crs
        The datum rule: GEDI elevations are WGS84-ellipsoidal; a simulated file states the
        tiles' datum it keeps (``photon_vertical_crs`` None: the file's own).
    simulated : (azimuth, seed), optional
        The L1B file was simulated over the tiles (``run --sensor gedi``): the report says
        so first.

    Returns
    -------
    ChainResult
    """
    from ...outputs.footprint_maps import write_footprint_plots
    from ...outputs.report import write_report
    from ...outputs.tables import write_layers, write_table
    from ...validation.footprints import (
        FOOTPRINT_METRICS,
        LAYER_RESIDUALS_FOOTPRINTS,
        LAYER_STATS_FOOTPRINTS,
        validate_footprints,
    )
    from ..waveforms import footprints_from_l1b
    from .result import ChainResult
    from .waveform_report import (
        _WORDS,
        POINT_COLUMNS,
        POINTS,
        POINTS_WORDS,
        facts_lines,
        footprint_facts,
        gedi_sections,
        input_warnings,
    )

    prog = as_progress(progress)
    out = check_writable(out_dir, folder=True)
    tiles = [Path(p) for p in las_paths]
    with new_files_removed_on_failure(out), input_warnings() as warned:
        out.mkdir(parents=True, exist_ok=True)
        plots_dir = out / "plots"
        plots_dir.mkdir(exist_ok=True)
        from ...readers.las import las_crs

        crs = las_crs(tiles[0])
        fp, wave_plots = footprints_from_l1b(l1b, beams=beams or None, params=params, crs=crs,
                                             plots_dir=plots_dir,
                                             progress=prog.sub(0.0, 0.4))
        footprints = write_layers({"footprints": fp}, out / "footprints.gpkg")
        prog.update(0.4, "footprint validation")
        val = validate_footprints(fp, tiles, geoid=geoid, offset=offset,
                                  photon_vertical_crs=photon_vertical_crs,
                                  progress=prog.sub(0.4, 0.85))
        validation = write_layers({LAYER_RESIDUALS_FOOTPRINTS: val.residuals,
                                   LAYER_STATS_FOOTPRINTS: val.stats},
                                  out / "validation.gpkg")
        write_table(val.stats.rename(columns={"length": "footprint_diameter"}),
                    out / "stats.csv", layer="stats")
        diameter = float(val.stats["length"].iloc[0]) if len(val.stats) else 22.0
        facts = footprint_facts(val.residuals, pairs=FOOTPRINT_METRICS,
                                metrics=tuple(FOOTPRINT_METRICS), diameter=diameter,
                                points={m: c for m, c in POINT_COLUMNS.items()
                                        if c in val.residuals},
                                estimators=f"GEDI L2A {getattr(params, 'setting', 'a1')}",
                                layer=LAYER_STATS_FOOTPRINTS, out=out)
        from .tiles import _tiles_crs, _vertical_name

        tiles_datum = _vertical_name(_tiles_crs(tiles))
        maps = write_footprint_plots(val.residuals, plots_dir, datum=tiles_datum)
        prog.update(0.95, "report")
        reference = str(val.residuals["reference"].iloc[0]) \
            if "reference" in val.residuals and len(val.residuals) else "points"
        sections = gedi_sections(fp, val, facts, l1b=l1b, tiles=tiles, params=params,
                                 reference=reference,
                                 simulated=simulated, geoid=geoid, offset=offset,
                                 tiles_datum=tiles_datum, wave_plots=wave_plots, maps=maps,
                                 warned=warned())
        report = write_report(out / "report.html", "canopyblocks: GEDI footprints against "
                              "the airborne lidar", sections)
        prog.update(1.0, "done")
        return ChainResult(out_dir=out, photons=str(l1b) if is_url(l1b) else Path(l1b), blocks=footprints, rasters={},
                           validation=validation, report=report,
                           plots=[*wave_plots, *maps], stats=val.stats,
                           simulated=simulated is not None,
                           summary=[*facts_lines(facts[facts["reference"] == POINTS],
                                                 _WORDS, POINTS_WORDS),
                                    *facts_lines(facts[facts["reference"] != POINTS], _WORDS,
                                                 "the points formed into waveforms ("
                                                 + ("round trip)" if simulated else
                                                    "like with like)"))])
