"""The HTML report of :func:`~canopyblocks.workflows.chain.run_chain`, leading with the answer.

Order: a summary (what was computed, from what, the recommended estimators and their
error against the like-with-like reference, a map); the paper's method with one
paragraph on its known bias; then the details.  Every number of the text is read from
the statistics tables the report also shows (and the validation layers hold), so text
and tables cannot disagree.

The like-with-like reference of photon blocks is the footprint-matched airborne
reference (ground = mean ground of simulated footprints over the airborne points, top =
that ground + the footprints' RH98; DESIGN 2.7).  The corridor maximum (the highest
DSM cell of the block's corridor) stays in the details, labelled as what it is.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..outputs.report import ReportSection, report_stats_table

__all__ = ["LeadResult", "estimators_sentence", "lead_numbers", "summary_section",
           "paper_section", "summary_lines", "datum_sentence", "bias_calibration_part",
           "SUMMARY_METRICS", "FOOTPRINT_WORDS", "CORRIDOR_WORDS", "lead_result",
           "low_confidence_sentence", "bias_offer_part", "truth_report_table", "details_stats"]

#: How the report names its two references.
FOOTPRINT_WORDS = "footprint-matched airborne reference (footprint RH98 and ground)"
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
    """The estimators the report leads with and their statistics against a reference."""

    name: str
    estimators: Any
    stats: pd.DataFrame
    reference: str          # words naming the reference, e.g. "footprint-matched RH98"
    layer: str              # the validation.gpkg layer holding ``stats``
    recommended: bool


def _fmt(v: float, signed: bool = False) -> str:
    if not np.isfinite(v):
        return "n/a"
    return f"{v:+.2f}" if signed else f"{v:.2f}"


def lead_numbers(stats: pd.DataFrame) -> pd.DataFrame:
    """The summary table: per block length, ground and Hmax n, bias, RMSE, r2 (group all)."""
    if stats is None or not len(stats):
        return pd.DataFrame(columns=["length", "metric", "n", "bias", "rmse", "r2"])
    s = stats[(stats["group"] == "all") & stats["metric"].isin(SUMMARY_METRICS)]
    s = s[["length", "metric", "n", "bias", "rmse", "r2"]].copy()
    s["metric"] = pd.Categorical(s["metric"], SUMMARY_METRICS, ordered=True)
    return s.sort_values(["length", "metric"]).reset_index(drop=True)


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
        parts.append(f"{_METRIC_WORDS[m]} bias {_fmt(r['bias'], True)} m, RMSE "
                     f"{_fmt(r['rmse'])} m, r2 {_fmt(r['r2'])} (n = {int(r['n'])})")
    return "; ".join(parts)


def summary_section(lead: LeadResult, *, source: str, n_tracks: int, n_photons: int,
                    beams: Sequence[str], lengths: Sequence[float], tiles: Sequence[Path],
                    n_blocks: int, map_png: Path | None) -> ReportSection:
    """The report's first section."""
    table = lead_numbers(lead.stats)
    length = _headline_length(table)
    what = (f"Block heights of {', '.join(f'{v:g}' for v in lengths)} m blocks ({n_blocks} "
            f"blocks) from {n_photons:,} photons of {n_tracks} "
            f"{'beam' if n_tracks == 1 else 'beams'} "
            f"({', '.join(beams) or 'none'}) of {source}, validated against the airborne "
            f"lidar tiles {', '.join(t.name for t in tiles)}.")
    who = (f"The recommended estimators, '{lead.name}'" if lead.recommended
           else f"The estimators used, '{lead.name}'")
    paras = [what, f"{who} ({estimators_sentence(lead.estimators)}), against the "
             f"{lead.reference}:"]
    if length is not None:
        paras.append(f"At {length:g} m: {_sentence(table, length)}.")
    else:
        paras.append("No block could be validated against this reference.")
    paras.append("Residual = block value minus reference value, metres; the table below is "
                 f"layer '{lead.layer}' of validation.gpkg (the blocks used, all aspects and "
                 "slopes together).")
    return ReportSection("Summary", paras,
                         {f"'{lead.name}' against the {lead.reference}":
                          report_stats_table(table)},
                         [map_png] if map_png is not None else [])


