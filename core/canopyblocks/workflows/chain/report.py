"""The HTML report of :func:`~canopyblocks.workflows.chain.run_chain`, leading with the answer.

Order: a summary (what was computed, from what, the recommended estimators and their
error against the like-with-like reference, a map); the paper's method with one
paragraph on its known bias; then the details.  Every number of the text is read from
the statistics tables the report also shows (and the validation layers hold), so text
and tables cannot disagree.

The like-with-like reference of photon blocks is the footprint-matched airborne
reference (ground = mean ground of simulated footprints over the airborne points; Hmax
and H90 = the blocks' own percentiles of the canopy points pooled over their footprints,
top = ground + Hmax; DESIGN 2.7). The summary gives every block length.  The corridor maximum (the highest
DSM cell of the block's corridor) stays in the details, labelled as what it is.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ...outputs.report import ReportSection, report_stats_table
from ...readers.remote import source_name

__all__ = ["LeadResult", "estimators_sentence", "lead_numbers", "summary_section",
           "paper_section", "summary_lines", "datum_sentence", "bias_calibration_part",
           "SUMMARY_METRICS", "FOOTPRINT_WORDS", "CORRIDOR_WORDS", "lead_result",
           "low_confidence_sentence", "bias_offer_part", "truth_report_table", "details_stats",
           "numbers_table", "counts_sentence", "footprint_words", "FOOTPRINT_STATISTIC_WORDS",
           "BLOCK_BOOTSTRAP_WORDS"]

#: How the report names the footprint reference's statistic (``ref_statistic``).
FOOTPRINT_STATISTIC_WORDS = {
    "pooled": "statistic 'pooled': Hmax and h90 = the estimate's own statistic of the "
              "airborne points pooled over the block's footprints -- for the recommended "
              "estimators the 98th and 90th percentiles of the points more than 0.6 m "
              "above the ground; ground = mean footprint ground",
    "footprint-mean": "statistic 'footprint-mean': the mean over the block's footprints of "
                      "their RH98 and RH90 of all points; ground = mean footprint ground",
    "footprint-max": "statistic 'footprint-max': the highest of the block's footprints' "
                     "ground + RH98; ground = mean footprint ground",
}
#: How the report names its two references.
FOOTPRINT_WORDS = ("footprint-matched airborne reference ("
                   + FOOTPRINT_STATISTIC_WORDS["pooled"] + ")")


def footprint_words(statistic: str = "pooled") -> str:
    """The footprint reference named with its statistic."""
    return ("footprint-matched airborne reference ("
            + FOOTPRINT_STATISTIC_WORDS.get(statistic, f"statistic '{statistic}'") + ")")
CORRIDOR_WORDS = "corridor maximum (highest DSM cell and mean DTM of the corridor)"

#: The metrics the summary states (metres): ground elevation and canopy height.
SUMMARY_METRICS: tuple[str, ...] = ("ground", "hmax")

_METRIC_WORDS = {"ground": "ground", "hmax": "canopy height (Hmax)"}

_NOISE = {"sigma": "a 2.5-sigma height filter", "conf": "ATL03's signal confidence",
          "density": "a local photon-density filter",
          "atl08": "an ATL08-style density filter whose threshold comes from the background "
                   "rate", "none": "no noise filter"}
_GROUND = {"paper": "the mean of the photons in a window above the lowest kept photon",
           "surface": "a robust ground surface fitted along the track",
           "atl08": "an iterated along-track ground surface (ATL08-style)"}


def _top_words(top: str) -> str:
    if top == "paper":
        return "the highest kept photon less a top window"
    if top == "atl08":
        return "the top-of-canopy photons above the ground surface (ATL08-style)"
    return f"the {top[1:]}th percentile of the canopy photons"


def estimators_sentence(est: Any) -> str:
    """What the estimators do, generated from the :class:`Estimators` object itself."""
    return (f"noise: {_NOISE.get(est.noise, est.noise)}; ground: "
            f"{_GROUND.get(est.ground, est.ground)}; canopy top: {_top_words(est.top)}")


@dataclass(frozen=True)
class LeadResult:
    """The estimators the report leads with and their facts against a reference."""

    name: str
    estimators: Any
    stats: pd.DataFrame
    reference: str          # words naming the reference, e.g. "footprint-matched RH98"
    layer: str              # the validation.gpkg layer holding ``stats``
    recommended: bool
    facts: pd.DataFrame | None = None   # its rows of the run's table of facts


#: What facts.csv holds, and where the report's other numbers are.
FILES_WORDS = (
    "facts.csv holds the n, bias, RMSE (with their 95 % intervals), R² and counts of every "
    "estimator set against each reference, per block length and metric (all aspects and "
    "slopes together): the numbers of the summary and of the paper's method. The "
    "report's other numbers are in their own files: "
    "calibration.csv (the cut-off calibration, when run), bias_calibration_<estimators>.csv "
    "(the bias calibration and its held-out error), truth_residuals.csv (the simulation's "
    "known truth, when simulated), the statistics layers of validation.gpkg (by group, with "
    "MAE and the least-squares fit slope), and stats.csv (the run's own blocks, those of "
    "blocks.gpkg, against the corridor maximum, every group: the layer 'stats'). The "
    "figures measured on unseen tiles are the project's benchmarks, not this run's.")

#: How the report says its intervals of photon blocks were made.
BLOCK_BOOTSTRAP_WORDS = (
    "a block bootstrap along the track, per block length (2,000 resamples of runs of "
    "adjacent blocks 100 m long, as neighbouring blocks are not independent; the analytic "
    "interval above 5,000 blocks)")

#: Below this many blocks no interval is given.
MIN_INTERVAL = 3


def _fmt(v: float, signed: bool = False) -> str:
    if not np.isfinite(v):
        return "n/a"
    return f"{v:+.2f}" if signed else f"{v:.2f}"


def _span(lo: float, hi: float, signed: bool = False) -> str:
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "n/a"
    return f"{_fmt(lo, signed)} to {_fmt(hi, signed)}"


def lead_numbers(facts: pd.DataFrame) -> pd.DataFrame:
    """The summary table from the facts: per block length, ground and Hmax n (of the
    blocks, with the left-out ones by reason), bias and RMSE with their 95 % intervals,
    R²."""
    cols = ["length", "metric", "n", "bias", "bias_lo", "bias_hi", "rmse", "rmse_lo",
            "rmse_hi", "r2", "n_blocks", "left_out"]
    if facts is None or not len(facts):
        return pd.DataFrame(columns=cols)
    s = facts[facts["metric"].isin(SUMMARY_METRICS)][cols].copy()
    s["metric"] = pd.Categorical(s["metric"], SUMMARY_METRICS, ordered=True)
    return s.sort_values(["length", "metric"]).reset_index(drop=True)


def numbers_table(table: pd.DataFrame) -> pd.DataFrame:
    """:func:`lead_numbers` as the report shows it (intervals as text, units)."""
    if not len(table):
        return pd.DataFrame()
    return pd.DataFrame({
        "length (m)": table["length"].round().astype("Int64"),
        "metric": table["metric"].astype(str).map(lambda m: _METRIC_WORDS.get(m, m)),
        "n (blocks)": table["n"].astype("Int64"),
        "bias (m)": table["bias"],
        "bias, 95 % interval (m)": [_span(a, b, True) for a, b in
                                    zip(table["bias_lo"], table["bias_hi"], strict=True)],
        "RMSE (m)": table["rmse"],
        "RMSE, 95 % interval (m)": [_span(a, b) for a, b in
                                    zip(table["rmse_lo"], table["rmse_hi"], strict=True)],
        "R²": table["r2"],
        "blocks of this length": table["n_blocks"].astype("Int64"),
        "left out (reason blocks)": table["left_out"].fillna("").replace("", "none"),
    })


def _headline_length(table: pd.DataFrame) -> float | None:
    lengths = sorted(float(v) for v in pd.unique(table["length"])) if len(table) else []
    if not lengths:
        return None
    return 25.0 if 25.0 in lengths else lengths[len(lengths) // 2]


def _sentence(table: pd.DataFrame, length: float) -> str:
    parts = []
    for m in SUMMARY_METRICS:
        row = table[(table["length"] == length) & (table["metric"] == m)]
        if not len(row):
            continue
        r = row.iloc[0]
        n = int(r["n"])
        if n < MIN_INTERVAL:
            parts.append(f"{_METRIC_WORDS[m]} bias {_fmt(r['bias'], True)} m, RMSE "
                         f"{_fmt(r['rmse'])} m (n = {n} {'block' if n == 1 else 'blocks'}; "
                         "too few blocks for an interval)")
            continue
        parts.append(f"{_METRIC_WORDS[m]} bias {_fmt(r['bias'], True)} m (95 % interval "
                     f"{_span(r['bias_lo'], r['bias_hi'], True)} m), RMSE {_fmt(r['rmse'])} m "
                     f"({_span(r['rmse_lo'], r['rmse_hi'])} m), R² {_fmt(r['r2'])} "
                     f"(n = {n} blocks)")
    return "; ".join(parts)


def counts_sentence(table: pd.DataFrame, what: str = "blocks") -> str:
    """Every block of the headline metric (Hmax) counted: used per length, and those
    left out by reason, adding up to all blocks."""
    hm = table[table["metric"].astype(str) == SUMMARY_METRICS[-1]]
    if not len(hm):
        return ""
    total: dict[str, int] = {}
    for lo in hm["left_out"].fillna(""):
        for part in filter(None, str(lo).split("; ")):
            k, v = part.rsplit(" ", 1)
            total[k] = total.get(k, 0) + int(v)
    per = ", ".join(f"{r.length:g} m: {int(r.n)} of {int(r.n_blocks)}"
                    for r in hm.itertuples())
    left = "; ".join(f"{k} {v}" for k, v in sorted(total.items())) or "none"
    return (f"Counts ({_METRIC_WORDS[SUMMARY_METRICS[-1]]}): the statistics use "
            f"{int(hm['n'].sum())} of the {int(hm['n_blocks'].sum())} {what} ({per}); left "
            f"out, by reason: {left} ({sum(total.values())} {what}). Each length's row "
            "of the table below adds up the same way.")


def summary_section(lead: LeadResult, *, source: str, n_tracks: int, n_photons: int,
                    beams: Sequence[str], lengths: Sequence[float], tiles: Sequence[Any],
                    n_blocks: int, map_png: Path | None) -> ReportSection:
    """The report's first section."""
    table = lead_numbers(lead.facts)
    length = _headline_length(table)
    every = sorted(float(v) for v in pd.unique(table["length"])) if len(table) else []
    what = (f"Block heights of {', '.join(f'{v:g}' for v in lengths)} m blocks ({n_blocks} "
            f"blocks) from {n_photons:,} photons of {n_tracks} "
            f"{'beam' if n_tracks == 1 else 'beams'} "
            f"({', '.join(beams) or 'none'}) of {source}, validated against the airborne "
            f"lidar tiles {', '.join(source_name(t) for t in tiles)}.")
    who = (f"The recommended estimators, '{lead.name}'" if lead.recommended
           else f"The estimators used, '{lead.name}'")
    paras = [what, f"{who} ({estimators_sentence(lead.estimators)}), against the "
             f"{lead.reference}:"]
    if length is not None:
        paras.extend(f"At {v:g} m: {_sentence(table, v)}." for v in every)
        paras.append(counts_sentence(table))
    else:
        paras.append("No block could be validated against this reference.")
    paras.append("Residual = block value minus reference value, metres. 95 % intervals: "
                 + BLOCK_BOOTSTRAP_WORDS + ". The table below holds the rows of facts.csv for these "
                 f"estimators and this reference (statistics layer '{lead.layer}' of "
                 "validation.gpkg; the blocks used, all aspects and slopes together). "
                 + FILES_WORDS)
    return ReportSection("Summary", paras,
                         {f"'{lead.name}' against the {lead.reference}":
                          numbers_table(table)},
                         [map_png] if map_png is not None else [])


