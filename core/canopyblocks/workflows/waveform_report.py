"""The report sections of the flash-lidar (ESFL) and dual-wavelength chains, after the
summary that leads with the answer (:mod:`canopyblocks.workflows.chain.flash_dual`):
inputs and method, footprints per flag, the statistics and the maps."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

__all__ = ["sensor_report_sections", "METHOD_WORDS"]

#: What each chain does, in the papers' terms (one paragraph each).
METHOD_WORDS = {
    "ESFL": ("The flash-lidar paper's chain: per footprint the pixels of the 4 x 4 region "
             "whose energy reaches the fraction f of the brightest; the pixels merged into "
             "one waveform per 5 m grid cell; noise from a Gaussian fitted to each "
             "waveform's histogram, threshold mean + 4 sd; terrain = the lowest Gaussian "
             "above it, top = the highest sample above it; outliers (terrain 10 m below its "
             "neighbours, heights over 60 m) flagged; terrain filtered by multiscale "
             "curvature classification; height = top - terrain."),
    "dual": ("The dual-wavelength paper's ground finder: the visible / near-infrared ratio "
             "of each pair, smoothed at decreasing widths; the single maximum of its "
             "gradient is the ground start, the last sample above noise the ground end, "
             "ground = their mean; tree height = first return above noise to the ground "
             "start."),
}


def sensor_report_sections(fp: pd.DataFrame, val: Any, *, product: str, source: str,
                           simulated: bool, tiles: Sequence[str], words: str,
                           maps: Sequence[Path], settings: str = "",
                           stats: pd.DataFrame | None = None) -> list[Any]:
    """Inputs, footprints and comparison sections (``val``: a FootprintValidation;
    ``settings``: the simulation's and the reading's, in words; ``stats``: the
    statistics to show, default ``val.stats``)."""

    from ..outputs.report import ReportSection

    flags = fp["flag"].value_counts().rename_axis("flag").reset_index(name="footprints")
    kind = "simulated over the tiles" if simulated else "read"
    ref = ("Reference: the airborne points under each row's pixels: ground = the class-2 "
           "TIN averaged over the pixel centres, top = the highest point, height = top - "
           "ground." if product == "ESFL" else
           "Reference: the airborne points under a Gaussian footprint of sigma 5.5 m (22 m) "
           "formed into the visible/near-infrared pair the sensor would record (leaf and "
           "soil reflectances, the 4 ns pulse, no noise) and read by the same ground finder "
           "with the simulated noise level's thresholds: ground = its ground centre, "
           "height = its tree height (first return above noise to the ground start), top = "
           "its first return above noise.")
    from ..outputs.report import footprint_stats_table

    stats = footprint_stats_table(val.stats if stats is None else stats).rename(
        columns={"n (blocks)": "n (footprints)", "sd": "SD (m)",
                 "footprint diameter (m)": "footprint or cell size (m)"})
    return [
        ReportSection("Inputs and method", [p for p in [
            f"{words.capitalize()} {kind}: {source}. Airborne tiles: {', '.join(tiles)}; "
            f"vertical datums: {val.datum}.", settings, METHOD_WORDS[product]] if p]),
        ReportSection("Footprints", [
            f"{len(fp)} rows (layer 'footprints' of footprints.gpkg: ground, top, height, "
            "flag" + ("; layer 'pixels': the pixels each row merges)." if product == "ESFL"
                      else ").")], {"rows per flag": flags}),
        ReportSection("Comparison with the airborne lidar", [
            ref, "Residual = estimate minus reference (m), over the rows flagged ok whose "
            "reference is ok; SD = the residuals' standard deviation."],
            {"statistics against the airborne points (m)" if product == "ESFL" else
             "statistics against the formed pair" + (" (the round trip; m)" if simulated
                                                     else " (m)"): stats}, list(maps)),
    ]