def paper_section(paper_stats: pd.DataFrame, *, reference: str, layer: str,
                  lead: LeadResult | None) -> ReportSection:
    """The paper's method with one paragraph on its known bias (numbers from its table)."""
    from ..blocks.estimators import preset

    table = lead_numbers(paper_stats)
    length = _headline_length(table)
    said = _sentence(table, length) if length is not None else "no block validated"
    text = (f"The paper's method ({estimators_sentence(preset('paper'))}) was built for dense "
            "airborne (MABEL) photons. On sparse ICESat-2 photons its ground sits at least the "
            "ground window above the lowest photon, its canopy top at least the top window "
            "below the highest kept photon, and its 2.5-sigma filter removes real tree-top "
            "photons in many blocks, so its canopy height comes out metres low. Against the "
            f"{reference}, at {length if length is None else f'{length:g}'} m: {said}.")
    if lead is not None and lead.name != "paper":
        text += f" The '{lead.name}' estimators of the summary avoid these floors."
    return ReportSection("The paper's method and its known bias", [
        text, f"Layer '{layer}' of validation.gpkg; the blocks used, all aspects and slopes together:"],
        {f"the paper's method against the {reference}": report_stats_table(table)})


def summary_lines(lead: LeadResult) -> list[str]:
    """The terminal's summary: the same numbers as the report's first section."""
    table = lead_numbers(lead.stats)
    who = "recommended" if lead.recommended else "estimators"
    out = [f"{who} '{lead.name}' against the {lead.reference}:"]
    for r in table.itertuples():
        out.append(f"  {r.length:>5g} m  {str(r.metric):<6}  n={int(r.n):<4} "
                   f"bias={_fmt(r.bias, True)} m  rmse={_fmt(r.rmse)} m  r2={_fmt(r.r2)}")
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
    from ..outputs.report import calibration_table

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


def lead_result(s: Any) -> LeadResult:
    """The :class:`LeadResult` of an :class:`~canopyblocks.workflows.chain_figures.EstimatorSet`
    (its statistics against the footprint-matched reference when computed)."""
    from ..blocks.estimators import RECOMMENDED_PRESET

    ref = FOOTPRINT_WORDS if s.fp_stats is not None else CORRIDOR_WORDS
    return LeadResult(s.name, s.est(), s.lead_stats, ref, s.lead_layer,
                      s.name == RECOMMENDED_PRESET)


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


def low_confidence_sentence(blocks: pd.DataFrame, name: str) -> str:
    """How many blocks the per-block uncertainty left out of the headline and why ("" when
    the blocks carry no ``low_confidence`` flag)."""
    if blocks is None or "flag" not in blocks.columns:
        return ""
    low = blocks["flag"].astype(str) == "low_confidence"
    n_low = int(low.sum())
    parts = []
    if "hmax_sigma" in blocks.columns:
        ok = blocks["flag"].astype(str) == "ok"
        sig = pd.to_numeric(blocks.loc[ok, "hmax_sigma"], errors="coerce").dropna()
        if len(sig):
            parts.append(f"The blocks kept carry a predicted 1-sigma Hmax error (column "
                         f"hmax_sigma; median {sig.median():.1f} m, ground_sigma for the "
                         "ground).")
    if n_low:
        th = _sigma_thresholds()
        why = (f"Hmax sigma wider than {th[0]:g} m or ground sigma wider than {th[1]:g} m"
               if th else "their predicted sigma is too wide to be useful")
        parts.append(f"{n_low} of {len(blocks)} blocks of '{name}' are flagged "
                     f"low_confidence ({why}) and left out of the headline statistics "
                     "(column use = false); they are still written.")
    return " ".join(parts)


def bias_offer_part(offer: Any, short: bool = False) -> tuple[str, dict[str, pd.DataFrame]]:
    """Words (and the table) of the lead estimators' bias calibration: offered only when
    fitted against the reference the estimators are scored on and improving every
    held-out error; else why not.  ``short``: one sentence for the summary."""
    from ..outputs.report import calibration_table

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