def paper_section(paper: LeadResult, *, lead: LeadResult | None) -> ReportSection:
    """The paper's method with one paragraph on its known bias (numbers from the facts)."""
    from ...blocks.estimators import preset

    table = lead_numbers(paper.facts)
    every = sorted(float(v) for v in pd.unique(table["length"])) if len(table) else []
    said = "; ".join(f"at {v:g} m: {_sentence(table, v)}" for v in every) \
        or "no block validated"
    text = (f"The paper's method ({estimators_sentence(preset('paper'))}) was built for dense "
            "airborne (MABEL) photons. On sparse ICESat-2 photons its ground sits at least the "
            "ground window above the lowest photon, its canopy top at least the top window "
            "below the highest kept photon, and its 2.5-sigma filter removes real tree-top "
            "photons in many blocks, so its canopy height comes out metres low. Against the "
            f"{paper.reference}, {said}.")
    if lead is not None and lead.name != "paper":
        text += f" The '{lead.name}' estimators of the summary avoid these floors."
    return ReportSection("The paper's method and its known bias", [
        text, counts_sentence(table),
        f"Statistics layer '{paper.layer}' of validation.gpkg; the blocks used, all aspects "
        "and slopes together:"],
        {f"the paper's method against the {paper.reference}": numbers_table(table)})


