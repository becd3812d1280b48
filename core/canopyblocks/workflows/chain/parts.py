"""The steps the stages of :mod:`.stages` call: simulating photons over the tiles,
the second estimator set, co-registration, the paper's cut-offs fitted to the corridor
maximum and the lead estimators' bias calibration."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from ...blocks import BlockParams
from ...blocks.estimators import RECOMMENDED_PRESET
from ...blocks.estimators import preset as named_preset
from ...errors import FileFormatError
from ...outputs.tables import write_table
from ...progress import Progress
from ...readers.remote import is_file_object, is_url, source_label, source_name
from .figures import BiasOffer, EstimatorSet

__all__: list[str] = []

log = logging.getLogger(__name__)


def _simulate(las_paths: Sequence[Any], out: Path, *, azimuth: float, diameter: float,
              photon_rate: str, seed: int, realisations: int, progress: Progress,
              crs: Any = None) -> tuple[Path, Any, pd.DataFrame | None, Path | None]:
    """Simulate one beam over the tiles (their points reprojected to ``crs`` when it is
    not theirs); with ``realisations`` > 0 also the study of the simulated photons against
    truth (13 and 17 m footprints) with its table and figure."""
    from ...readers.survey import read_survey
    from ...simulate import SimParams, line_through, seed002_experiment, simulate_photons
    from ...simulate.plots import plot_cover_residuals
    from ...simulate.writers import write_simulation_atl03

    try:
        points = read_survey(list(las_paths), progress=progress.sub(0.0, 0.2), to_crs=crs)
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

    from ...blocks.calibration import DEFAULT_GRID, CutoffEdgeWarning
    from ...validation.calibration import calibrate_against_reference

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

    from ...reference.datum import check_vertical_datums
    from ...reference.raster_sampling import read_surface
    from ...validation.block_validation import validate_blocks
    from ...validation.coregistration import coregister
    from ...validation.coregistration_targets import (
        CoregTargets,
        apply_offset,
        targets_from_photons,
    )
    from ..coregister import offset_to_apply, vertical_shift, write_offsets

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
    from ...validation.block_validation import validate_blocks
    from ..blocks import run_blocks

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
    from ...errors import NoUsableDataError
    from ...validation.bias_calibration import fit_bias_calibration, write_bias_calibration
    from ..blocks import track_strengths

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
