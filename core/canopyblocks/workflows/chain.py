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
from ..blocks.estimators import preset as named_preset
from ..errors import FileFormatError, InputError
from ..outputs.tables import write_layers, write_table
from ..progress import Progress, as_progress
from ..readers.remote import is_file_object, is_url, source_label, source_name
from ..reference.sensor_width import corridor_width
from ..schema import LAYER_RESIDUALS, LAYER_STATS
from .blocks import blocks_from_file
from .chain_figures import BiasOffer, EstimatorSet, chain_figures
from .chain_photon_report import photon_report
from .chain_report import datum_sentence, lead_result, summary_lines
from .chain_result import ChainResult
from .chain_tiles import _tiles_crs, _vertical_name

__all__ = ["ChainResult", "run_chain"]

log = logging.getLogger(__name__)


def _simulate(las_paths: Sequence[Path], out: Path, *, azimuth: float, diameter: float,
              photon_rate: str, seed: int, realisations: int, progress: Progress
              ) -> tuple[Path, Any, pd.DataFrame | None, Path | None]:
    """Simulate one beam over the tiles; with ``realisations`` > 0 also the study of the
    simulated photons against truth (13 and 17 m footprints) with its table and figure."""
    from ..readers.las import read_las
    from ..simulate import SimParams, line_through, seed002_experiment, simulate_photons
    from ..simulate.plots import plot_cover_residuals
    from ..simulate.writers import write_simulation_atl03

    try:
        points = read_las(list(las_paths), progress=progress.sub(0.0, 0.2))
    except FileFormatError:
        progress.check()  # read_las reports a cancellation as a read error
        raise
    params = SimParams(diameter=diameter, photon_rate=photon_rate)  # type: ignore[arg-type]
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
        write_table(table, out / "truth_residuals.csv", layer="truth_residuals")
        figure = plot_cover_residuals(exp, out / "plots" / "truth_residuals_by_cover.png")
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
    sensor: str = "icesat2",
    sensor_options: Any = None,
    noise: float | None = None,
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
        Corridor width, m; default the footprint of the photons' sensor (ICESat-2 13 m,
        MABEL 2 m: :mod:`canopyblocks.reference.sensor_width`; a photon table of no known
        sensor needs it) and ``diameter`` for simulated photons.
    resolution : float
        Reference raster cell size, m.
    geoid, offset
        Vertical conversion of real photon heights (ellipsoidal) to the tiles' datum.
    realisations : int
        Simulated runs only: photon draws per footprint diameter (13 and 17 m) for the
        study of the photon classification against truth (``truth_residuals.csv``,
        ``plots/truth_residuals_by_cover.png``); 0 skips it.
    calibrate : bool
        Also fit the cut-offs to the reference (DESIGN.md 1.7; first track), recompute the
        blocks with them and validate again: layers ``residuals_calibrated`` and
        ``stats_calibrated``, table ``calibration.csv`` with held-out RMSEs.
    estimators : Estimators, optional
        Block estimators (DESIGN 1.10); default the recommended ones (the ``atl08``
        preset); ``preset("paper")`` for the paper's method.
    calibration : path or BiasCalibration, optional
        Bias calibration applied to the blocks.
    compare_preset : str, optional
        With other estimators than the recommended ones: also compute the blocks with this
        preset (default the recommended one,
        :data:`~canopyblocks.blocks.estimators.RECOMMENDED_PRESET`); with the recommended
        ones: also the paper's method, for its own section. Validated like the user's
        (layers ``residuals_<preset>``, ``stats_<preset>``, with the footprint reference
        also ``residuals_footprint_<preset>``, ``stats_footprint_<preset>``). The report
        leads with the recommended estimators against the footprint-matched reference;
        their bias calibration, fitted against that reference, is written
        (``bias_calibration_<preset>.json``) and offered only when it improves the
        held-out error. None skips the second set.
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
    sensor : {"icesat2", "gedi", "esfl", "dual"}
        What to simulate without ``photons``: ICESat-2 photons (default), GEDI waveforms,
        flash-lidar (ESFL) cubes or dual-wavelength pairs; the waveform sensors go
        through :func:`~canopyblocks.workflows.chain_waveforms.run_waveform_chain` or
        :func:`~canopyblocks.workflows.chain_flash_dual.run_sensor_chain` (as does an
        ESFL or dual file given as ``photons``).
    sensor_options : SensorOptions, optional
        ESFL and dual: the chain's options (``canopyblocks waveforms``'s).
    noise : float, optional
        ESFL and dual simulations: noise sd as a share of the peak (default 0.05).
    """
    from ..arguments import check_path, check_paths
    check_paths(las_paths, "run_chain: las_paths", "a LAS/LAZ path or a non-empty list of them")
    check_path(out_dir, "run_chain: out_dir", "a folder path")
    from ..outputs.profile_plot import plot_profile  # noqa: F401  (fails early without matplotlib)
    from ..reference.rasters import make_reference_rasters
    from ..validation.block_validation import validate_atl08, validate_blocks

    if preset is not None:
        import warnings

        warnings.warn("run_chain(preset=) is deprecated; use photon_rate=", FutureWarning,
                      stacklevel=2)
        photon_rate = preset
    prog = as_progress(progress)
    from .chain_flash_dual import waveform_chain

    waveform = waveform_chain(las_paths, out_dir, photons, sensor, beams=beams,
                               azimuth=azimuth, seed=seed, geoid=geoid, offset=offset,
                               options=sensor_options, noise=noise, progress=prog)
    if waveform is not None:
        return waveform
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
                tiles, out, azimuth=azimuth, diameter=diameter, photon_rate=photon_rate, seed=seed,
                realisations=realisations, progress=prog.sub(0.0, 0.25))
            # simulated heights are the tiles' own heights: same vertical datum by construction
            offset, geoid, photon_vcrs = 0.0, None, _tiles_crs(tiles) or crs
            width = diameter if width is None else width
        ref_vcrs = _tiles_crs(tiles)
        if not simulated:  # the one datum rule, before minutes of work (validate applies it too)
            from ..reference.datum import check_vertical_datums

            check_vertical_datums("EPSG:4979", ref_vcrs, geoid=geoid, offset=offset)
        plots_dir = out / "plots"
        prog.update(0.25, "block heights")
        res = blocks_from_file(photons, params, estimators=estimators, calibration=calibration,
                               beams=beams, channel=channel, atl08=atl08,
                               crs=crs, output=out / "blocks.gpkg", with_photons=True,
                               progress=prog.sub(0.25, 0.4))
        blocks = res.blocks
        width = corridor_width(width, res.track_ids, source=str(photons))
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
        fkw: dict[str, Any] = {"geoid": geoid, "offset": offset,
                               "photon_vertical_crs": photon_vcrs,
                               "reference_vertical_crs": ref_vcrs}
        primary = RECOMMENDED_PRESET if estimators is None else (estimators.name or "custom")
        sets = {primary: EstimatorSet(primary, blocks, res.labels, "",
                                      val.residuals, val.stats)}
        if footprint_reference:
            from ..validation.footprints import validate_blocks_footprint

            vf = validate_blocks_footprint(blocks, tiles, **fkw)
            sets[primary] = sets[primary].with_footprint(vf.residuals, vf.stats)
        other = _other_preset(primary, compare_preset, calibration)
        if other is not None:
            sets[other] = _compare_preset(other, res.tracks, params, rasters, vkw,
                                          prog.sub(0.85, 0.9))
            if footprint_reference:
                vfo = validate_blocks_footprint(sets[other].blocks, tiles, **fkw)
                sets[other] = sets[other].with_footprint(vfo.residuals, vfo.stats)
        for s in sets.values():
            layers.update(s.layers())
        lead = sets.get(RECOMMENDED_PRESET) or sets[primary]
        bias = _lead_bias_calibration(lead, photons, res.tracks, width, out)
        cutoffs, edges = None, None
        if calibrate:
            from .blocks import run_blocks

            prog.update(0.9, "calibrating cut-offs")
            cutoffs, edges = _calibrated_cutoffs(res.tracks[0], val.residuals, params)
            blocks_c, _ = run_blocks(res.tracks, cutoffs.params, estimators=named_preset("paper"))
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
        datum = _vertical_name(ref_vcrs)
        paper = sets.get("paper")
        figures = chain_figures(lead, paper, res.tracks[0], plots_dir, dtm=rasters.dtm,
                                datum=datum, lead_reference=_lead_reference(lead))
        prog.update(0.95, "report")
        report = photon_report(
            out, tiles=tiles, photons=photons, simulated=simulated, params=params,
            width=width, resolution=resolution, primary=sets[primary], lead=lead,
            paper=paper, figures=figures, azimuth=azimuth,
            datum=datum_sentence(val.datum, geoid=geoid, offset=offset, tiles=datum),
            diameter=diameter, photon_rate=photon_rate, seed=seed, bias=bias,
            calibration=None if cutoffs is None else cutoffs.table, cutoff_edges=edges,
            truth_table=seed002, truth_png=seed002_png, offsets=offsets_doc,
            tracks=res.tracks)
        prog.update(1.0, "done")
        return ChainResult(out_dir=out, photons=_as_path(photons), blocks=out / "blocks.gpkg",
                           rasters={"dtm": rasters.dtm, "dsm_max": rasters.dsm_max,
                                    "dsm_p90": rasters.dsm_p90},
                           validation=validation, report=report, plots=figures.all(),
                           stats=val.stats, simulated=simulated,
                           summary=summary_lines(lead_result(lead)))


def _other_preset(primary: str, compare_preset: str | None, calibration: Any) -> str | None:
    """The estimators computed beside the user's: the recommended ones (when the user's
    are others), or the paper's method for its own section (when the user's are the
    recommended ones); none with ``compare_preset`` None or a bias calibration applied."""
    if not compare_preset or calibration is not None:
        return None
    if primary != RECOMMENDED_PRESET:
        return compare_preset if compare_preset != primary else None
    return "paper"


def _calibrated_cutoffs(track: Any, residuals: pd.DataFrame, params: BlockParams
                        ) -> tuple[Any, list[str]]:
    """The paper's cut-offs fitted to the reference, with one warning for all lengths
    whose best cut-off lies on the edge of the searched grid (instead of one per length
    and cut-off); and the words naming those edge cut-offs for the report."""
    import warnings

    from ..blocks.calibration import DEFAULT_GRID, CutoffEdgeWarning
    from ..validation.calibration import calibrate_against_reference

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CutoffEdgeWarning)
        result = calibrate_against_reference(track, residuals, params)
    edge = [w for w in caught if issubclass(w.category, CutoffEdgeWarning)]
    for w in caught:
        if w not in edge:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    words: list[str] = []
    if edge:
        which = sorted({" ".join(str(w.message).split(":")[1].split()[2:4]) for w in edge})
        lengths = sorted({float(str(w.message).split(" m blocks")[0]) for w in edge})
        warnings.warn(
            f"calibrated cut-offs of the {', '.join(f'{v:g}' for v in lengths)} m blocks of "
            f"track {track.track}: the best {' and '.join(which)} lie on the edge of the "
            "searched grid, so the optimum may lie beyond it (at the low edge this is the "
            "window floor of the paper's method, which the recommended estimators avoid)",
            CutoffEdgeWarning, stacklevel=2)
        found: dict[tuple[str, str], set[float]] = {}
        for w in edge:  # '25 m blocks of track gt1r: the best top cut-off 0.001 lies ...'
            msg = str(w.message)
            kind = msg.split("the best ")[1].split()[0]
            value = msg.split(" cut-off ")[1].split()[0]
            found.setdefault((kind, value), set()).add(float(msg.split(" m blocks")[0]))
        lo, hi = min(DEFAULT_GRID), max(DEFAULT_GRID)
        words = [f"{lo:g}..{hi:g}"] + [
            f"the {kind} cut-off {value} of the "
            f"{', '.join(f'{v:g}' for v in sorted(ls))} m blocks"
            for (kind, value), ls in sorted(found.items())]
    return result, words


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


def _compare_preset(name: str, tracks: Any, params: BlockParams, rasters: Any,
                    vkw: dict[str, Any], prog: Progress) -> EstimatorSet:
    """The blocks made with preset ``name`` (with their photon labels), validated against
    the corridor maximum."""
    from ..validation.block_validation import validate_blocks
    from .blocks import run_blocks

    est = named_preset(name)
    blocks, labels = run_blocks(tracks, params, estimators=est, labels=True,
                                progress=prog.sub(0.0, 0.6))
    val = validate_blocks(blocks, dtm=rasters.dtm, dsm_max=rasters.dsm_max,
                          dsm_p90=rasters.dsm_p90, **vkw, progress=prog.sub(0.6, 0.9))
    prog.update(1.0)
    return EstimatorSet(name, blocks, labels, f"_{name}", val.residuals, val.stats,
                        estimators=est)


def _lead_reference(lead: EstimatorSet) -> str:
    return "footprint" if lead.fp_stats is not None else "corridor"


def _lead_bias_calibration(lead: EstimatorSet, photons: Any, tracks: Any, width: float,
                           out: Path) -> BiasOffer:
    """A bias calibration of the lead estimators fitted against the reference they are
    scored on, with its held-out error; written (``bias_calibration_<name>.json``) and
    offered only when it improves the held-out error of every length and metric."""
    from ..errors import NoUsableDataError
    from ..validation.bias_calibration import fit_bias_calibration, write_bias_calibration
    from .blocks import track_strengths

    residuals = lead.lead_residuals
    if "estimators" not in residuals.columns:
        label = lead.estimators.label() if lead.estimators is not None else "paper"
        residuals = residuals.assign(estimators=label)
    reference = _lead_reference(lead)
    try:
        cal = fit_bias_calibration(residuals, strengths=track_strengths(photons, tracks) or None,
                                   preset=lead.name, corridor_width=width, reference=reference,
                                   sources=(source_name(photons),))
    except NoUsableDataError as exc:
        log.warning("no bias calibration for the %s estimators: %s", lead.name, exc)
        return BiasOffer(lead.name, reference, pd.DataFrame(), False, str(exc))
    table = cal.table()
    worse = table[~(table["holdout_rmse_after"] < table["holdout_rmse_before"])]
    if len(worse):
        r = worse.iloc[0]
        why = (f"it does not improve the held-out error everywhere: {r['metric']} at "
               f"{r['length']:g} m "
               f"goes from {r['holdout_rmse_before']:.2f} m to {r['holdout_rmse_after']:.2f} m"
               + (f" ({len(worse)} of {len(table)} rows do not improve)" if len(worse) > 1
                  else ""))
        return BiasOffer(lead.name, reference, table, False, why)
    write_bias_calibration(cal, out / f"bias_calibration_{lead.name}.json")
    return BiasOffer(lead.name, reference, table, True, "")


def _as_path(photons: Any) -> Path | str:
    """A local file as a Path; a URL or an open file by its name in messages."""
    return source_label(photons) if is_url(photons) or is_file_object(photons) else Path(photons)
