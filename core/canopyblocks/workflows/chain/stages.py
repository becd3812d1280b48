"""The named stages of a photon run of :func:`~canopyblocks.workflows.chain.run.run_chain`.

One :class:`RunState` holds what the stages hand on; each stage fills its part:

1. :func:`photons_stage` -- simulate ICESat-2 photons over the tiles (or take the file),
   with the vertical datum rule;
2. :func:`blocks_stage` -- block heights (``blocks.gpkg``) and the corridor width;
3. :func:`rasters_stage` -- the PDAL reference rasters;
4. :func:`validation_stage` -- the blocks (co-registered when asked) against the corridor
   maximum and the footprint-matched reference, the second estimator set beside them,
   one terrain per block in every layer;
5. :func:`calibration_stage` -- the lead's bias calibration, the paper's cut-offs fitted to
   the corridor maximum (``--calibrate``), ATL08's own heights (``--atl08``);
6. :func:`write_stage` -- ``validation.gpkg``, ``stats.csv`` and the table of facts;
7. :func:`report_stage` -- figures, ``report.html`` and the terminal summary.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from ...blocks import BlockParams
from ...blocks.estimators import RECOMMENDED_PRESET
from ...blocks.estimators import preset as named_preset
from ...outputs.tables import write_layers, write_table
from ...progress import Progress
from ...readers.remote import source_name
from ...reference.sensor_width import corridor_width
from ...schema import LAYER_RESIDUALS, LAYER_STATS
from ...validation.facts import terrain_of
from .facts import one_terrain, photon_facts, shared_terrain
from .figures import BiasOffer, EstimatorSet, Figures, chain_figures
from .report import datum_sentence, lead_result, summary_lines
from .result import ChainResult
from .tiles import _tiles_crs, _vertical_name

__all__ = ["RunState", "photons_stage", "blocks_stage", "rasters_stage", "validation_stage",
           "calibration_stage", "write_stage", "report_stage"]


@dataclass
class RunState:
    """What the stages of one photon run hand on (filled stage by stage)."""

    out: Path
    tiles: list[Any]               # the survey's sources (survey_tiles)
    params: BlockParams
    options: dict[str, Any]          # run_chain's keyword arguments, as given
    prog: Progress
    photons: Any = None
    simulated: bool = False
    crs: Any = None
    geoid: Any = None
    offset: float | None = None
    photon_vcrs: Any = None
    ref_vcrs: Any = None
    width: float | None = None
    truth_table: pd.DataFrame | None = None
    truth_png: Path | None = None
    res: Any = None                  # BlockResult of blocks_from_file
    rasters: Any = None
    val: Any = None                  # the user's blocks against the corridor maximum
    sets: dict[str, EstimatorSet] = field(default_factory=dict)
    primary: str = RECOMMENDED_PRESET
    layers: dict[str, pd.DataFrame] = field(default_factory=dict)
    offsets_doc: dict[str, Any] | None = None
    bias: BiasOffer | None = None
    cutoffs: Any = None
    edges: list[str] | None = None
    extra: dict[str, tuple[str, str, pd.DataFrame]] = field(default_factory=dict)
    validation: Path | None = None
    facts: pd.DataFrame | None = None

    @property
    def lead(self) -> EstimatorSet:
        return self.sets.get(RECOMMENDED_PRESET) or self.sets[self.primary]

    def vkw(self) -> dict[str, Any]:
        """The validation's datum and width arguments (the rasters keep the tiles'
        vertical datum, which the one datum rule must see)."""
        return {"width": self.width, **self.fkw()}

    def fkw(self) -> dict[str, Any]:
        return {"geoid": self.geoid, "offset": self.offset,
                "photon_vertical_crs": self.photon_vcrs,
                "reference_vertical_crs": self.ref_vcrs}


def photons_stage(st: RunState) -> None:
    """Simulated photons (their heights are the tiles' own: one datum by construction),
    or the file's, checked against the tiles' datum before minutes of work."""
    from ..survey import working_crs
    from .parts import _simulate

    o = st.options
    st.photons, st.geoid, st.offset, st.width = (o["photons"], o["geoid"], o["offset"],
                                                 o["width"])
    st.simulated = st.photons is None
    if st.simulated:
        st.photons, st.crs, st.truth_table, st.truth_png = _simulate(
            st.tiles, st.out, azimuth=o["azimuth"], diameter=o["diameter"],
            photon_rate=o["photon_rate"], seed=o["seed"], realisations=o["realisations"],
            progress=st.prog.sub(0.0, 0.25), crs=working_crs(st.tiles))
        st.offset, st.geoid = 0.0, None
        st.photon_vcrs = _tiles_crs(st.tiles) or st.crs
        st.width = o["diameter"] if st.width is None else st.width
    st.ref_vcrs = _tiles_crs(st.tiles)
    if not st.simulated:
        from ...reference.datum import check_vertical_datums

        st.crs = working_crs(st.tiles)  # the survey's CRS (UTM when it is Web Mercator)
        check_vertical_datums("EPSG:4979", st.ref_vcrs, geoid=st.geoid, offset=st.offset)


def blocks_stage(st: RunState) -> None:
    """Block heights of every track (``blocks.gpkg``) and the corridor width."""
    from ..blocks import blocks_from_file

    o = st.options
    st.prog.update(0.25, "block heights")
    st.res = blocks_from_file(st.photons, st.params, estimators=o["estimators"],
                              calibration=o["calibration"], beams=o["beams"],
                              channel=o["channel"], atl08=o["atl08"], crs=st.crs,
                              output=st.out / "blocks.gpkg", with_photons=True,
                              progress=st.prog.sub(0.25, 0.4))
    st.width = corridor_width(st.width, st.res.track_ids, source=str(st.photons))


def rasters_stage(st: RunState) -> None:
    """The reference rasters over the tracks' corridors, in the blocks' CRS."""
    from ..rasters import corridor_area, make_survey_rasters

    st.prog.update(0.4, "reference rasters")
    # over the corridors only: tiles away from the track are skipped by their headers
    from ...errors import CoverageError

    area = corridor_area(st.res.blocks, float(st.width))  # type: ignore[arg-type]  # set by blocks_stage
    try:
        st.rasters = make_survey_rasters(
            st.tiles, st.out / "rasters", resolution=st.options["resolution"],
            crs=st.res.blocks.crs, ground=st.options["ground"], polygon=area,
            progress=st.prog.sub(0.4, 0.75))
    except CoverageError as e:
        if "does not overlap the tiles" not in str(e):
            raise
        box = tuple(round(float(v), 1) for v in area.bounds)
        raise CoverageError(
            f"the airborne tiles do not cover the track: its corridors {box} lie outside "
            f"them ({e}); give the tiles under the track") from e


def validation_stage(st: RunState) -> None:
    """Every estimator set against every reference, with one terrain per block."""
    from ...validation.block_validation import validate_blocks
    from .parts import _compare_preset, _coregistered, _other_preset

    o, r = st.options, st.rasters
    st.prog.update(0.75, "validation")
    blocks = st.res.blocks
    before = None
    if o["coregister"]:
        blocks, st.offsets_doc, before = _coregistered(
            blocks, st.res.tracks, r, st.out, st.vkw(), st.prog.sub(0.75, 0.8),
            source=source_name(st.photons))
    st.val = validate_blocks(blocks, dtm=r.dtm, dsm_max=r.dsm_max, dsm_p90=r.dsm_p90,
                             **st.vkw(), progress=st.prog.sub(0.8, 0.85))
    st.layers = {LAYER_RESIDUALS: st.val.residuals, LAYER_STATS: st.val.stats}
    if before is not None:
        st.layers[f"{LAYER_STATS}_uncorrected"] = before
    est = o["estimators"]
    st.primary = RECOMMENDED_PRESET if est is None else (est.name or "custom")
    st.sets = {st.primary: _footprint(st, EstimatorSet(
        st.primary, blocks, st.res.labels, "", st.val.residuals, st.val.stats))}
    other = _other_preset(st.primary, o["compare_preset"], o["calibration"])
    if other is not None:
        st.sets[other] = _footprint(st, _compare_preset(
            other, st.res.tracks, st.params, r, st.vkw(), st.prog.sub(0.85, 0.9)))
    st.sets = one_terrain(st.sets, terrain_of(st.sets[st.primary].corridor_residuals))
    for s in st.sets.values():
        st.layers.update(s.layers())


def _footprint(st: RunState, s: EstimatorSet) -> EstimatorSet:
    """``s`` also against the footprint-matched reference (unless switched off)."""
    if not st.options["footprint_reference"]:
        return s
    from ...validation.footprints import validate_blocks_footprint

    vf = validate_blocks_footprint(s.blocks, st.tiles,
                                   statistic=st.options.get("reference_statistic", "pooled"),
                                   **st.fkw())
    return s.with_footprint(vf.residuals, vf.stats)


def calibration_stage(st: RunState) -> None:
    """The lead's bias calibration; the paper's cut-offs fitted to the corridor maximum
    (``calibrate``); ATL08's own heights against the rasters (``atl08``)."""
    from ...validation.block_validation import validate_atl08, validate_blocks
    from .parts import _calibrated_cutoffs, _lead_bias_calibration

    o, r = st.options, st.rasters
    assert st.width is not None   # set by blocks_stage
    st.bias = _lead_bias_calibration(st.lead, st.photons, st.res.tracks, st.width, st.out)
    if o["calibrate"]:
        from ..blocks import run_blocks

        st.prog.update(0.9, "calibrating cut-offs")
        st.cutoffs, st.edges = _calibrated_cutoffs(st.res.tracks[0], st.val.residuals,
                                                   st.params)
        blocks_c, _ = run_blocks(st.res.tracks, st.cutoffs.params,
                                 estimators=named_preset("paper"))
        val_c = validate_blocks(blocks_c, dtm=r.dtm, dsm_max=r.dsm_max, dsm_p90=r.dsm_p90,
                                **st.vkw())
        res_c, stats_c = shared_terrain(val_c.residuals,
                                        terrain_of(st.sets[st.primary].corridor_residuals))
        st.layers.update({f"{LAYER_RESIDUALS}_calibrated": res_c,
                          f"{LAYER_STATS}_calibrated": stats_c})
        st.extra[f"{LAYER_STATS}_calibrated"] = ("paper, calibrated cut-offs", "corridor",
                                                 res_c)
        write_table(st.cutoffs.table, st.out / "calibration.csv", layer="calibration")
    if o["atl08"] is not None:
        v8 = validate_atl08(st.res.blocks, o["atl08"], width=st.width)
        st.layers.update({f"{LAYER_RESIDUALS}_atl08": v8.residuals,
                          f"{LAYER_STATS}_atl08": v8.stats})


def write_stage(st: RunState) -> None:
    """``validation.gpkg``, ``stats.csv`` (the user's blocks against the corridor
    maximum) and ``facts.csv`` (every number of the report)."""
    st.validation = write_layers(st.layers, st.out / "validation.gpkg")
    write_table(st.sets[st.primary].corridor_stats, st.out / "stats.csv", layer=LAYER_STATS)
    st.facts = photon_facts(st.sets, st.out, st.extra)


def report_stage(st: RunState) -> ChainResult:
    """Figures, ``report.html`` and the result (its terminal summary from the facts)."""
    from .parts import _as_path, _lead_reference
    from .photon_report import photon_report

    o, lead, r = st.options, st.lead, st.rasters
    datum = _vertical_name(st.ref_vcrs)
    paper = st.sets.get("paper")
    figures: Figures = chain_figures(lead, paper, st.res.tracks[0], st.out / "plots",
                                     dtm=r.dtm, datum=datum,
                                     lead_reference=_lead_reference(lead))
    st.prog.update(0.95, "report")
    assert st.bias is not None and st.width is not None and st.validation is not None
    report = photon_report(
        st.out, tiles=st.tiles, photons=st.photons, simulated=st.simulated, params=st.params,
        width=st.width, resolution=o["resolution"], primary=st.sets[st.primary], lead=lead,
        paper=paper, figures=figures, azimuth=o["azimuth"],
        datum=datum_sentence(st.val.datum, geoid=st.geoid, offset=st.offset, tiles=datum),
        diameter=o["diameter"], photon_rate=o["photon_rate"], seed=o["seed"], bias=st.bias,
        calibration=None if st.cutoffs is None else st.cutoffs.table,
        cutoff_edges=st.edges, truth_table=st.truth_table, truth_png=st.truth_png,
        offsets=st.offsets_doc, tracks=st.res.tracks, facts=st.facts)
    st.prog.update(1.0, "done")
    return ChainResult(out_dir=st.out, photons=_as_path(st.photons),
                       blocks=st.out / "blocks.gpkg",
                       rasters={"dtm": r.dtm, "dsm_max": r.dsm_max, "dsm_p90": r.dsm_p90},
                       validation=st.validation, report=report, plots=figures.all(),
                       stats=st.sets[st.primary].corridor_stats, simulated=st.simulated,
                       summary=_caveated(st.tiles, summary_lines(lead_result(lead, st.facts))))


def _caveated(tiles: Sequence[Path], lines: list[str]) -> list[str]:
    """The terminal summary with the report's first caveat (validated tiles = fitted
    tiles) said first."""
    from .glossary import training_caveat

    caveat = training_caveat(tiles)
    return [caveat, *lines] if caveat else lines
