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
from ...readers.remote import is_url, source_name

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
    from ...outputs.report import ReportSection, write_report
    from ...outputs.tables import write_layers, write_table
    from ...validation.footprints import (
        FOOTPRINT_METRICS,
        LAYER_RESIDUALS_FOOTPRINTS,
        LAYER_STATS_FOOTPRINTS,
        validate_footprints,
    )
    from ..waveforms import footprints_from_l1b
    from .glossary import glossary_section
    from .report import datum_sentence
    from .result import ChainResult
    from .waveform_report import (
        _WORDS,
        MIN_GROUP,
        facts_lines,
        footprint_facts,
        simulated_words,
        waveform_stats_tables,
        waveform_summary_section,
    )

    prog = as_progress(progress)
    out = check_writable(out_dir, folder=True)
    tiles = [Path(p) for p in las_paths]
    with new_files_removed_on_failure(out):
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
                                estimators=f"GEDI L2A {getattr(params, 'setting', 'a1')}",
                                layer=LAYER_STATS_FOOTPRINTS, out=out)
        from .tiles import _tiles_crs, _vertical_name

        tiles_datum = _vertical_name(_tiles_crs(tiles))
        maps = write_footprint_plots(val.residuals, plots_dir, datum=tiles_datum)
        prog.update(0.95, "report")
        flags = fp["flag"].value_counts().rename_axis("flag").reset_index(name="footprints")
        setting = getattr(params, "setting", "a1")
        beams_used = sorted(str(b) for b in fp["beam"].unique()) if "beam" in fp else []
        sections = [
            waveform_summary_section(
                val.stats, source=Path(l1b).name, n_footprints=len(fp), beams=beams_used,
                tiles=tiles, setting=setting, facts=facts,
                simulated="" if simulated is None else simulated_words(
                    "GEDI", Path(l1b).name, azimuth=simulated[0], seed=simulated[1])),
            ReportSection("Inputs", [
                f"GEDI L1B waveforms from {source_name(l1b)}, processed with the GEDI L2A "
                f"algorithm (setting {setting}).",
                "Airborne tiles: " + ", ".join(t.name for t in tiles) + "; vertical datums: "
                + datum_sentence(val.datum, geoid=geoid, offset=offset, tiles=tiles_datum,
                                 what="waveforms")]),
            ReportSection("Footprints", [
                f"{len(fp)} footprints (layer 'footprints' of footprints.gpkg: ground, top, "
                "RH25-RH100, cover (fraction), penetration, flags)."],
                {"footprints per flag": flags}, wave_plots[:6]),
            ReportSection("Validation against the airborne lidar", [
                "Each footprint is compared with the airborne points weighted by a Gaussian "
                "footprint: ground, RH98, RH50 (m) and cover (fraction). Residual = waveform "
                "value minus reference value. Groups by beam, aspect, slope (degrees) and "
                "reference cover class (a fraction of the footprint); groups of fewer than "
                f"{MIN_GROUP} footprints are left out of the tables (the maps show every "
                "footprint)."],
                waveform_stats_tables(val.stats), maps),
            glossary_section(["RH98", "footprint-matched airborne reference", "bias", "RMSE",
                              "95 % interval", "R²", "L1B / L2A", "cover", "aspect class",
                              "slope class", "reference outside", "random seed"]),
        ]
        report = write_report(out / "report.html", "canopyblocks: GEDI footprints and "
                              "validation", sections)
        prog.update(1.0, "done")
        return ChainResult(out_dir=out, photons=str(l1b) if is_url(l1b) else Path(l1b), blocks=footprints, rasters={},
                           validation=validation, report=report,
                           plots=[*wave_plots, *maps], stats=val.stats,
                           simulated=simulated is not None,
                           summary=facts_lines(facts, _WORDS,
                                               "the footprint-matched airborne reference"))
