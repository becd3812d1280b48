"""The HTML report's sections of a GEDI run (:mod:`~canopyblocks.workflows.chain.waveforms`).

It opens with a summary like the photon report's: what was computed, and the footprints'
errors against the footprint-matched airborne reference.  Counts are of footprints;
heights in metres; cover as a fraction (0..1), in a table of its own; groups of fewer
than 3 footprints are left out of the tables (their count is stated).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...outputs.report import ReportSection, footprint_stats_table

__all__ = ["waveform_summary_section", "waveform_stats_tables", "MIN_GROUP",
           "footprint_facts", "facts_sentence", "facts_lines", "footprint_counts",
           "GEDI_FOOTPRINT_WORDS", "simulated_words", "gedi_sections"]

#: Where the GEDI footprint's 22 m comes from (the reference weights the points so).
GEDI_FOOTPRINT_WORDS = (
    "Footprint diameter 22 m: GEDI's nominal footprint, the 1/e² diameter of its Gaussian "
    "beam (sigma 5.5 m); the reference weights the airborne points by the same Gaussian, "
    "out to 1.5 radii.")

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


def footprint_facts(residuals: pd.DataFrame, *, pairs: dict[str, str], metrics: Sequence[str],
                    diameter: float, estimators: str, layer: str,
                    out: Path | None = None) -> pd.DataFrame:
    """The run's table of facts of footprint residuals (one row per metric; ``length``
    = the footprint diameter, m), written to ``facts.csv`` in ``out`` when given."""
    from ...outputs.tables import write_table
    from ...validation.facts import fact_rows, facts_table

    table = facts_table(fact_rows(residuals, estimators=estimators, reference="footprint",
                                  layer=layer, pairs=pairs, metrics=metrics,
                                  length=diameter))
    if out is not None:
        write_table(table, out / "facts.csv", layer="facts")
    return table


#: Below this many footprints (or blocks) no interval is given.
MIN_INTERVAL = 3


def _count(n: int, what: str) -> str:
    """``1 footprint``, ``2 footprints`` (``what``: the plural)."""
    return f"{n} {what[:-1] if n == 1 and what.endswith('s') else what}"


def _too_few(what: str) -> str:
    return f"too few {what} for an interval"


def _unit(metric: str) -> str:
    return "" if metric == "cover" else " m"


def facts_sentence(facts: pd.DataFrame, words: dict[str, str], what: str = "footprints"
                   ) -> str:
    """Each metric's bias and RMSE with their 95 % intervals, R² and n, from the facts."""
    parts = []
    for r in facts.itertuples():
        if not np.isfinite(r.bias):
            continue
        u = _unit(str(r.metric))
        few = int(r.n) < MIN_INTERVAL
        ci_b = (f" (95 % interval {r.bias_lo:+.2f} to {r.bias_hi:+.2f}{u})"
                if np.isfinite(r.bias_lo) and not few else "")
        ci_r = (f" ({r.rmse_lo:.2f} to {r.rmse_hi:.2f}{u})"
                if np.isfinite(r.rmse_lo) and not few else "")
        r2 = f", R² {r.r2:.2f}" if np.isfinite(r.r2) else ""
        note = f"; {_too_few(what)}" if few else ""
        parts.append(f"{words.get(str(r.metric), r.metric)} bias {r.bias:+.2f}{u}{ci_b}, "
                     f"RMSE {r.rmse:.2f}{u}{ci_r}{r2} (n = {_count(int(r.n), what)}{note})")
    return "; ".join(parts)


def footprint_counts(facts: pd.DataFrame, metric: str, what: str = "footprints") -> str:
    """Every footprint counted for ``metric``: used, and left out by reason."""
    row = facts[facts["metric"] == metric]
    if not len(row):
        return ""
    r = row.iloc[0]
    left = str(r["left_out"]) if isinstance(r["left_out"], str) and r["left_out"] else "none"
    return (f"Counts: the statistics of {metric} use {int(r['n'])} of the "
            f"{int(r['n_blocks'])} {what}; left out, by reason: {left}.")


def facts_lines(facts: pd.DataFrame, words: dict[str, str], reference: str,
                what: str = "footprints") -> list[str]:
    """The terminal summary of a waveform run, from the facts (the report's numbers)."""
    out = [f"against {reference} (95 % intervals in brackets; every number in facts.csv):"]
    for r in facts.itertuples():
        u = _unit(str(r.metric))
        head = (f"  {words.get(str(r.metric), r.metric)}: n={int(r.n)} of "
                f"{_count(int(r.n_blocks), what)}  bias={r.bias:+.2f}{u}")
        if int(r.n) < MIN_INTERVAL:
            out.append(f"{head}  rmse={r.rmse:.2f}{u}  ({_too_few(what)})")
            continue
        r2 = f"  R²={r.r2:.2f}" if np.isfinite(r.r2) else ""
        out.append(f"{head} [{r.bias_lo:+.2f} to {r.bias_hi:+.2f}]  rmse={r.rmse:.2f}{u} "
                   f"[{r.rmse_lo:.2f} to {r.rmse_hi:.2f}]{r2}")
    return out