def summary_lines(lead: LeadResult) -> list[str]:
    """The terminal's summary: the same numbers as the report's first section (the
    facts)."""
    table = lead_numbers(lead.facts)
    who = "recommended" if lead.recommended else "estimators"
    out = [f"{who} '{lead.name}' against the {lead.reference} (95 % intervals in brackets; "
           "every number in facts.csv):"]
    for r in table.itertuples():
        if int(r.n) < MIN_INTERVAL:
            out.append(f"  {r.length:>5g} m  {str(r.metric):<6}  n={int(r.n):<4} "
                       f"bias={_fmt(r.bias, True)} m  rmse={_fmt(r.rmse)} m  (too few "
                       "blocks for an interval)")
            continue
        out.append(f"  {r.length:>5g} m  {str(r.metric):<6}  n={int(r.n):<4} "
                   f"bias={_fmt(r.bias, True)} m [{_span(r.bias_lo, r.bias_hi, True)}]  "
                   f"rmse={_fmt(r.rmse)} m [{_span(r.rmse_lo, r.rmse_hi)}]  "
                   f"R²={_fmt(r.r2)}")
    c = counts_sentence(table)
    if c:
        out.append("  " + c.split(" Each length")[0])
    return out


def datum_sentence(decision: str, *, geoid: Any = None, offset: float | None = None,
                   tiles: str | None = None, what: str = "photons") -> str:
    """The report's words for the vertical-datum decision of a validation ("same",
    "differ" with the conversion that was given, "unknown")."""
    theirs = f"the tiles' ({tiles})" if tiles else "the tiles'"
    if decision == "same":
        return f"the {what}' heights are in {theirs} datum."
    if decision == "differ":
        how = (f"the geoid raster {Path(geoid).name}" if geoid is not None
               else f"a constant offset of {offset:+g} m" if offset is not None
               else "the conversion given")
        return f"the {what}' heights were converted to {theirs} datum with {how}."
    return (f"the datum of the {what} or of the tiles is not stated; the heights were "
            "compared as they are.")


