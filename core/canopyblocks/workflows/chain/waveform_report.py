"""The HTML report's sections of a GEDI run (:mod:`~canopyblocks.workflows.chain.waveforms`).

It opens with a summary like the photon report's: what was computed, and the footprints'
errors against the footprint-matched airborne reference.  Counts are of footprints;
heights in metres; cover as a fraction (0..1), in a table of its own; groups of fewer
than 3 footprints are left out of the tables (their count is stated).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...outputs.report import ReportSection, footprint_stats_table

__all__ = ["waveform_summary_section", "waveform_stats_tables", "MIN_GROUP",
           "footprint_facts", "facts_sentence", "facts_lines", "footprint_counts",
           "GEDI_FOOTPRINT_WORDS", "simulated_words", "gedi_sections", "MIN_INTERVAL",
           "ELEVATIONS", "without_unsupported", "input_warnings", "warnings_paragraph",
           "POINTS", "FORMED", "POINTS_WORDS", "POINT_COLUMNS", "own_reference_label",
           "INTERVAL_WORDS"]

#: facts.csv's name of the independent reference (the airborne points themselves) and of
#: the reference formed into the sensor's waveform and read by the same algorithm.
POINTS = "airborne points"
FORMED = "waveform-formed"

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
    t = footprint_stats_table(without_unsupported(stats)).rename(columns={"n (blocks)": "n (footprints)"})
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


def without_unsupported(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` (facts or statistics) without the numbers its rows cannot support: no
    interval, R² or fit below :data:`MIN_INTERVAL` footprints, and no R² or fit of an
    elevation (:data:`ELEVATIONS`: the terrain's relief alone makes them correlate)."""
    t = table.copy()
    if not len(t):
        return t
    few = pd.to_numeric(t["n"], errors="coerce").fillna(0).to_numpy() < MIN_INTERVAL
    elev = t["metric"].astype(str).isin(ELEVATIONS).to_numpy()
    for cols, rows in ((("bias_lo", "bias_hi", "rmse_lo", "rmse_hi"), few),
                       (("r2", "slope", "intercept"), few | elev)):
        for c in cols:
            if c in t:
                t[c] = np.where(rows, np.nan, pd.to_numeric(t[c], errors="coerce"))
    if "interval" in t:
        t["interval"] = np.where(few, "none", t["interval"].astype(object))
    return t


def points_view(residuals: pd.DataFrame) -> pd.DataFrame:
    """The residuals as the independent comparison sees them: a footprint whose formed
    waveform the reading found no ground in still has the points' values."""
    from ...reference.footprint_params import REFERENCE_FLAG_NO_GROUND, REFERENCE_FLAG_OK

    r = residuals.copy()
    if "ref_flag" not in r:
        return r
    lost = r["ref_flag"].astype(str).to_numpy() == REFERENCE_FLAG_NO_GROUND
    if "flag" in r:   # the footprint's own flag was ok when it shows the reference's
        lost &= r["flag"].astype(str).to_numpy() == REFERENCE_FLAG_NO_GROUND
    r["ref_flag"] = np.where(lost, REFERENCE_FLAG_OK, r["ref_flag"].astype(object))
    if "flag" in r:
        r["flag"] = np.where(lost, REFERENCE_FLAG_OK, r["flag"].astype(object))
    if "use" in r:
        r["use"] = r["use"].astype(bool).to_numpy() | lost
    return r


def footprint_facts(residuals: pd.DataFrame, *, pairs: dict[str, str], metrics: Sequence[str],
                    diameter: float, estimators: str, layer: str,
                    out: Path | None = None, reference: str = FORMED,
                    points: dict[str, str] | None = None,
                    size_name: str = "footprint_diameter") -> pd.DataFrame:
    """The run's table of facts of footprint residuals (one row per reference and
    metric: against the independent airborne points (``points``: metric -> their
    column) first, then against ``reference`` (``pairs``)), without what
    :func:`without_unsupported` drops; written to ``facts.csv`` in ``out`` when given,
    its ``length`` column (the footprint diameter or cell size, m) named ``size_name``."""
    from ...outputs.tables import write_table
    from ...validation.facts import fact_rows, facts_table

    rows = []
    if points:
        rows += fact_rows(points_view(residuals), estimators=estimators, reference=POINTS, layer=layer,
                          pairs=points, metrics=[m for m in metrics if m in points],
                          length=diameter)
    rows += fact_rows(residuals, estimators=estimators, reference=reference,
                      layer=layer, pairs=pairs, metrics=metrics, length=diameter)
    table = without_unsupported(facts_table(rows))
    if out is not None:
        write_table(table.rename(columns={"length": size_name}), out / "facts.csv",
                    layer="facts")
    return table


#: Below this many footprints no interval, R² or fit is given.
MIN_INTERVAL = 10
#: Elevations: their R² measures the terrain's relief, not the agreement.
ELEVATIONS = frozenset({"ground", "top"})


def _count(n: int, what: str) -> str:
    """``1 footprint``, ``2 footprints`` (``what``: the plural)."""
    return f"{n} {what[:-1] if n == 1 and what.endswith('s') else what}"