def simulated_words(sensor: str, source: str, *, azimuth: float | None,
                    seed: int | None) -> str:
    """The sentence saying a file was simulated over the tiles (not an acquisition)."""
    how = "" if azimuth is None else f" along a line at azimuth {azimuth:g} degrees"
    rnd = "" if seed is None else f", random seed {seed}"
    return (f"{source} ({sensor}) is not an acquisition: it was simulated from the airborne "
            f"tiles below{how}{rnd}, so the validation checks the processing chain against "
            "the very points the waveforms were made from.")


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
                             setting: str, facts: pd.DataFrame | None = None,
                             simulated: str = "", reference: str = "waveform") -> ReportSection:
    """The GEDI report's first section (numbers from ``facts`` when given; ``reference``:
    the reference's definition, ``FootprintReferenceParams.definition``)."""
    from ...validation.footprints import reference_words

    paras = [f"{_count(n_footprints, 'GEDI footprints')} of {len(beams)} "
             f"{'beam' if len(beams) == 1 else 'beams'} ({', '.join(beams) or 'none'}) of "
             f"{source}, processed with the GEDI L2A algorithm (setting {setting}), "
             f"validated against the airborne lidar tiles {', '.join(t.name for t in tiles)}."]
    if simulated:
        paras.append(simulated)
    said = facts_sentence(facts, _WORDS) if facts is not None and len(facts) else ""
    if said:
        paras.append(f"Against the footprint-matched airborne reference: {said}. Cover is a "
                     "fraction of the footprint (0..1), for the waveforms from their canopy "
                     "and ground energy. The reference is " + reference_words(reference) + ".")
        paras.append(footprint_counts(facts, "rh98"))
    else:
        paras.append("No footprint could be validated against the airborne reference.")
    paras.append(GEDI_FOOTPRINT_WORDS)
    paras.append("Residual = waveform value minus reference value. 95 % intervals: bootstrap "
                 f"over the footprints (2,000 resamples; none below {MIN_INTERVAL} "
                 "footprints). facts.csv holds every number of this summary (its 'length' "
                 "column is the footprint diameter, m); the tables below are layer "
                 "'stats_footprints' of validation.gpkg (whose 'length' column is the "
                 "footprint diameter, m) and stats.csv (the same rows, the column named "
                 "footprint_diameter).")
    tables = {k: v for k, v in waveform_stats_tables(stats).items() if "all footprints" in k}
    return ReportSection("Summary", paras, tables)


def gedi_sections(fp: pd.DataFrame, val: Any, facts: pd.DataFrame, *, l1b: Any,
                  tiles: Sequence[Path], params: Any, simulated: tuple[float, int] | None,
                  geoid: Any, offset: float | None, tiles_datum: str | None,
                  wave_plots: Sequence[Path], maps: Sequence[Path],
                  reference: str = "waveform") -> list[ReportSection]:
    """The sections of the GEDI report: summary (from the facts), inputs, footprints,
    validation, glossary (``reference``: the reference's definition)."""
    from ...readers.remote import source_name
    from ...validation.footprints import reference_words
    from .glossary import gedi_glossary_section
    from .report import datum_sentence

    flags = fp["flag"].value_counts().rename_axis("flag").reset_index(name="footprints")
    setting = getattr(params, "setting", "a1")
    beams_used = sorted(str(b) for b in fp["beam"].unique()) if "beam" in fp else []
    sections = [
        waveform_summary_section(
            val.stats, source=Path(l1b).name, n_footprints=len(fp), beams=beams_used,
            tiles=tiles, setting=setting, facts=facts, reference=reference,
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
            {"footprints per flag": flags}, list(wave_plots)[:6]),
        ReportSection("Validation against the airborne lidar", [
            "Each footprint is compared with " + reference_words(reference) + ": ground, "
            "RH98, RH50 (m) and cover (fraction). Residual = waveform "
            "value minus reference value. Groups by beam, aspect, slope (degrees) and "
            "reference cover class (a fraction of the footprint); groups of fewer than "
            f"{MIN_GROUP} footprints are left out of the tables (the maps show every "
            "footprint)."],
            waveform_stats_tables(val.stats), list(maps)),
        gedi_glossary_section(
            ["RH98", "footprint-matched airborne reference", "bias", "RMSE",
             "95 % interval", "R²", "L1B / L2A", "setting a1", "lowest mode", "top",
             "penetration", "ALS", "cover", "aspect class", "slope class",
             "reference outside", "random seed", "beam names (gt1l ... gt3r)"],
            reference),
    ]
    return sections
