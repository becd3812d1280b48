"""The HTML report of a photon run of :func:`~canopyblocks.workflows.chain.run_chain`.

Every number, table and figure names its estimators and its reference.  Order: the
summary (the recommended estimators against the like-with-like reference, the map and
the profile); the paper's method against the same reference; the inputs; the lead
estimators in detail (figures, and a bias correction only when it was fitted against the
reference they are scored on and improves the held-out error); the blocks written; the
paper's method against the corridor maximum (a section of its own); the simulation
against truth; the paper's calibrated cut-offs (naming those on the edge of the grid).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from ...blocks import BlockParams
from ...outputs.report import ReportSection, calibration_table, report_stats_table, write_report
from ...readers.remote import source_label, source_name
from ...schema import FLAG_OK, FLAGS, LAYER_BLOCKS
from .figures import BiasOffer, EstimatorSet, Figures, estimator_words, reference_short
from .glossary import glossary_section, training_sentence
from .report import (
    bias_offer_part,
    counts_sentence,
    details_stats,
    lead_numbers,
    lead_result,
    low_confidence_sentence,
    numbers_table,
    paper_section,
    summary_section,
    truth_report_table,
)

__all__ = ["photon_report"]


def _cap(words: str) -> str:
    return words[:1].upper() + words[1:]


def photon_report(out: Path, *, tiles: list[Path], photons: Any, simulated: bool,
                  params: BlockParams, width: float, resolution: float,
                  primary: EstimatorSet, lead: EstimatorSet, paper: EstimatorSet | None,
                  figures: Figures, azimuth: float, datum: str, diameter: float,
                  photon_rate: str, seed: int, bias: BiasOffer, tracks: Sequence[Any],
                  calibration: pd.DataFrame | None = None,
                  cutoff_edges: list[str] | None = None,
                  truth_table: pd.DataFrame | None = None, truth_png: Path | None = None,
                  offsets: dict[str, Any] | None = None,
                  facts: pd.DataFrame | None = None) -> Path:
    """Write ``report.html`` in ``out`` (see the module notes for its order); every
    count, n, bias and RMSE of its text comes from ``facts`` (``facts.csv``)."""
    lr = lead_result(lead, facts)
    source = (f"ICESat-2 photons simulated over the airborne tiles: track azimuth "
              f"{azimuth:g} degrees, {diameter:g} m footprints, '{photon_rate}' photon rate "
              f"(mean signal photons per shot; see the glossary), random seed {seed} "
              "(the same seed draws the same photons); written in the ATL03 layout to "
              f"{source_name(photons)} and read back."
              if simulated else f"Photons read from {source_label(photons)}.")
    sections = [_summary(lr, lead, photons, simulated, params, tiles, tracks, figures, bias)]
    if paper is not None and paper is not lead:
        ref_kind = "footprint" if paper.fp_stats is not None else "corridor"
        sections.append(paper_section(lead_result(paper, facts, ref_kind), lead=lr))
    sections.append(ReportSection("Inputs", [
        source,
        "Airborne tiles: " + ", ".join(source_name(t) for t in tiles) + ".",
        f"Block lengths {', '.join(f'{v:g}' for v in params.lengths)} m; corridor width "
        f"{width:g} m; reference rasters at {resolution:g} m from PDAL; vertical datums: "
        + ("the tiles' own (the photons were simulated from them)." if simulated else datum),
    ]))
    sections += [_details(lr, lead, bias, figures), _written(primary, lead)]
    if paper is not None:
        sections.append(_paper_corridor(paper, lead, facts, figures, width))
    if lead.name != "paper" and lead.fp_stats is not None:
        sections.append(_lead_corridor(lead, facts))
    if truth_table is not None:
        sections.append(_truth(truth_table, truth_png))
    if calibration is not None:
        sections.append(_cutoffs(calibration, cutoff_edges))
    if offsets is not None:
        sections.append(_offsets_section(offsets))
    sections.append(glossary_section())
    return write_report(out / "report.html", "canopyblocks: block heights and validation",
                        sections)


def _summary(lr: Any, lead: EstimatorSet, photons: Any, simulated: bool,
             params: BlockParams, tiles: list[Path], tracks: Sequence[Any],
             figures: Figures, bias: BiasOffer) -> ReportSection:
    """The summary: what was computed, what the numbers rest on (said first when the
    tiles are those the method was fitted on), the facts, the sigma, the bias offer."""
    summary = summary_section(
        lr, source=source_name(photons) + (" (simulated)" if simulated else ""),
        n_tracks=len(tracks), n_photons=int(sum(len(t) for t in tracks)),
        beams=[str(t.track) for t in tracks], lengths=params.lengths, tiles=tiles,
        n_blocks=len(lead.blocks), map_png=figures.residual_map)
    extra = [low_confidence_sentence(lead.blocks, lead.name, lr.facts),
             bias_offer_part(bias, short=True)[0]]
    first, *rest = summary.paragraphs
    summary.paragraphs = [first, training_sentence(tiles), *rest, *[e for e in extra if e]]
    summary.images = [*summary.images, *([figures.profile] if figures.profile else [])]
    return summary


def _details(lr: Any, lead: EstimatorSet, bias: BiasOffer, figures: Figures
             ) -> ReportSection:
    """The lead estimators against their reference, by aspect and slope, with figures."""
    who = estimator_words(lead.name)
    words, tables = bias_offer_part(bias)
    return ReportSection(
        f"{_cap(who)} against the {lr.reference}: details", [
            f"Layer '{lead.lead_layer}' of validation.gpkg. Residual = block value minus "
            "reference value, metres, over the blocks used (flag ok, reference available). "
            "The figures show the same blocks: photon value against reference value per "
            "metric (1:1 line dashed, least-squares fit red, grey bars the predicted 1-sigma "
            "error of each block), and the RMSE per aspect class (classes of 3 or more "
            "blocks; flat = terrain slope below 2 degrees). Slope classes are the mean "
            "terrain slope of the block's corridor, degrees.",
            words],
        {**details_stats(lead.lead_stats), **tables},
        [*figures.lead_scatter, *figures.lead_aspect])


def _written(primary: EstimatorSet, lead: EstimatorSet) -> ReportSection:
    """The blocks written, per length and flag."""
    blocks = primary.blocks
    who = estimator_words(lead.name)
    counts = (blocks.groupby(["length", "flag"]).size().unstack(fill_value=0).reset_index()
              if len(blocks) else pd.DataFrame())
    counts = (report_stats_table(counts.rename_axis(columns=None)).rename(
        columns={f: f"{f} (blocks)" for f in FLAGS}) if len(counts) else counts)
    pwho = estimator_words(primary.name)
    return ReportSection(f"Block heights written ({pwho})", [
        f"{len(blocks)} blocks of {pwho}, {int((blocks['flag'] == FLAG_OK).sum())} flagged "
        f"ok (layer '{LAYER_BLOCKS}' of blocks.gpkg)."
        + ("" if primary is lead or not lead.suffix else
           f" The blocks of {who} are in the validation layers named after it ("
           + ", ".join(f"'{k}'" for k in lead.layers() if k.startswith("residuals"))
           + ").")],
        {f"blocks per length and flag ({pwho})": counts})


def _paper_corridor(paper: EstimatorSet, lead: EstimatorSet, facts: pd.DataFrame | None,
                    figures: Figures, width: float) -> ReportSection:
    """The paper's method as the paper scored it, against the corridor maximum."""
    return ReportSection("The paper's method against the corridor maximum", [
        "The paper's method scored as the paper scored it. Reference: the corridor maximum -- the highest DSM cell and the mean DTM of "
        f"the cells a {width:g} m corridor touches. Sparse photons rarely hit the "
        "single highest crown of a corridor, so this reference sits above what photons "
        "can see: it is not the like-with-like reference of the summary. Residual = "
        "photon value minus reference value, per block, over blocks flagged ok whose "
        "corridor lies inside the rasters. R² and slope are of the least-squares fit of the "
        f"photon values on the reference values (layer '{paper.corridor_layer}'). No "
        "bias correction of the heights is fitted against this reference (the paper's "
        "own cut-offs are fitted against it, as the paper did, in the section "
        "'Calibrated cut-offs of the paper's method' when asked for); the report "
        "scores heights against the "
        + ("footprint-matched reference." if lead.fp_stats is not None
           else "corridor maximum only for comparison."),
        counts_sentence(lead_numbers(lead_result(paper, facts, "corridor").facts))],
        {"the blocks used, all aspects and slopes together: n, bias and RMSE with "
         "their 95 % intervals": numbers_table(lead_numbers(
             lead_result(paper, facts, "corridor").facts)),
         **details_stats(paper.corridor_stats)},
        [*figures.paper_scatter, *figures.paper_aspect])


