"""The whole chain in one call: photons (read or simulated) and airborne tiles ->
block heights -> PDAL reference rasters -> validation -> layers, plots, HTML report.

This is what ``canopyblocks run`` and the README's demo execute.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from ..atomic import check_writable, new_files_removed_on_failure
from ..blocks import BlockParams
from ..blocks.estimators import RECOMMENDED_PRESET
from ..errors import FileFormatError, InputError
from ..outputs.report import ReportSection, write_report
from ..outputs.tables import write_layers, write_table
from ..progress import Progress, as_progress
from ..readers.remote import is_file_object, is_url, source_label, source_name
from ..schema import FLAG_OK, FLAGS, LAYER_BLOCKS, LAYER_RESIDUALS, LAYER_STATS
from .blocks import blocks_from_file
from .chain_report import datum_sentence
from .chain_result import ChainResult
from .chain_tiles import _tiles_crs, _vertical_name

__all__ = ["ChainResult", "run_chain"]

log = logging.getLogger(__name__)


def _simulate(las_paths: Sequence[Path], out: Path, *, azimuth: float, diameter: float,
              preset: str, seed: int, realisations: int, progress: Progress
              ) -> tuple[Path, Any, pd.DataFrame | None, Path | None]:
    """Simulate one beam over the tiles; with ``realisations`` > 0 also the seed-002
    experiment (13 and 17 m footprints) with its table and figure."""
    from ..readers.las import read_las
    from ..simulate import SimParams, line_through, seed002_experiment, simulate_photons
    from ..simulate.plots import plot_cover_residuals
    from ..simulate.writers import write_simulation_atl03

    try:
        points = read_las(list(las_paths), progress=progress.sub(0.0, 0.2))
    except FileFormatError:
        progress.check()  # read_las reports a cancellation as a read error
        raise
    params = SimParams(diameter=diameter, preset=preset)  # type: ignore[arg-type]
    track = line_through(points.bounds, azimuth, inset=max(diameter, 17.0) / 2.0)
    sim = simulate_photons(points, track, params, realisations=1, seed=seed,
                           progress=progress.sub(0.2, 0.4))
    path = write_simulation_atl03(sim, out / "photons_atl03.h5")
    table, figure = None, None
    if realisations > 0:
        diams = tuple(sorted({float(diameter), 13.0, 17.0}))
        exp = seed002_experiment(points, track, params, diameters=diams,
                                 realisations=realisations, seed=seed, keep_simulations=False,
                                 progress=progress.sub(0.4, 1.0))
        table = exp.table
        write_table(table, out / "seed002_table.csv", layer="seed002")
        figure = plot_cover_residuals(exp, out / "plots" / "seed002_residuals_by_cover.png")
    progress.update(1.0, "photons simulated")
    return path, points.crs, table, figure


def run_chain(
    las_paths: Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    *,
    photons: str | os.PathLike[str] | None = None,
    beams: Sequence[str] = (),
    channel: int | str | None = None,
    atl08: str | os.PathLike[str] | None = None,
    azimuth: float = 0.0,
    diameter: float = 13.0,
    photon_rate: str = "temperate",
    seed: int = 0,
    params: BlockParams | None = None,
    width: float | None = None,
    resolution: float = 2.0,
    ground: str = "class2",
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    calibrate: bool = False,
    realisations: int = 100,
    estimators: Any = None,
    calibration: Any = None,
    compare_preset: str | None = RECOMMENDED_PRESET,
    coregister: bool = False,
    footprint_reference: bool = True,
    progress: Progress | None = None,
    preset: str | None = None,
) -> ChainResult:
    """Run photons -> blocks -> reference rasters -> validation -> report.

    Parameters
    ----------
    las_paths : sequence of path
        Airborne LAS/LAZ tiles (metric CRS) covering the track.
    out_dir : path
        Output folder: ``photons_atl03.h5`` (when simulated), ``blocks.gpkg``,
        ``rasters/{dtm,dsm_max,dsm_p90}.tif``, ``validation.gpkg`` (layers ``residuals``,
        ``stats``), ``stats.csv``, ``plots/*.png``, ``report.html``.
    photons : path, optional
        ATL03 / MABEL / table photon file, or a GEDI L1B file (then the chain is
        :func:`~canopyblocks.workflows.chain_waveforms.run_waveform_chain`: footprints validated
        against the tiles).  When None, ICESat-2 photons are simulated
        over the tiles along a line at ``azimuth`` degrees through the survey centre,
        with ``diameter`` m footprints and the ``photon_rate`` (``boreal``, ``temperate``,
        ``tropical``; as ``simulate(..., preset=)`` of the simulation parameters).
    preset : str, optional
        Deprecated name of ``photon_rate`` (a FutureWarning; it will be removed).
    params : BlockParams, optional
        Default: lengths 10, 25 and 50 m (seed 001).
    width : float, optional
        Corridor width, m; default 2 m for real photons and the footprint diameter for
        simulated ones (an ICESat-2 footprint is 13-17 m wide).
    resolution : float
        Reference raster cell size, m.
    geoid, offset
        Vertical conversion of real photon heights (ellipsoidal) to the tiles' datum.
    realisations : int
        Simulated runs only: photon draws per footprint diameter (13 and 17 m) for the
        seed 002 analysis of the photon classification against truth
        (``seed002_table.csv``, ``plots/seed002_residuals_by_cover.png``); 0 skips it.
    calibrate : bool
        Also fit the cut-offs to the reference (DESIGN.md 1.7; first track), recompute the
        blocks with them and validate again: layers ``residuals_calibrated`` and
        ``stats_calibrated``, table ``calibration.csv`` with held-out RMSEs.
    estimators : Estimators, optional
        Block estimators (DESIGN 1.10; default the paper's).
    calibration : path or BiasCalibration, optional
        Bias calibration applied to the blocks.
    compare_preset : str, optional
        With the paper's estimators: also compute the blocks with this preset (default
        the recommended one, :data:`~canopyblocks.blocks.estimators.RECOMMENDED_PRESET`),
        validate them, fit a bias calibration with its held-out error; the report leads
        with them (layers ``residuals_<preset>``, ``stats_<preset>``, with the footprint
        reference also ``residuals_footprint_<preset>``, ``stats_footprint_<preset>``;
        ``bias_calibration_<preset>.json``). None skips it.
    coregister : bool
        Search the joint geolocation offset of the blocks against the DTM/DSM and
        validate the horizontally shifted blocks (DESIGN 2.8); ``offsets.json``, layer
        ``stats_uncorrected``.
    footprint_reference : bool
        Validate also against the footprint-matched airborne reference (DESIGN 2.7; the
        default): the like-with-like reference the report and the summary lead with
        (ground = mean footprint ground, top = ground + RH98 of footprints of
        ``diameter`` m over the airborne points); layers ``residuals_footprint``,
        ``stats_footprint``.  False leads with the corridor maximum.
    """
    from ..arguments import check_path, check_paths
    check_paths(las_paths, "run_chain: las_paths", "a LAS/LAZ path or a non-empty list of them")
    check_path(out_dir, "run_chain: out_dir", "a folder path")
    from ..outputs.profile_plot import plot_profile  # noqa: F401  (fails early without matplotlib)
    from ..outputs.validation_plots import write_validation_plots
    from ..reference.rasters import make_reference_rasters
    from ..validation.block_validation import validate_atl08, validate_blocks

    if preset is not None:
        import warnings

        warnings.warn("run_chain(preset=) is deprecated; use photon_rate=", FutureWarning,
                      stacklevel=2)
        photon_rate = preset
    prog = as_progress(progress)
    if photons is not None and str(photons).lower().endswith((".h5", ".hdf5")):
        from ..readers.gedi import is_gedi_l1b

        if is_gedi_l1b(photons):   # full-waveform lidar: footprints, not blocks
            from .chain_waveforms import run_waveform_chain

            return run_waveform_chain(las_paths, out_dir, photons, beams=beams,
                                      geoid=geoid, offset=offset, progress=prog)
    out = check_writable(out_dir, folder=True)
    for name, value in (("width", width), ("resolution", resolution),
                        ("diameter", diameter)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a positive number of metres; got {value!r}")
    with new_files_removed_on_failure(out):
        out.mkdir(parents=True, exist_ok=True)
        tiles = [Path(p) for p in las_paths]
        params = params or BlockParams(lengths=(10.0, 25.0, 50.0))
        simulated = photons is None
        crs: Any = None
        photon_vcrs = None
        seed002: pd.DataFrame | None = None
        seed002_png: Path | None = None
        if photons is None:
            photons, crs, seed002, seed002_png = _simulate(
                tiles, out, azimuth=azimuth, diameter=diameter, preset=photon_rate, seed=seed,
                realisations=realisations, progress=prog.sub(0.0, 0.25))
            # simulated heights are the tiles' own heights: same vertical datum by construction
            offset, geoid, photon_vcrs = 0.0, None, _tiles_crs(tiles) or crs
            width = diameter if width is None else width
        width = 2.0 if width is None else width
        ref_vcrs = _tiles_crs(tiles)
        if not simulated:  # the one datum rule, before minutes of work (validate applies it too)
            from ..reference.datum import check_vertical_datums

            check_vertical_datums("EPSG:4979", ref_vcrs, geoid=geoid, offset=offset)
        plots_dir = out / "plots"
        prog.update(0.25, "block heights")
        res = blocks_from_file(photons, params, estimators=estimators, calibration=calibration,
                               beams=beams, channel=channel, atl08=atl08,
                               crs=crs, output=out / "blocks.gpkg", with_photons=True,
                               profile=plots_dir / "profile.png", progress=prog.sub(0.25, 0.4))
        blocks = res.blocks
        prog.update(0.4, "reference rasters (PDAL)")
        rasters = make_reference_rasters(tiles, out / "rasters", resolution=resolution,
                                         crs=blocks.crs, ground=ground,  # type: ignore[arg-type]
                                         progress=prog.sub(0.4, 0.75))
        prog.update(0.75, "validation")
        # the rasters were made in the blocks' (horizontal) CRS: their heights keep the
        # tiles' vertical datum (ref_vcrs), which the one datum rule (DESIGN 2.6) must see
        vkw: dict[str, Any] = {"width": width, "geoid": geoid, "offset": offset,
                               "photon_vertical_crs": photon_vcrs,
                               "reference_vertical_crs": ref_vcrs}
        layers: dict[str, pd.DataFrame] = {}
        offsets_doc = None
        if coregister:
            blocks, offsets_doc, before = _coregistered(
                blocks, res.tracks, rasters, out, vkw, prog.sub(0.75, 0.8),
                source=source_name(photons))
            if before is not None:
                layers[f"{LAYER_STATS}_uncorrected"] = before
        val = validate_blocks(blocks, dtm=rasters.dtm, dsm_max=rasters.dsm_max,
                              dsm_p90=rasters.dsm_p90, **vkw, progress=prog.sub(0.8, 0.85))
        layers = {LAYER_RESIDUALS: val.residuals, LAYER_STATS: val.stats, **layers}
        if footprint_reference:
            from ..validation.footprints import validate_blocks_footprint

            fkw: dict[str, Any] = {"geoid": geoid, "offset": offset,
                                   "photon_vertical_crs": photon_vcrs,
                                   "reference_vertical_crs": ref_vcrs}
            vf = validate_blocks_footprint(blocks, tiles, **fkw)
            layers.update({f"{LAYER_RESIDUALS}_footprint": vf.residuals,
                           f"{LAYER_STATS}_footprint": vf.stats})
        compared = None
        compared_fp = None
        if compare_preset and estimators is None and calibration is None:
            compared, cblocks = _compare_preset(compare_preset, res.tracks, params, rasters,
                                                out, vkw, photons, prog.sub(0.85, 0.9))
            layers.update({f"{LAYER_RESIDUALS}_{compare_preset}": compared[0],
                           f"{LAYER_STATS}_{compare_preset}": compared[1]})
            if footprint_reference:
                compared_fp = validate_blocks_footprint(cblocks, tiles, **fkw)
                layers.update({f"{LAYER_RESIDUALS}_footprint_{compare_preset}":
                               compared_fp.residuals,
                               f"{LAYER_STATS}_footprint_{compare_preset}": compared_fp.stats})
        cutoffs = None
        if calibrate:
            from .blocks import run_blocks

            prog.update(0.9, "calibrating cut-offs")
            cutoffs = _calibrated_cutoffs(res.tracks[0], val.residuals, params)
            blocks_c, _ = run_blocks(res.tracks, cutoffs.params)
            val_c = validate_blocks(blocks_c, dtm=rasters.dtm, dsm_max=rasters.dsm_max,
                                    dsm_p90=rasters.dsm_p90, **vkw)
            layers.update({f"{LAYER_RESIDUALS}_calibrated": val_c.residuals,
                           f"{LAYER_STATS}_calibrated": val_c.stats})
            write_table(cutoffs.table, out / "calibration.csv", layer="calibration")
        if atl08 is not None:
            v8 = validate_atl08(blocks, atl08, width=width)
            layers.update({f"{LAYER_RESIDUALS}_atl08": v8.residuals,
                           f"{LAYER_STATS}_atl08": v8.stats})
        validation = write_layers(layers, out / "validation.gpkg")
        write_table(val.stats, out / "stats.csv", layer=LAYER_STATS)
        plots = [plots_dir / "profile.png",
                 *write_validation_plots(val.residuals, val.stats, plots_dir,
                                         datum=_vertical_name(ref_vcrs))]
        lead, lead_res = _lead(estimators, compare_preset, compared, compared_fp,
                               layers, val)
        map_png = _residual_map(lead_res, rasters.dtm, plots_dir, lead)
        plots.append(map_png)
        prog.update(0.95, "report")
        report = _report(out, tiles=tiles, photons=photons, simulated=simulated,
                         params=params, width=width, resolution=resolution, blocks=blocks,
                         stats=val.stats, plots=plots, azimuth=azimuth,
                         datum=datum_sentence(val.datum, geoid=geoid, offset=offset,
                                              tiles=_vertical_name(ref_vcrs)),
                         diameter=diameter, preset=photon_rate, seed=seed,
                         calibration=None if cutoffs is None else cutoffs.table,
                         seed002=seed002, seed002_png=seed002_png, compared=compared,
                         compare_preset=compare_preset, offsets=offsets_doc, lead=lead,
                         layers=layers, tracks=res.tracks, map_png=map_png)
        prog.update(1.0, "done")
        return ChainResult(out_dir=out, photons=_as_path(photons), blocks=out / "blocks.gpkg",
                           rasters={"dtm": rasters.dtm, "dsm_max": rasters.dsm_max,
                                    "dsm_p90": rasters.dsm_p90},
                           validation=validation, report=report, plots=plots, stats=val.stats,
                           simulated=simulated, summary=_summary_lines(lead))


def _calibrated_cutoffs(track: Any, residuals: pd.DataFrame, params: BlockParams) -> Any:
    """The paper's cut-offs fitted to the reference, with one warning for all lengths
    whose best cut-off lies on the edge of the searched grid (instead of one per length
    and cut-off)."""
    import warnings

    from ..blocks.calibration import CutoffEdgeWarning
    from ..validation.calibration import calibrate_against_reference

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CutoffEdgeWarning)
        result = calibrate_against_reference(track, residuals, params)
    edge = [w for w in caught if issubclass(w.category, CutoffEdgeWarning)]
    for w in caught:
        if w not in edge:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if edge:
        which = sorted({" ".join(str(w.message).split(":")[1].split()[2:4]) for w in edge})
        lengths = sorted({float(str(w.message).split(" m blocks")[0]) for w in edge})
        warnings.warn(
            f"calibrated cut-offs of the {', '.join(f'{v:g}' for v in lengths)} m blocks of "
            f"track {track.track}: the best {' and '.join(which)} lie on the edge of the "
            "searched grid, so the optimum may lie beyond it (at the low edge this is the "
            "window floor of the paper's method, which the recommended estimators avoid)",
            CutoffEdgeWarning, stacklevel=2)
    return result


def _coregistered(blocks: Any, tracks: Any, rasters: Any, out: Path, vkw: dict[str, Any],
                  prog: Progress, source: str = "photons"
                  ) -> tuple[Any, dict[str, Any] | None, pd.DataFrame | None]:
    """Blocks shifted by the joint offset found from the photons (their ground- and
    top-window photons, DESIGN 2.8), horizontally only (the vertical offset is reported:
    applying it would hide the estimators' ground bias); the offsets document; the
    uncorrected statistics."""
    from dataclasses import replace

    from ..reference.datum import check_vertical_datums
    from ..reference.raster_sampling import read_surface
    from ..validation.block_validation import validate_blocks
    from ..validation.coregistration import coregister
    from ..validation.coregistration_targets import CoregTargets, apply_offset, targets_from_photons
    from .coregister import offset_to_apply, vertical_shift, write_offsets

    dtm = read_surface(rasters.dtm, what="DTM")
    dsm = read_surface(rasters.dsm_max, what="DSM")
    check_vertical_datums(vkw["photon_vertical_crs"] or "EPSG:4979",
                          vkw["reference_vertical_crs"] if vkw["reference_vertical_crs"]
                          is not None else dtm.crs, geoid=vkw["geoid"], offset=vkw["offset"])
    parts = [targets_from_photons(t, dtm.crs, track_index=i,
                                  heights=t.h - vertical_shift(t.lon, t.lat, vkw["geoid"],
                                                               vkw["offset"]))
             for i, t in enumerate(tracks)]
    result = coregister(CoregTargets.concat(parts), dtm, dsm, progress=prog)
    write_offsets(result, out / "offsets.json")
    doc = result.to_dict()
    joint = offset_to_apply(result, source)
    if joint is None:
        return blocks, doc, None
    before = validate_blocks(blocks, dtm=rasters.dtm, dsm_max=rasters.dsm_max,
                             dsm_p90=rasters.dsm_p90, **vkw).stats
    return apply_offset(blocks, replace(joint, vertical=0.0)), doc, before


def _compare_preset(name: str, tracks: Any, params: BlockParams, rasters: Any, out: Path,
                    vkw: dict[str, Any], photons: Any, prog: Progress
                    ) -> tuple[tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame], Any]:
    """Residuals and stats of the blocks made with preset ``name``, and the table of a
    bias calibration fitted on them (with its parity hold-out error); the blocks."""
    from ..blocks.estimators import preset
    from ..errors import NoUsableDataError
    from ..validation.bias_calibration import fit_bias_calibration, write_bias_calibration
    from ..validation.block_validation import validate_blocks
    from .blocks import run_blocks, track_strengths

    est = preset(name)
    blocks, _ = run_blocks(tracks, params, estimators=est, progress=prog.sub(0.0, 0.6))
    val = validate_blocks(blocks, dtm=rasters.dtm, dsm_max=rasters.dsm_max,
                          dsm_p90=rasters.dsm_p90, **vkw, progress=prog.sub(0.6, 0.9))
    residuals = val.residuals.assign(estimators=est.label())
    try:
        cal = fit_bias_calibration(residuals, strengths=track_strengths(photons, tracks) or None,
                                   preset=name, corridor_width=vkw["width"],
                                   sources=(source_name(photons),))
    except NoUsableDataError as exc:
        log.warning("no bias calibration for the %s preset: %s", name, exc)
        table = pd.DataFrame()
        table.attrs["why"] = str(exc)  # said in the report instead of an empty table
    else:
        write_bias_calibration(cal, out / f"bias_calibration_{name}.json")
        table = cal.table()
    prog.update(1.0)
    return (val.residuals, val.stats, table), blocks


_FOOTPRINT_WORDS = "footprint-matched airborne reference (footprint RH98 and ground)"
_CORRIDOR_WORDS = "corridor maximum (highest DSM cell and mean DTM of the corridor)"


def _lead(estimators: Any, compare_preset: str | None, compared: Any, compared_fp: Any,
          layers: dict[str, pd.DataFrame], val: Any) -> tuple[Any, pd.DataFrame]:
    """The estimators the report leads with (the recommended preset when it was computed,
    else the ones used) against the like-with-like reference when it was computed."""
    from ..blocks.estimators import Estimators, preset
    from .chain_report import LeadResult

    if compared is not None and compare_preset:
        name, est = compare_preset, preset(compare_preset)
        fp_layer, co_layer = f"footprint_{compare_preset}", compare_preset
        fp = compared_fp
        corridor = (compared[0], compared[1])
    else:
        est = estimators if estimators is not None else Estimators(name="paper")
        name = est.name or "custom"
        fp_layer, co_layer = "footprint", ""
        fp_res = layers.get(f"{LAYER_RESIDUALS}_footprint")
        fp = None if fp_res is None else (fp_res, layers[f"{LAYER_STATS}_footprint"])
        corridor = (val.residuals, val.stats)
    recommended = name == RECOMMENDED_PRESET
    if fp is not None:
        res, st = (fp.residuals, fp.stats) if hasattr(fp, "stats") else fp
        return LeadResult(name, est, st, _FOOTPRINT_WORDS, f"{LAYER_STATS}_{fp_layer}",
                          recommended), res
    layer = f"{LAYER_STATS}_{co_layer}" if co_layer else LAYER_STATS
    return LeadResult(name, est, corridor[1], _CORRIDOR_WORDS, layer, recommended), corridor[0]


def _summary_lines(lead: Any) -> list[str]:
    from .chain_report import summary_lines

    return summary_lines(lead)


def _residual_map(residuals: Any, dtm: Path, folder: Path, lead: Any) -> Path:
    """Block corridors coloured by their Hmax residual (the lead estimators against the
    lead reference) over a hillshade of the DTM (25 m blocks, else the middle length)."""
    from ..outputs.footprint_maps import plot_footprint_map

    lengths = sorted(float(v) for v in residuals["length"].unique())
    length = 25.0 if 25.0 in lengths else lengths[len(lengths) // 2]
    sub = residuals[residuals["length"] == length]
    ref = "footprint RH98" if lead.reference == _FOOTPRINT_WORDS else "corridor maximum"
    return plot_footprint_map(sub, "res_hmax", folder / "residual_map.png", dtm=dtm,
                              title=f"Hmax residual of '{lead.name}' against the {ref}, "
                                    f"{length:g} m blocks")


def _as_path(photons: Any) -> Path | str:
    """A local file as a Path; a URL or an open file by its name in messages."""
    return source_label(photons) if is_url(photons) or is_file_object(photons) else Path(photons)


def _report(out: Path, *, tiles: list[Path], photons: Any, simulated: bool,
            params: BlockParams, width: float, resolution: float, blocks: pd.DataFrame,
            stats: pd.DataFrame, datum: str, plots: list[Path], azimuth: float,
            diameter: float, preset: str, seed: int, lead: Any, layers: dict[str, Any],
            tracks: Any, map_png: Path,
            calibration: pd.DataFrame | None = None, seed002: pd.DataFrame | None = None,
            seed002_png: Path | None = None,
            compared: tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame] | None = None,
            compare_preset: str | None = None, offsets: dict[str, Any] | None = None) -> Path:
    from ..outputs.report import calibration_table, report_stats_table
    from .chain_report import bias_calibration_part, details_stats, paper_section, summary_section

    source = (f"ICESat-2 photons simulated over the airborne tiles: track azimuth "
              f"{azimuth:g} degrees, {diameter:g} m footprints, '{preset}' photon rate, "
              f"seed {seed}; written in the ATL03 layout to {source_name(photons)} and read "
              "back." if simulated else f"Photons read from {source_label(photons)}.")
    counts = (blocks.groupby(["length", "flag"]).size().unstack(fill_value=0).reset_index()
              if len(blocks) else pd.DataFrame())
    counts = (report_stats_table(counts.rename_axis(columns=None)).rename(
        columns={f: f"{f} (blocks)" for f in FLAGS}) if len(counts) else counts)
    beams = [str(t.track) for t in tracks]
    sections = [summary_section(
        lead, source=source_name(photons) + (" (simulated)" if simulated else ""),
        n_tracks=len(tracks), n_photons=int(sum(len(t) for t in tracks)), beams=beams,
        lengths=params.lengths, tiles=tiles, n_blocks=len(blocks),
        map_png=map_png)]
    fp_paper = layers.get(f"{LAYER_STATS}_footprint")
    if fp_paper is not None:
        sections.append(paper_section(fp_paper, reference=_FOOTPRINT_WORDS,
                                      layer=f"{LAYER_STATS}_footprint", lead=lead))
    else:
        sections.append(paper_section(stats, reference=_CORRIDOR_WORDS, layer=LAYER_STATS,
                                      lead=lead))
    sections += [
        ReportSection("Inputs", [
            source,
            "Airborne tiles: " + ", ".join(t.name for t in tiles) + ".",
            f"Block lengths {', '.join(f'{v:g}' for v in params.lengths)} m; corridor width "
            f"{width:g} m; reference rasters at {resolution:g} m from PDAL; vertical datums: "
            + ("the tiles' own (the photons were simulated from them)." if simulated
               else datum),
        ]),
        ReportSection("Block heights (the paper's method)", [
            f"{len(blocks)} blocks, {int((blocks['flag'] == FLAG_OK).sum())} flagged ok "
            f"(layer '{LAYER_BLOCKS}' of blocks.gpkg; estimators "
            f"{blocks['estimators'].iloc[0] if 'estimators' in blocks and len(blocks) else 'paper'})."],
            {"blocks per length and flag": counts},
            [p for p in plots if p.name == "profile.png"]),
        ReportSection("The paper's method against the corridor maximum", [
            "Reference: the corridor maximum -- the highest DSM cell and the mean DTM of the "
            f"cells a {width:g} m corridor touches. Sparse photons rarely hit the single "
            "highest crown of a corridor, so this reference sits above what photons can see; "
            "the footprint-matched reference of the summary is the like-with-like one. "
            "Residual = photon value minus reference value, per block, over blocks flagged ok "
            "whose corridor lies inside the rasters. r2 and slope are of the OLS fit of the "
            f"photon values on the reference values (layer '{LAYER_STATS}')."],
            details_stats(stats),
            [p for p in plots if p.name not in ("profile.png", map_png.name)]),
    ]
    if compared is not None and compare_preset:
        _, pstats, ptable = compared
        words, tables = bias_calibration_part(ptable, compare_preset)
        sections.append(ReportSection(
            f"The '{compare_preset}' estimators against the corridor maximum", [
                f"Layer '{LAYER_STATS}_{compare_preset}'. {words}"],
            {**details_stats(pstats), **tables}))
    if seed002 is not None:
        sections.append(ReportSection("Simulated photons against truth", [
            "Each simulated footprint keeps its truth (ground = the lowest peak of the "
            "pseudo-waveform, top = the highest return). The photons are classified by "
            "steps of 20 photons (ground below min + 3 PSF, canopy top above max - 1 m) and "
            "compared with the truth, over many realisations per footprint diameter. "
            "Residual = photon minus truth, metres."],
            {"residuals per footprint diameter (m)": seed002},
            [seed002_png] if seed002_png is not None else []))
    if calibration is not None:
        sections.append(ReportSection("Calibrated cut-offs of the paper's method", [
            "The canopy-top and ground fractions fitted to the corridor reference. The RMSE "
            "columns are held out: cut-offs fitted on the even blocks are scored on the odd "
            "blocks and vice versa. Layers residuals_calibrated and stats_calibrated of "
            "validation.gpkg hold the validation with the cut-offs fitted on all blocks."],
            {"calibrated cut-offs (fractions of the block's photons) and their held-out "
             "RMSE (m)": calibration_table(calibration)}))
    if offsets is not None:
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
        sections.append(ReportSection("Co-registration", [
            "Offsets (m) that would align the blocks with the DTM: the shift to add to the "
            "reported positions. An offset is 'ok' only when, fitted on some stretches of "
            "the track, it also improves the held-out stretches significantly. " + applied],
            {"offsets (m)": rows}))
    return write_report(out / "report.html", "canopyblocks: block heights and validation",
                        sections)
