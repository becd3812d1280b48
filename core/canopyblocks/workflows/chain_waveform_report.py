"""The HTML report's sections of a GEDI run (:mod:`~canopyblocks.workflows.chain_waveforms`).

It opens with a summary like the photon report's: what was computed, and the footprints'
errors against the footprint-matched airborne reference.  Counts are of footprints;
heights in metres; cover as a fraction (0..1), in a table of its own; groups of fewer
than 3 footprints are left out of the tables (their count is stated).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from ..outputs.report import ReportSection, footprint_stats_table

__all__ = ["waveform_summary_section", "waveform_stats_tables", "MIN_GROUP"]

#: Groups with fewer footprints than this are left out of the tables.
MIN_GROUP = 3

_WORDS = {"ground": "ground", "rh98": "RH98 (canopy height)", "rh50": "RH50",
          "cover": "cover"}


def _table(stats: pd.DataFrame, cover: bool) -> pd.DataFrame:
    t = footprint_stats_table(stats).rename(columns={"n (blocks)": "n (footprints)"})
    if cover:  # a fraction, not metres
        t = t.rename(columns={c: c.replace("(m)", "(fraction)") for c in t.columns
                              if c != "footprint diameter (m)"})
        t = t.rename(columns={"slope (m/m)": "slope"})
    return t


def waveform_stats_tables(stats: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """Tables of the footprint statistics: heights (m) and cover (fraction), all
    footprints and by group (groups with n >= :data:`MIN_GROUP`)."""
    if stats is None or not len(stats):
        return {}
    out: dict[str, pd.DataFrame] = {}
    is_cover = stats["metric"] == "cover"
    for cover, what in ((False, "heights (m)"), (True, "cover (fraction of the footprint)")):
        part = stats[is_cover == cover]
        if not len(part):
            continue
        overall = part[part["group"] == "all"]
        out[f"{what}: all footprints"] = _table(overall, cover)
        groups = part[part["group"] != "all"]
        keep = groups[groups["n"] >= MIN_GROUP]
        dropped = len(groups) - len(keep)
        cap = f"{what} by group (groups of {MIN_GROUP} or more footprints"
        cap += f"; {dropped} group rows with fewer left out)" if dropped else ")"
        if len(keep):
            out[cap] = _table(keep, cover)
    return out


def _said(stats: pd.DataFrame, metric: str) -> str | None:
    row = stats[(stats["group"] == "all") & (stats["metric"] == metric)]
    if not len(row):
        return None
    r = row.iloc[0]
    if not np.isfinite(r["bias"]):
        return None
    unit = "" if metric == "cover" else " m"
    return (f"{_WORDS.get(metric, metric)} bias {r['bias']:+.2f}{unit}, RMSE "
            f"{r['rmse']:.2f}{unit}")


def waveform_summary_section(stats: pd.DataFrame, *, source: str, n_footprints: int,
                             beams: Sequence[str], tiles: Sequence[Path],
                             setting: str, reference: str = "waveform") -> ReportSection:
    """The GEDI report's first section (``reference``: the reference's definition,
    ``FootprintReferenceParams.definition``)."""
    from ..validation.footprints import reference_words

    alls = stats[stats["group"] == "all"] if len(stats) else stats
    n_used = int(alls["n"].max()) if len(alls) else 0
    paras = [f"{n_footprints} GEDI footprints of {len(beams)} "
             f"{'beam' if len(beams) == 1 else 'beams'} ({', '.join(beams) or 'none'}) of "
             f"{source}, processed with the GEDI L2A algorithm (setting {setting}), "
             f"validated against the airborne lidar tiles {', '.join(t.name for t in tiles)}."]
    parts = [s for s in (_said(stats, m) for m in ("ground", "rh98", "rh50", "cover")) if s]
    if parts:
        paras.append(f"Against the footprint-matched airborne reference, over {n_used} "
                     "footprints: " + "; ".join(parts) + ". Cover is a fraction of the "
                     "footprint (0..1), for the waveforms from their canopy and ground "
                     "energy. The reference is " + reference_words(reference) + ".")
    else:
        paras.append("No footprint could be validated against the airborne reference.")
    paras.append("Residual = waveform value minus reference value; the tables below are "
                 "layer 'stats_footprints' of validation.gpkg.")
    tables = {k: v for k, v in waveform_stats_tables(stats).items() if "all footprints" in k}
    return ReportSection("Summary", paras, tables)