def _lead_corridor(lead: EstimatorSet, facts: pd.DataFrame | None) -> ReportSection:
    """The lead estimators against the corridor maximum, for comparison."""
    who = estimator_words(lead.name)
    return ReportSection(f"{_cap(who)} against the corridor maximum", [
        f"Layer '{lead.corridor_layer}', for comparison with the paper's method on the "
        "paper's reference. The corridor maximum sits above what photons can see, so "
        f"{who} looks metres low against it while it is close to the footprint-matched "
        "reference of the summary; no bias correction of the heights is fitted against "
        "it (one would make the heights as much too tall against the like-with-like "
        "reference).", counts_sentence(lead_numbers(lead_result(lead, facts,
                                                                "corridor").facts))],
        {f"{who} against the {reference_short('corridor')}, the blocks used":
         numbers_table(lead_numbers(lead_result(lead, facts, "corridor").facts))})


def _truth(truth_table: pd.DataFrame, truth_png: Path | None) -> ReportSection:
    """The simulation against its own truth."""
    return ReportSection("Simulated photons against truth", [
        "A study of the simulation itself, not of the block estimators above. Each "
        "simulated footprint keeps its truth (ground = the lowest peak of the "
        "pseudo-waveform, top = the highest return). The photons of each footprint are "
        "classified by the simulation study's step classifier (steps of 20 photons; "
        "ground below the lowest photon + 3 PSF widths, canopy top above the highest "
        "photon - 1 m) and compared with the truth, over many photon draws per footprint "
        "diameter. Footprint diameters 13 m (ICESat-2 at the start of the mission) and "
        "17 m (at its end, as the footprint grows), plus the diameter simulated for the "
        "blocks above if it is another: the rows show how the footprint size changes the "
        "errors. "
        "Residual = photon minus truth, metres; cover as a fraction of the footprint. "
        "In the figure, each point is the mean residual of the photons of one cover "
        "class and its error bar plus and minus one standard deviation of those "
        "photons' residuals (their spread, not the uncertainty of the mean)."],
        {"residuals against truth per footprint diameter": truth_report_table(truth_table)},
        [truth_png] if truth_png is not None else [])


