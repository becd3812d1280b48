"""Validation from files: the one core call behind ``canopyblocks validate``.

A block table (photon blocks) or a footprint table (GEDI) is read, optionally
co-registered against the DTM (DESIGN 2.8: the joint ``all`` offset is searched and applied
before validating, the uncorrected statistics kept beside the corrected ones), validated
against the chosen reference (corridor rasters, ATL08 land segments, or the
footprint-matched ALS reference of DESIGN 2.7) and written atomically with its plots.

Zero usable results is an error, never an empty table with exit 0.
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import pandas as pd

from ..errors import CanopyBlocksWarning, CRSError, InputError, NoUsableDataError
from ..progress import Progress, as_progress
from ..schema import LAYER_FOOTPRINTS, LAYER_RESIDUALS, LAYER_STATS
from ..validation.footprints import (
    LAYER_RESIDUALS_FOOTPRINTS,
    LAYER_STATS_FOOTPRINTS,
    FootprintValidation,
    validate_footprints,
)

__all__ = ["FileValidation", "validate_file", "is_footprint_table", "REFERENCE_KINDS"]

log = logging.getLogger(__name__)

ReferenceKind = Literal["corridor", "atl08", "footprint", "rasters"]
#: The references a block table can be validated against.
REFERENCE_KINDS: tuple[str, ...] = ("corridor", "atl08", "footprint")
"""Reference kinds (``rasters`` is the former name of ``corridor``, still accepted)."""


@dataclass(frozen=True, eq=False)
class FileValidation:
    """What :func:`validate_file` did.

    Attributes
    ----------
    kind : str
        ``"blocks"`` or ``"footprints"``.
    residuals, stats : DataFrame
        The (co-registered, when asked) validation.
    stats_before : DataFrame or None
        Statistics without the co-registration offset (with ``coregister``).
    coregistration : CoregResult or None
        Offsets found (with ``coregister``).
    applied : str
        Name of the offset applied (``"all"``), or ``""`` when none was (undetermined).
    output : Path
    offsets : Path or None
        ``offsets.json`` written beside the output (with ``coregister``).
    datum : str
        How the vertical datums were reconciled.
    files : tuple of Path
        The files written: ``output`` for a GeoPackage, one file per layer for CSV or
        Parquet (:func:`~canopyblocks.outputs.tables.layer_files`).
    """

    kind: str
    residuals: pd.DataFrame
    stats: pd.DataFrame
    stats_before: pd.DataFrame | None
    coregistration: Any
    applied: str
    output: Path
    offsets: Path | None
    datum: str
    files: tuple[Path, ...] = ()

    @property
    def n_used(self) -> int:
        """Blocks or footprints that entered the statistics."""
        return int(self.residuals["use"].sum())


def is_footprint_table(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` holds a waveform footprint table (layer ``footprints`` or a
    table with ``shot_number`` and ``rh98`` columns)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".gpkg":
        from ..outputs.tables import gpkg_layer_names

        try:
            layers = gpkg_layer_names(p)
        except Exception:  # noqa: BLE001 - unreadable: let the block reader say why
            return False
        return LAYER_FOOTPRINTS in layers and "blocks" not in layers
    if suffix in (".parquet", ".csv"):
        try:
            if suffix == ".csv":
                cols = pd.read_csv(p, nrows=0).columns
            else:
                import pyarrow.parquet as pq

                cols = pq.read_schema(p).names
        except Exception:  # noqa: BLE001
            return False
        return "shot_number" in cols and ("rh98" in cols or {"beam", "height"} <= set(cols))
    return False


def _sensor_pixels(path: str | os.PathLike[str], table: pd.DataFrame) -> pd.DataFrame | None:
    """The pixels layer of ESFL footprints (the GeoPackage's, or the table beside a
    .parquet/.csv), None for other footprints or when there is none."""
    from ..validation.flash_footprints import sensor_of

    if sensor_of(table) != "ESFL":
        return None
    from ..outputs.tables import gpkg_layer_names, read_layer
    from .waveforms import pixels_path
    from .waveforms_flash_dual import LAYER_PIXELS

    p = Path(path)
    if p.suffix.lower() == ".gpkg":
        return read_layer(p, LAYER_PIXELS) if LAYER_PIXELS in gpkg_layer_names(p) else None
    side = pixels_path(p)
    return read_layer(side) if side.exists() else None


def _no_results(what: str, path: object, residuals: pd.DataFrame) -> NoUsableDataError:
    reasons = ""
    for col in ("reason", "flag"):
        if col in residuals.columns and len(residuals):
            counts = residuals[col].astype(str).value_counts()
            reasons = "; " + ", ".join(f"{k}: {v}" for k, v in counts.items())
            break
    return NoUsableDataError(
        f"{path}: validated 0 of {len(residuals)} {what}{reasons}; check that the reference "
        "covers the track (same place, CRS and datum) and that the inputs hold usable "
        "results")


def validate_file(
    path: str | os.PathLike[str],
    output: str | os.PathLike[str],
    *,
    reference: ReferenceKind | None = None,
    dtm: str | os.PathLike[str] | None = None,
    dsm_max: str | os.PathLike[str] | None = None,
    dsm_p90: str | os.PathLike[str] | None = None,
    atl08: str | os.PathLike[str] | None = None,
    points: Sequence[str | os.PathLike[str]] = (),
    footprint_params: Any = None,
    width: float | None = None,
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    reference_vertical_crs: Any = None,
    photon_vertical_crs: Any = "EPSG:4979",
    slope_threshold: float = 2.0,
    table_crs: Any = None,
    points_crs: Any = None,
    plots: str | os.PathLike[str] | None = None,
    coregister: bool = False,
    coregister_vertical: bool = False,
    coreg_params: Any = None,
    coregister_photons: str | os.PathLike[str] | None = None,
    reference_statistic: str = "pooled",
    progress: Progress | None = None,
) -> FileValidation:
    """Validate the block or footprint table in ``path`` and write ``output``.

    Parameters
    ----------
    path : path
        Block table (``canopyblocks blocks`` output: GeoPackage layer ``blocks``,
        GeoParquet, CSV) or footprint table (``canopyblocks waveforms`` output).
    output : path
        ``.gpkg`` (layers ``residuals``/``stats``, plus ``stats_uncorrected`` with
        ``coregister``; footprints: ``residuals_footprints``/``stats_footprints``) or
        ``.csv``/``.parquet``.  Must differ from ``path``.
    reference : {"corridor", "atl08", "footprint"}, optional
        Blocks only (default: ``atl08`` when an ``atl08`` file is given, ``footprint``
        when ``points`` are given without a ``dtm``, else ``corridor``): the corridor maximum of the rasters (``dtm``, ``dsm_max``,
        ``dsm_p90``; ``"rasters"``, its former name, is still accepted), ATL08
        land segments (``atl08``), or the footprint-matched ALS reference (``points``).
        Footprint tables are always validated against the footprint reference.
    points : sequence of path
        Airborne LAS/LAZ tiles (``reference="footprint"`` and footprint tables).
    footprint_params : FootprintReferenceParams, optional
        Default: ICESat-2 (13 m) for blocks, GEDI (22 m) for footprints.
    width : float, optional
        Corridor width (m) for the raster reference; default the footprint of the
        blocks' sensor (ICESat-2 13 m, MABEL 2 m, known from the track ids); a table of
        no known sensor needs it.
    geoid, offset, reference_vertical_crs, photon_vertical_crs
        The datum rule (DESIGN 2.6): known-different datums without a conversion are
        refused.
    table_crs : CRS-like
        CRS of a CSV table (CSV carries none).
    plots : folder, optional
        Scatter, aspect and map PNGs.
    coregister : bool
        Search the joint geolocation offset against ``dtm`` (and ``dsm_max``) first and
        validate the shifted table (DESIGN 2.8); ``offsets.json`` is written beside
        ``output`` as ``<stem>_offsets.json``.
    coreg_params : CoregParams, optional
    coregister_photons : path, optional
        With ``coregister``: search the offset from these photons (the file the blocks
        were made from, read in the table's CRS) instead of the table's rows; the same
        offsets as ``coregister_file(coregister_photons, ...)``.
    reference_statistic : {"pooled", "footprint-mean", "footprint-max"}
        Blocks against the footprint reference: the blocks' own statistic of the returns
        pooled over each block (the default), or the mean / maximum over its footprints
        of their RH (:mod:`canopyblocks.reference.footprint_blocks`).

    Raises
    ------
    InputError, CRSError, DatumError, NoUsableDataError (nothing validated)
    """
    from ..arguments import check_path
    check_path(path, "validate_file: path")
    check_path(output, "validate_file: output")
    from ..atomic import check_writable, new_files_removed_on_failure
    from ..outputs.tables import check_output_path, layer_files, read_blocks, read_layer

    prog = as_progress(progress)
    if geoid is not None and offset is not None:
        raise InputError("give either --geoid (a geoid raster) or --offset (a constant), "
                         "not both")
    if reference == "rasters":
        reference = "corridor"
    if reference is None:  # the one place the reference is chosen from what was given
        reference = "atl08" if atl08 is not None else (
            "footprint" if points and dtm is None else "corridor")
    if reference not in REFERENCE_KINDS:
        raise InputError(f"reference must be one of {', '.join(REFERENCE_KINDS)}; "
                         f"got {reference!r}")
    if Path(path).resolve() == Path(output).resolve():
        raise InputError(f"{output}: the output would overwrite the input {path}; give "
                         "another output file")
    check_output_path(output)
    if plots is not None:
        check_writable(plots, folder=True)
    if coregister_photons is not None and not coregister:
        raise InputError("the photons to co-register from are used with --coregister only; "
                         "add --coregister or leave them out")
    if coregister and dtm is None:
        raise InputError("co-registration needs the DTM: give --dtm (and --dsm-max to use "
                         "the canopy surface too)")
    if points:  # the survey as every command takes it (folders, patterns, .vpc, COPC, EPT)
        from .rasters import survey_tiles

        points = survey_tiles(points)
    footprints = is_footprint_table(path)
    if footprints:
        table = read_layer(path, LAYER_FOOTPRINTS) if Path(path).suffix.lower() == ".gpkg" \
            else read_layer(path)
        kind = "footprints"
        if not points:
            raise InputError(f"{path} holds waveform footprints: validate them against the "
                             "airborne tiles with --points TILE.laz")
        if len(table) == 0:
            raise NoUsableDataError(f"{path} holds no footprints; nothing to validate")
        pixels = _sensor_pixels(path, table)
    else:
        pixels = None
        table = read_blocks(path)
        kind = "blocks"
        if len(table) == 0:
            raise NoUsableDataError(f"{path} holds no blocks; nothing to validate (check "
                                    "the photons and block lengths that made it)")
        _check_reference_inputs(reference, dtm, dsm_max, dsm_p90, atl08, points)
        if footprint_params is not None and reference != "footprint":
            warnings.warn(f"the footprint's diameter, cut and weighting (--diameter, --cut, "
                          f"--weighting) apply to the footprint reference only; the "
                          f"{reference} reference ignores them"
                          + (" (its corridor is --width wide)" if reference == "corridor"
                             else ""), CanopyBlocksWarning, stacklevel=2)
    if getattr(table, "crs", None) is None and not (footprints and {"lon", "lat"}
                                                     <= set(table.columns)):
        if table_crs is None:
            raise CRSError(f"{path} carries no CRS (CSV); give its CRS (--table-crs "
                           "EPSG:...)")
        from ..geo import as_crs

        table = table.set_crs(as_crs(table_crs, "--table-crs"))

    coreg = None
    applied = ""
    stats_before = None
    if coregister:
        from ..validation.coregistration_targets import apply_offset
        from .coregister import coregister_file, offset_to_apply

        prog.update(0.0, "co-registration")
        assert dtm is not None  # checked above
        coreg = coregister_file(table if coregister_photons is None else coregister_photons,
                                 dtm, dsm_max,
                                 crs=table_crs if coregister_photons is None
                                 else _horizontal_crs_of(table),
                                 geoid=geoid, offset=offset,
                                 photon_vertical_crs=photon_vertical_crs,
                                 reference_vertical_crs=reference_vertical_crs,
                                 params=coreg_params, progress=prog.sub(0.0, 0.3))
        joint = offset_to_apply(coreg, path if coregister_photons is None  # what was fitted
                                else coregister_photons)
        if joint is not None:
            before = _validate(kind, table, reference, dtm, dsm_max, dsm_p90, atl08, points,
                               footprint_params, width, geoid, offset,
                               reference_vertical_crs, photon_vertical_crs,
                               slope_threshold, points_crs, prog.sub(0.3, 0.6), pixels,
                               statistic=reference_statistic)
            stats_before = before[1]
            shift = joint if coregister_vertical else replace(joint, vertical=0.0)
            table = apply_offset(table, shift, crs=table_crs)
            applied = joint.name
    residuals, stats, datum = _validate(kind, table, reference, dtm, dsm_max, dsm_p90, atl08,
                                        points, footprint_params, width, geoid, offset,
                                        reference_vertical_crs, photon_vertical_crs,
                                        slope_threshold, points_crs,
                                        prog.sub(0.6 if coregister else 0.0, 0.9), pixels,
                                        statistic=reference_statistic)
    if int(residuals["use"].sum()) == 0:
        raise _no_results(kind, path, residuals)
    prog.update(0.9, "writing")
    offsets_path = None
    out = Path(output)
    with (new_files_removed_on_failure(plots) if plots is not None
          else contextlib.nullcontext()):
        if plots is not None:
            _write_plots(kind, residuals, stats, Path(plots), dtm)
        layers = _layer_names(kind)
        tables: dict[str, pd.DataFrame] = {layers[0]: residuals, layers[1]: stats}
        if stats_before is not None:
            tables[f"{layers[1]}_uncorrected"] = stats_before
        from ..outputs.tables import write_layers

        if coreg is not None:
            from .coregister import write_offsets

            offsets_path = write_offsets(coreg, out.with_name(out.stem + "_offsets.json"))
        try:
            write_layers(tables, out)
        except BaseException:
            if offsets_path is not None:
                offsets_path.unlink(missing_ok=True)
            raise
    prog.update(1.0, "validated")
    return FileValidation(kind=kind, residuals=residuals, stats=stats,
                          stats_before=stats_before, coregistration=coreg, applied=applied,
                          output=out, offsets=offsets_path, datum=datum,
                          files=tuple(dict.fromkeys(layer_files(out, tables).values())))


def _horizontal_crs_of(table: pd.DataFrame) -> Any:
    """The table's horizontal CRS (None when it has none): the metric CRS in which the
    photons behind it were blocked."""
    crs = getattr(table, "crs", None)
    if crs is None:
        return None
    return crs.sub_crs_list[0] if crs.is_compound else crs


def _layer_names(kind: str) -> tuple[str, str]:
    if kind == "footprints":
        from ..validation.footprints import LAYER_RESIDUALS_FOOTPRINTS, LAYER_STATS_FOOTPRINTS

        return LAYER_RESIDUALS_FOOTPRINTS, LAYER_STATS_FOOTPRINTS
    return LAYER_RESIDUALS, LAYER_STATS


def _check_reference_inputs(reference: str, dtm: object, dsm_max: object, dsm_p90: object,
                            atl08: object, points: Sequence[object]) -> None:
    rasters = (dtm, dsm_max, dsm_p90)
    if reference == "corridor":
        if atl08 is not None:
            raise InputError("give either the rasters (--dtm ...) or --atl08, not both")
        if any(r is None for r in rasters):
            raise InputError("give --dtm, --dsm-max and --dsm-p90 (or --atl08 FILE, or "
                             "--reference footprint --points TILE.laz)")
    elif reference == "atl08" and atl08 is None:
        raise InputError("--reference atl08 needs --atl08 FILE")
    elif reference == "atl08" and any(r is not None for r in rasters):
        raise InputError("give either the rasters (--dtm ...) or --atl08, not both")
    elif reference == "footprint" and not points:
        raise InputError("--reference footprint needs the airborne tiles: --points TILE.laz")


def _validate(kind: str, table: pd.DataFrame, reference: str, dtm: Any, dsm_max: Any,
              dsm_p90: Any, atl08: Any, points: Sequence[Any], footprint_params: Any,
              width: float | None, geoid: Any, offset: float | None,
              reference_vertical_crs: Any,
              photon_vertical_crs: Any, slope_threshold: float, points_crs: Any,
              prog: Progress, pixels: pd.DataFrame | None = None, *,
              statistic: str = "pooled") -> tuple[pd.DataFrame, pd.DataFrame, str]:
    from ..validation.flash_footprints import sensor_of

    if kind == "footprints" and sensor_of(table) is not None:   # ESFL or dual rows
        from ..validation.flash_footprints import validate_sensor_footprints

        v = validate_sensor_footprints(table, list(points), pixels=pixels,
                                       reference_vertical_crs=reference_vertical_crs,
                                       geoid=geoid, offset=offset, points_crs=points_crs,
                                       definition=getattr(footprint_params, "definition",
                                                          "waveform"),
                                       progress=prog)
        return v.residuals, v.stats, v.datum
    if kind == "footprints":
        from ..validation.footprints import validate_footprints

        v = validate_footprints(table, list(points), params=footprint_params,
                                photon_vertical_crs=photon_vertical_crs,
                                reference_vertical_crs=reference_vertical_crs, geoid=geoid,
                                offset=offset, points_crs=points_crs,
                                slope_threshold=slope_threshold, progress=prog)
        return v.residuals, v.stats, v.datum
    if reference == "atl08" or (atl08 is not None and reference != "footprint"):
        from ..validation.block_validation import validate_atl08

        r = validate_atl08(table, atl08, width=width, progress=prog)
    elif reference == "footprint":
        from ..reference.footprint_params import FootprintReferenceParams
        from ..validation.footprints import validate_blocks_footprint

        r = validate_blocks_footprint(table, list(points),
                                      params=footprint_params or
                                      FootprintReferenceParams.icesat2(),
                                      geoid=geoid, offset=offset,
                                      photon_vertical_crs=photon_vertical_crs,
                                      reference_vertical_crs=reference_vertical_crs,
                                      slope_threshold=slope_threshold, points_crs=points_crs,
                                      statistic=statistic, progress=prog)
    else:
        from ..validation.block_validation import validate_blocks

        r = validate_blocks(table, dtm=dtm, dsm_max=dsm_max, dsm_p90=dsm_p90,
                            width=width, geoid=geoid, offset=offset,
                            reference_vertical_crs=reference_vertical_crs,
                            photon_vertical_crs=photon_vertical_crs,
                            slope_threshold=slope_threshold, progress=prog)
    return r.residuals, r.stats, r.datum


def _write_plots(kind: str, residuals: pd.DataFrame, stats: pd.DataFrame, folder: Path,
                 dtm: Any) -> None:
    if kind == "footprints" and "res_rh98" not in residuals.columns:   # ESFL or dual
        from ..outputs.footprint_maps import plot_footprint_map

        for c in ("res_ground", "res_height"):
            plot_footprint_map(residuals, c, folder / f"footprints_{c}.png", dtm=dtm)
        return
    if kind == "footprints":
        from ..outputs.footprint_maps import write_footprint_plots

        write_footprint_plots(residuals, folder, dtm=dtm)
        return
    from ..outputs.validation_plots import write_validation_plots

    write_validation_plots(residuals, stats, folder)


def validate_footprints_file(
    footprints_path: str | os.PathLike[str],
    las_paths: Sequence[str | os.PathLike[str]],
    output: str | os.PathLike[str],
    *,
    layer: str = LAYER_FOOTPRINTS,
    plots: str | os.PathLike[str] | None = None,
    dtm: str | os.PathLike[str] | None = None,
    progress: Progress | None = None,
    **kwargs: object,
) -> FootprintValidation:
    """Read a footprints layer, validate it, write ``residuals_footprints`` and
    ``stats_footprints`` to ``output`` (a new file; atomically), optionally plots.

    Parameters
    ----------
    footprints_path : path
        GeoPackage (layer ``layer``), GeoParquet or CSV footprint table.
    las_paths : sequence of path
        Airborne LAS/LAZ tiles.
    output : path
        .gpkg (two layers), or .csv/.parquet (``<stem>_<layer><suffix>`` each).  Must
        differ from ``footprints_path``.
    plots : folder, optional
        Scatter (footprint vs reference, ground and RH98) and maps (RH98, residuals).
    dtm : path, optional
        DTM GeoTIFF for the maps' hillshade.
    **kwargs
        Passed to :func:`validate_footprints` (params, geoid, offset, ...).
    """
    from ..atomic import check_writable, new_files_removed_on_failure
    from ..outputs.tables import check_output_path, read_layer, write_layers

    src, dst = Path(footprints_path), Path(output)
    if dst.exists() and src.exists() and dst.resolve() == src.resolve():
        raise InputError(f"-o {dst} is the footprints file itself; write the validation to "
                         "a new file")
    check_output_path(dst)
    if plots is not None:
        check_writable(plots, folder=True)
    table = read_layer(src, layer if src.suffix.lower() == ".gpkg" else None)
    from .rasters import survey_tiles

    result = validate_footprints(table, survey_tiles(las_paths), progress=progress,
                                 **kwargs)  # type: ignore[arg-type]
    ctx = new_files_removed_on_failure(plots) if plots is not None else None
    if ctx is not None:
        with ctx:
            from ..outputs.footprint_maps import write_footprint_plots

            write_footprint_plots(result.residuals, Path(plots),  # type: ignore[arg-type]
                                  dtm=dtm)
            write_layers({LAYER_RESIDUALS_FOOTPRINTS: result.residuals,
                          LAYER_STATS_FOOTPRINTS: result.stats}, dst)
    else:
        write_layers({LAYER_RESIDUALS_FOOTPRINTS: result.residuals,
                      LAYER_STATS_FOOTPRINTS: result.stats}, dst)
    return result