def _too_few(what: str, n: int) -> str:
    return f"too few {what} ({n}) for an interval or R²"


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
        r2 = f", R² {r.r2:.2f}" if np.isfinite(r.r2) and not few else ""
        note = f"; {_too_few(what, int(r.n))}" if few else ""
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
    if not len(facts):
        return []
    out = [f"against {reference} (95 % intervals in brackets; every number in facts.csv):"]
    for r in facts.itertuples():
        u = _unit(str(r.metric))
        head = (f"  {words.get(str(r.metric), r.metric)}: n={int(r.n)} of "
                f"{_count(int(r.n_blocks), what)}  bias={r.bias:+.2f}{u}")
        if int(r.n) < MIN_INTERVAL:
            out.append(f"{head}  rmse={r.rmse:.2f}{u}  ({_too_few(what, int(r.n))})")
            continue
        r2 = f"  R²={r.r2:.2f}" if np.isfinite(r.r2) else ""
        out.append(f"{head} [{r.bias_lo:+.2f} to {r.bias_hi:+.2f}]  rmse={r.rmse:.2f}{u} "
                   f"[{r.rmse_lo:.2f} to {r.rmse_hi:.2f}]{r2}")
    return out


@contextmanager
def input_warnings() -> Iterator[Callable[[], list[str]]]:
    """Collect the warnings a chain gives (Python warnings and logged ones) for its
    report to repeat: yields a function returning those given so far.  They still reach
    the terminal (the Python ones re-issued on leaving)."""
    logged: list[str] = []

    class _Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            logged.append(record.getMessage())

    keep = _Keep(logging.WARNING)
    logger = logging.getLogger("canopyblocks")
    logger.addHandler(keep)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield lambda: list(dict.fromkeys([*(str(w.message) for w in caught), *logged]))
    finally:
        logger.removeHandler(keep)
    for w in dict((str(w.message), w) for w in caught).values():
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def warnings_paragraph(said: Sequence[str]) -> str:
    """The report's sentence repeating the run's warnings (empty when none)."""
    if not said:
        return ""
    return ("Warnings about the inputs (as on the terminal): "
            + " ".join(f"({i}) {w.rstrip('.')}." for i, w in enumerate(said, 1)))


def simulated_words(sensor: str, source: str, *, azimuth: float | None,
                    seed: int | None) -> str:
    """The sentence saying a file was simulated over the tiles (not an acquisition)."""
    how = "" if azimuth is None else f" along a line at azimuth {azimuth:g} degrees"
    rnd = "" if seed is None else f", random seed {seed}"
    return (f"{source} ({sensor}) is not an acquisition: it was simulated from the airborne "
            f"tiles below{how}{rnd}, so every comparison below is with the very points the "
            "waveforms were made from.")


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


#: The independent airborne quantities a GEDI footprint is compared with first.
POINTS_WORDS = ("the independent airborne quantities under each footprint (ground = the "
                "footprint-weighted mean of the class-2 ground points; RH98 and RH50 = "
                "footprint-weighted percentiles of the heights of all points above a plane "
                "through them)")
#: Metric -> its column of those quantities in the residuals layer.
POINT_COLUMNS = {"ground": "ref_ground_points", "rh98": "ref_rh98_points",
                 "rh50": "ref_rh50_points"}


def _by_reference(facts: pd.DataFrame | None, independent: bool) -> pd.DataFrame:
    if facts is None or not len(facts):
        return pd.DataFrame()
    return facts[(facts["reference"] == POINTS) == independent]


def own_reference_label(simulated: bool, reference: str) -> str:
    """What the second comparison is: a round trip for a simulated file."""
    if reference == "points":
        return "Against the airborne points"
    if simulated:
        return ("Round trip, not an independent check (the simulator's own noise-free "
                "waveform, read by the same algorithm: it tests the processing chain, not "
                "the measurement)")
    return ("Against the same airborne points formed into the waveform the sensor would "
            "record and read by the same algorithm (like with like)")