def _cutoffs(calibration: pd.DataFrame, cutoff_edges: list[str] | None) -> ReportSection:
    """The paper's cut-offs fitted to the corridor maximum, held out."""
    edge = ""
    if cutoff_edges:
        grid, *which = cutoff_edges
        edge = (f" On the edge of the searched grid ({grid}): {', '.join(which)}. "
                "Such a cut-off is a bound, not an optimum: the best value may lie "
                "beyond the grid (at its low edge, the window floor of the paper's "
                "method, which the recommended estimators avoid).")
    return ReportSection("Calibrated cut-offs of the paper's method", [
        "The canopy-top and ground fractions of the paper's method fitted to the "
        "corridor maximum. The RMSE columns are held out: cut-offs fitted on the even "
        "blocks are scored on the odd blocks and vice versa. Layers "
        "residuals_calibrated and stats_calibrated of validation.gpkg hold the "
        "validation with the cut-offs fitted on all blocks. Both RMSEs of a row are over "
        "the same held-out blocks (n held out)." + edge],
        {"the paper's method: calibrated cut-offs (fractions of the block's photons) "
         "and their held-out RMSE against the corridor maximum":
         calibration_table(calibration)})


def _offsets_section(offsets: dict[str, Any]) -> ReportSection:
    rows = pd.DataFrame([{"track": k, **{c: v.get(c) for c in (
        "along_track", "cross_track", "east", "north", "vertical", "rmse_before",
        "rmse_after", "status", "reason")}} for k, v in offsets.items()])
    joint = offsets.get("all") or next(iter(offsets.values()))
    applied = (
        "The joint offset 'all' was applied horizontally before validating; its "
        "vertical part, which includes the ground estimator's bias, is reported only. "
        "Layer stats_uncorrected holds the statistics without it."
        if joint.get("determined") else
        "The joint offset 'all' is undetermined (see its reason): it was not applied, "
        "and the validation is of the blocks as reported.")
    return ReportSection("Co-registration", [
        "Offsets (m) that would align the blocks with the DTM: the shift to add to the "
        "reported positions. An offset is 'ok' only when, fitted on some stretches of "
        "the track, it also improves the held-out stretches significantly. " + applied],
        {"offsets (m)": rows.rename(columns=lambda c: c.replace("_", " "))})