def bias_calibration_part(table: pd.DataFrame, preset: str
                          ) -> tuple[str, dict[str, pd.DataFrame]]:
    """Words and tables of the bias calibration fitted in the chain: its table with the
    held-out error, or why there is none (``table.attrs['why']``)."""
    from ...outputs.report import calibration_table

    if table is None or not len(table):
        why = getattr(table, "attrs", {}).get("why", "too few validated blocks")
        return (f"No bias calibration was fitted for the '{preset}' estimators: "
                f"{why.rstrip('.')}.", {})
    return ("A bias calibration per block length and beam strength, fitted on these blocks, "
            "with its held-out error (fitted on even blocks, scored on odd ones and vice "
            "versa); fit one on other sites to apply it (canopyblocks calibrate --method "
            "bias).", {"bias calibration: correction per block length and beam strength "
                       "(m)": calibration_table(table)})


def details_stats(stats: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """The statistics tables of a validation for the details: all blocks, and groups by
    aspect and slope with n >= 3 (the count of groups left out is stated)."""
    if stats is None or not len(stats):
        return {}
    overall = stats[stats["group"] == "all"]
    out = {"the blocks used, all aspects and slopes together": report_stats_table(overall)}
    for kind in ("aspect", "slope"):
        g = stats[stats["group"].astype(str).str.startswith(f"{kind}:")]
        if not len(g):
            continue
        keep = g[g["n"] >= 3]
        dropped = len(g) - len(keep)
        cap = f"by {kind} class (groups with n >= 3"
        cap += f"; {dropped} group rows with fewer blocks left out)" if dropped else ")"
        out[cap] = report_stats_table(keep)
    return out


def lead_result(s: Any, facts: pd.DataFrame | None = None,
                reference: str | None = None) -> LeadResult:
    """The :class:`LeadResult` of an :class:`~canopyblocks.workflows.chain.figures.EstimatorSet`
    against ``reference`` (``footprint``/``corridor``; default the footprint-matched one
    when computed), with its rows of the run's ``facts``."""
    from ...blocks.estimators import RECOMMENDED_PRESET

    kind = reference or ("footprint" if s.fp_stats is not None else "corridor")
    stat = "pooled"
    fp = s.fp_residuals
    if fp is not None and "ref_statistic" in fp.columns and len(fp):
        stat = str(fp["ref_statistic"].iloc[0])
    ref = footprint_words(stat) if kind == "footprint" else CORRIDOR_WORDS
    stats = s.lead_stats if kind == "footprint" else s.corridor_stats
    layer = s.lead_layer if kind == "footprint" else s.corridor_layer
    rows = None
    if facts is not None:
        rows = facts[(facts["estimators"] == s.name) & (facts["reference"] == kind)]
    return LeadResult(s.name, s.est(), stats, ref, layer, s.name == RECOMMENDED_PRESET, rows)


def _sigma_thresholds() -> tuple[float, float] | None:
    """The per-block uncertainty model's ``low_confidence`` thresholds (Hmax, ground; m),
    when the model is installed."""
    import importlib

    try:
        mod = importlib.import_module("canopyblocks.blocks.uncertainty")
        model = mod.sigma_model()
        return float(model.hmax_max), float(model.ground_max)
    except Exception:  # noqa: BLE001 -- no model: the sentence names no threshold
        return None


def low_confidence_sentence(blocks: pd.DataFrame, name: str,
                            facts: pd.DataFrame | None = None) -> str:
    """What the per-block uncertainty (sigma) says and how often it held: the predicted
    sigma beside its observed coverage (share of residuals within 1 and 2 sigma) per
    length, from the facts; and the ``low_confidence`` rule ("" without sigma)."""
    if blocks is None or "flag" not in blocks.columns or "hmax_sigma" not in blocks.columns:
        return ""
    parts = ["Each block carries a predicted 1-sigma error (columns hmax_sigma and "
             "ground_sigma, m): a Gaussian error of that sigma would put 68 % of the "
             "residuals within 1 sigma and 95 % within 2 sigma."]
    if facts is not None and len(facts):
        obs = []
        for m in ("hmax", "ground"):
            f = facts[(facts["metric"] == m) & facts["within_1sigma"].notna()]
            for r in f.itertuples():
                obs.append(f"{_METRIC_WORDS[m]} {r.length:g} m: median sigma "
                           f"{r.median_sigma:.2f} m against an RMSE of {r.rmse:.2f} m, "
                           f"{r.within_1sigma:.0%} within 1 sigma and {r.within_2sigma:.0%} "
                           f"within 2 sigma (n = {int(r.n)})")
        if obs:
            parts.append("Observed on these blocks: " + "; ".join(obs) + ".")
    th = _sigma_thresholds()
    why = (f"Hmax sigma wider than {th[0]:g} m or ground sigma wider than {th[1]:g} m"
           if th else "a predicted sigma too wide to be useful")
    parts.append(f"Blocks of '{name}' with {why} are flagged low_confidence and left out "
                 "of the statistics (column use = false; counted above); they are still "
                 "written.")
    return " ".join(parts)


def bias_offer_part(offer: Any, short: bool = False) -> tuple[str, dict[str, pd.DataFrame]]:
    """Words (and the table) of the lead estimators' bias calibration: offered only when
    fitted against the reference the estimators are scored on and improving every
    held-out error; else why not.  ``short``: one sentence for the summary."""
    from ...outputs.report import calibration_table

    who = "the paper's method" if offer.name == "paper" else f"the '{offer.name}' estimator"
    ref = ("footprint-matched reference" if offer.reference == "footprint"
           else "corridor maximum")
    if not len(offer.table):
        text = (f"No bias correction is offered for {who}: none could be fitted against the "
                f"{ref} ({offer.why.rstrip('.')}).")
        return text, {}
    if offer.offered:
        hm = offer.table[offer.table["metric"] == "hmax"]
        span = (f"{hm['intercept'].min():+.1f} to {hm['intercept'].max():+.1f} m"
                if len(hm) else "see the table")
        text = (f"A bias correction for {who}, fitted against the {ref} it is scored on, "
                f"improves the held-out error (Hmax correction {span}); it is written to "
                f"bias_calibration_{offer.name}.json. It was fitted on these blocks: fit "
                "one on other sites before applying it (canopyblocks calibrate --method "
                "bias).")
        cap = (f"bias correction of {who} against the {ref}, per block length and beam "
               "strength, with its held-out error (fitted on even blocks, scored on odd "
               "ones and vice versa)")
    else:
        text = (f"No bias correction is offered for {who}: one fitted against the {ref} it "
                f"is scored on {offer.why.removeprefix('it ')}.")
        cap = (f"bias correction of {who} against the {ref}: fitted, not offered (it does "
               "not improve the held-out error of every length and metric)")
    if short:
        return text, {}
    return text, {cap: calibration_table(offer.table)}


#: Report headers of the simulation-against-truth table.
TRUTH_HEADERS: dict[str, str] = {
    "diameter": "footprint diameter (m)", "realisations": "photon draws",
    "n_shots": "footprints", "n_photons": "photons", "mean_cover": "mean cover (fraction)",
    "n_ground": "ground photons", "ground_bias": "ground bias (m)",
    "ground_std": "ground SD (m)", "ground_rms": "ground RMS (m)",
    "n_top": "canopy-top photons", "top_bias": "canopy-top bias (m)",
    "top_std": "canopy-top SD (m)", "top_rms": "canopy-top RMS (m)",
}


def truth_report_table(table: pd.DataFrame) -> pd.DataFrame:
    """The simulation-against-truth table with words and units as headers, counts as
    integers."""
    df = pd.DataFrame(table).copy()
    for c in df.columns:
        if c in ("realisations", "n_shots", "n_photons", "n_ground", "n_top"):
            df[c] = pd.to_numeric(df[c], errors="coerce").round().astype("Int64")
    return df.rename(columns={c: TRUTH_HEADERS.get(c, c.replace("_", " "))
                              for c in df.columns})