def waveform_summary_section(stats: pd.DataFrame, *, source: str, n_footprints: int,
                             beams: Sequence[str], tiles: Sequence[Path],
                             setting: str, facts: pd.DataFrame | None = None,
                             simulated: str = "", reference: str = "waveform",
                             warned: Sequence[str] = ()) -> ReportSection:
    """The GEDI report's first section: the independent comparison first, then the
    reference formed as the waveforms are (numbers from ``facts``; ``reference``: the
    reference's definition, ``FootprintReferenceParams.definition``; ``warned``: the
    run's warnings, repeated)."""
    from ...validation.footprints import reference_words

    paras = [f"{_count(n_footprints, 'GEDI footprints')} of {len(beams)} "
             f"{'beam' if len(beams) == 1 else 'beams'} ({', '.join(beams) or 'none'}) of "
             f"{source}, processed with the GEDI L2A algorithm (setting {setting}), "
             f"compared with the airborne lidar tiles {', '.join(t.name for t in tiles)}.",
             simulated, warnings_paragraph(warned)]
    ind, own = _by_reference(facts, True), _by_reference(facts, False)
    said = facts_sentence(ind, _WORDS) if len(ind) else ""
    if said:
        paras.append(f"Against {POINTS_WORDS}: {said}. The points' percentiles count every "
                     "return, a waveform only the energy above its detection threshold, so "
                     "a waveform's RH98 below the points' is expected: the gap is measured "
                     "here, not corrected.")
    own_said = facts_sentence(own, _WORDS) if len(own) else ""
    if own_said:
        paras.append(f"{own_reference_label(bool(simulated), reference)}: {own_said}. "
                     "Cover is a fraction of the footprint (0..1), for the waveforms from "
                     "their canopy and ground energy. This reference is "
                     + reference_words(reference) + ".")
        paras.append(footprint_counts(own, "rh98"))
    if not (said or own_said):
        paras.append("No footprint could be compared with the airborne reference.")
    paras.append(GEDI_FOOTPRINT_WORDS)
    paras.append(INTERVAL_WORDS + " facts.csv holds every number of this summary (column "
                 f"'reference': '{POINTS}' the independent comparison, '{FORMED}' the "
                 "formed waveform's; 'footprint_diameter' in metres); the tables below are "
                 "layer 'stats_footprints' of validation.gpkg (against the formed waveform; "
                 "its 'length' column is the footprint diameter, m) and stats.csv (the same "
                 "rows, the column named footprint_diameter).")
    return ReportSection("Summary", [p for p in paras if p])


#: How the summaries' intervals and R² are given.
INTERVAL_WORDS = (
    "Residual = waveform value minus reference value. 95 % intervals: bootstrap over the "
    f"footprints (2,000 resamples); no interval and no R² below {MIN_INTERVAL} footprints; "
    "no R² of an elevation (ground, top), whose agreement the terrain's relief alone would "
    "make look perfect: R² is of heights only.")


def gedi_simulation_words() -> str:
    """The settings a ``run --sensor gedi`` simulation used (the simulator's defaults)."""
    from ...simulate.gedi_waveforms import GediSimParams

    p = GediSimParams()
    return (f"Simulation settings: a shot every {p.spacing:g} m along the line; a Gaussian "
            f"beam of sigma {p.sigma:g} m; canopy returns {p.rho_ratio:g} times the ground's "
            f"energy; a pulse of {p.pulse_fwhm_ns:g} ns (full width at half maximum); peak "
            f"{p.peak_counts:g} counts over noise of mean {p.noise_mean:g} and standard "
            f"deviation {p.noise_sd:g} counts; each point's energy weighted by the point "
            f"density of its {p.density_cell:g} m cell.")


def gedi_sections(fp: pd.DataFrame, val: Any, facts: pd.DataFrame, *, l1b: Any,
                  tiles: Sequence[Path], params: Any, simulated: tuple[float, int] | None,
                  geoid: Any, offset: float | None, tiles_datum: str | None,
                  wave_plots: Sequence[Path], maps: Sequence[Path],
                  reference: str = "waveform", warned: Sequence[str] = ()
                  ) -> list[ReportSection]:
    """The sections of the GEDI report: summary (from the facts), inputs, footprints,
    comparison, glossary (``reference``: the reference's definition; ``warned``: the
    run's warnings)."""
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
            tiles=tiles, setting=setting, facts=facts, reference=reference, warned=warned,
            simulated="" if simulated is None else simulated_words(
                "GEDI", Path(l1b).name, azimuth=simulated[0], seed=simulated[1])),
        ReportSection("Inputs", [p for p in [
            f"GEDI L1B waveforms from {source_name(l1b)}, processed with the GEDI L2A "
            f"algorithm (setting {setting}).",
            "Airborne tiles: " + ", ".join(t.name for t in tiles) + "; vertical datums: "
            + datum_sentence(val.datum, geoid=geoid, offset=offset, tiles=tiles_datum,
                             what="waveforms"),
            gedi_simulation_words() if simulated is not None else ""] if p]),
        ReportSection("Footprints", [
            f"{len(fp)} footprints (layer 'footprints' of footprints.gpkg: ground, top, "
            "RH25-RH100, cover (fraction), penetration, flags)."],
            {"footprints per flag": flags}, list(wave_plots)[:6]),
        ReportSection(own_reference_label(simulated is not None, reference).split(" (")[0], [
            "Each footprint is compared with " + reference_words(reference) + ": ground, "
            "RH98, RH50 (m) and cover (fraction). Residual = waveform "
            "value minus reference value. Groups by beam, aspect, slope (degrees) and "
            "reference cover class (a fraction of the footprint); groups of fewer than "
            f"{MIN_GROUP} footprints are left out of the tables (the maps show every "
            "footprint)."],
            waveform_stats_tables(val.stats), list(maps)),
        gedi_glossary_section(
            ["independent airborne quantities", "round trip", "RH98",
             "footprint-matched airborne reference", "bias", "RMSE", "95 % interval",
             "R² (heights only)", "L1B / L2A", "setting a1", "lowest mode", "top",
             "penetration", "ALS", "cover", "aspect class", "slope class",
             "reference outside", "random seed", "beam names (gt1l ... gt3r)"],
            reference),
    ]
    return sections
