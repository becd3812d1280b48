"""Many granules against many tiles (DESIGN 6): the one function behind ``canopyblocks
batch``.

1. Tile index (headers) and units (granule, beam, tiles crossed).
2. Units run serially, in local processes or on Dask; each writes its partition
   ``out/parts/<granule>/<beam>/{blocks,residuals}.parquet``; the manifest
   ``out/manifest.json`` records every unit's status, counts, warnings and error.
   Each unit makes the survey's reference rasters over its beam's corridor
   (``out/rasters/<granule>/<beam>/``; every tile of the unit together, as ``run`` does,
   so the two give the same blocks and residuals).
   A rerun skips units whose partition is complete; a failed unit is reported and the
   others go on.
3. A reduce reads the partitions in unit order and writes one merged table of every
   unit's validated blocks, ``out/residuals.parquet`` (:func:`merged_residuals`),
   ``out/stats.csv`` and ``out/report.html``. The same inputs give byte-identical outputs
   on every backend.
"""

from __future__ import annotations

import functools
import json
import logging
import os
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import pandas as pd

from ...atomic import atomic_output, check_writable, record_written
from ...errors import CanopyBlocksWarning, InputError, NoUsableDataError
from ...progress import Progress, as_progress
from ...readers.tile_checks import check_tile_datums
from ..backends import BACKENDS, Backend, run_items
from .cleanup import (
    complete_outputs,
    private_tempdir,
    refuse_output_in_inputs,
    remove_partial_outputs,
)
from .units import Unit, drop_duplicate_granules, find_units, list_inputs, tile_index
from .work import BatchConfig, corridor_reach, run_unit

__all__ = ["BatchResult", "run_batch", "MANIFEST"]

log = logging.getLogger(__name__)

MANIFEST = "manifest.json"


@dataclass
class BatchResult:
    """What :func:`run_batch` did: units by status, the statistics and the files."""

    out_dir: Path
    units: list[dict] = field(default_factory=list)
    stats: pd.DataFrame | None = None
    skipped: int = 0

    @property
    def failed(self) -> list[dict]:
        """Units that failed (their ``error`` says why)."""
        return [u for u in self.units if u["status"] == "failed"]

    @property
    def not_crossing(self) -> list[dict]:
        """Granules left out because no beam of theirs passes a tile (``error`` says how
        far they pass); status ``skipped`` in the manifest."""
        return [u for u in self.units if u["status"] == "skipped"]


def _load_manifest(out: Path) -> dict[str, dict]:
    p = out / MANIFEST
    if not p.exists():
        return {}
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
        return {u["key"]: u for u in doc.get("units", [])}
    except (OSError, ValueError, KeyError, TypeError):
        log.warning("%s is unreadable; every unit is run again", p)
        return {}


def _check_same_config(out: Path, config: BatchConfig) -> None:
    """Refuse to continue a batch made with other settings: its finished units and its
    rasters would be reused as if made with these (e.g. another corridor width)."""
    p = out / MANIFEST
    try:
        old = json.loads(p.read_text(encoding="utf-8")).get("config")
    except (OSError, ValueError, AttributeError):
        return  # no manifest, or an unreadable one (every unit is run again)
    new = json.loads(json.dumps(asdict(config)))
    if not isinstance(old, dict) or old == new:
        return
    diff = ", ".join(f"{k} {old.get(k)!r} -> {new.get(k)!r}" for k in sorted(new)
                     if old.get(k) != new.get(k))
    raise InputError(f"{out} holds a batch made with other settings ({diff}); its finished "
                     "units and rasters would be reused as if made with these: give another "
                     "output folder, or the same settings to continue it")


def _write_manifest(out: Path, units: dict[str, dict], config: BatchConfig) -> None:
    doc = {"config": asdict(config),
           "units": [units[k] for k in sorted(units)]}
    with atomic_output(out / MANIFEST) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=2, sort_keys=True), encoding="utf-8")


def _complete(out: Path, entry: dict | None) -> bool:
    return bool(entry and entry.get("status") in ("ok", "empty")
                and all((out / f).exists() for f in entry.get("files", [])))


def run_batch(granules: Sequence[str | os.PathLike[str]],
              tiles: Sequence[str | os.PathLike[str]], out_dir: str | os.PathLike[str],
              config: BatchConfig | None = None, *, beams: Sequence[str] = (),
              backend: Backend = "serial", workers: int | None = None,
              scheduler: str | None = None, progress: Progress | None = None) -> BatchResult:
    """Validate many ATL03 granules against many airborne tiles.

    Parameters
    ----------
    granules : sequence of path
        ATL03 files, or folders of them (``*.h5``).
    tiles : sequence of path or URL
        The airborne survey: LAS/LAZ tiles, folders, glob patterns, a ``.vpc``, COPC
        files or EPT datasets (as :func:`~canopyblocks.workflows.rasters.survey_tiles`
        resolves them), in one CRS or several (e.g. UTM zones: each unit is validated on
        the tiles of one CRS; the merged table is in the first's).
    out_dir : path
        Output folder (created; reused by a rerun).
    config : BatchConfig, optional
    beams : sequence of str
        Beams to use (default every beam with photons).
    backend : "serial", "processes" or "dask"
    workers : int, optional
        Default: the machine's cores.
    scheduler : str, optional
        A running Dask scheduler's address (with ``backend="dask"``).
    progress : Progress, optional
        One step per unit; cancellation stops scheduling new units.

    Returns
    -------
    BatchResult

    Raises
    ------
    NoUsableDataError
        No granule crosses any tile, or no unit produced validated blocks.
    InputError
        The output folder is (or lies inside) an input folder; an unknown backend.
    DatumError
        The photons' and the tiles' vertical datums are known to differ and neither
        ``config.geoid`` nor ``config.offset`` converts them (the rule ``validate``,
        ``run`` and ``calibrate`` apply).

    Notes
    -----
    However the batch ends (an error, a cancellation, Ctrl-C, SIGTERM), no partial file
    and no temporary folder of its workers is left, and the complete outputs it kept are
    recorded for the command line's message; a rerun first removes partial files a
    killed batch left.
    """
    from ...arguments import check_path, check_paths
    check_paths(granules, "run_batch: granules")
    check_paths(tiles, "run_batch: tiles")
    check_path(out_dir, "run_batch: out_dir", "a folder path")
    cfg = BatchConfig() if config is None else config
    if not isinstance(cfg, BatchConfig):
        raise InputError(f"run_batch: config must be a BatchConfig (e.g. BatchConfig(offset=0.0)) "
                         f"or None; got {type(cfg).__name__} {str(cfg)[:60]}")
    prog = as_progress(progress)
    if backend not in BACKENDS:
        raise InputError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
    out = Path(out_dir)
    g_paths = drop_duplicate_granules(list_inputs(granules, (".h5",)))
    from ..rasters import survey_tiles

    t_paths = [str(t) for t in survey_tiles(tiles)]
    refuse_output_in_inputs(out, [*granules, *tiles])
    check_writable(out, folder=True)
    prog.update(0.0, "indexing tiles and tracks")
    index = tile_index(t_paths)
    check_tile_datums(t_paths)  # one vertical datum for all tiles
    _check_datums(cfg, t_paths[0])
    _check_same_config(out, cfg)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    remove_partial_outputs(out)  # left by a batch killed before its clean-up
    before = complete_outputs(out)
    try:
        with private_tempdir() as tmp:
            return _run(g_paths, index, out, cfg, beams=beams, backend=backend,
                        workers=workers, scheduler=scheduler, prog=prog, tmp=tmp)
    except BaseException:
        remove_partial_outputs(out)
        record_written(sorted(complete_outputs(out) - before))
        if created and not any(out.iterdir()):  # no empty folder left by a failed batch
            out.rmdir()
        raise


def _check_datums(cfg: BatchConfig, tile: str) -> None:
    """The one datum rule, before any work (each unit's validation applies it again)."""
    from ...errors import DatumError
    from ...readers.survey import source_crs
    from ...reference.datum import check_vertical_datums

    ref = cfg.reference_vcrs if cfg.reference_vcrs is not None else source_crs(tile).crs
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "unknown" is warned by each unit's validation
        try:
            check_vertical_datums(cfg.photon_vcrs, ref, geoid=cfg.geoid, offset=cfg.offset)
        except DatumError as exc:
            where = ("the reference vertical CRS given" if cfg.reference_vcrs is not None
                     else f"tiles such as {tile}")
            raise DatumError(f"{where}: {exc}") from None


def _run(g_paths: list[str], index: list, out: Path, cfg: BatchConfig, *,
         beams: Sequence[str], backend: Backend, workers: int | None, scheduler: str | None,
         prog: Progress, tmp: str) -> BatchResult:
    problems: dict[str, str] = {}
    missed: dict[str, str] = {}
    units = find_units(g_paths, index, beams=beams, problems=problems, missed=missed,
                       reach=corridor_reach(cfg))
    if not units and problems and len(problems) == len(g_paths):  # none could be read
        first = next(iter(problems.values()))
        if len(problems) == 1:
            raise NoUsableDataError(first)
        raise NoUsableDataError(f"none of the {len(g_paths)} granules could be read: "
                                f"{first} (and {len(problems) - 1} more alike)")
    if not units:
        detail = "; ".join(f"{k}: {v}" for k, v in problems.items())
        raise NoUsableDataError(f"none of the {len(g_paths)} granule(s) crosses any of the "
                                f"{len(index)} tile(s); check that they cover the same place"
                                + (f" ({detail})" if detail else ""))
    manifest = _load_manifest(out)
    for g, msg in problems.items():  # unreadable granules: reported, the rest go on
        key = f"{Path(g).name}:*"
        manifest[key] = {"key": key, "granule": g, "beam": "*", "tiles": [],
                         "status": "failed", "error": msg, "n_blocks": 0, "n_validated": 0,
                         "files": [], "warnings": []}
        warnings.warn(f"{key} failed: {msg}", CanopyBlocksWarning, stacklevel=2)
    for g, msg in missed.items():  # granules whose beams pass no tile: listed, not dropped
        key = f"{Path(g).name}:*"
        manifest[key] = {"key": key, "granule": g, "beam": "*", "tiles": [],
                         "status": "skipped", "error": msg, "n_blocks": 0, "n_validated": 0,
                         "files": [], "warnings": []}
    todo = [u for u in units if not _complete(out, manifest.get(u.key))]
    skipped = len(units) - len(todo)
    if skipped:
        log.info("%d of %d units already complete: skipped", skipped, len(units))
    raster_root = out / "rasters"
    done_count = [0]
    unit_prog = prog.sub(0.05, 0.9)

    def done(summary: dict) -> None:
        manifest[summary["key"]] = summary
        _write_manifest(out, manifest, cfg)
        done_count[0] += 1
        for w in summary["warnings"]:
            warnings.warn(f"{summary['key']}: {w}", CanopyBlocksWarning, stacklevel=2)
        unit_prog.report(done_count[0] / max(1, len(todo)),
                         f"{summary['key']}: {summary['status']}")

    fn = functools.partial(run_unit, config=cfg, out_dir=str(out),
                           raster_root=str(raster_root))
    run_items(fn, todo, backend=backend, workers=workers, scheduler=scheduler, done=done,
              cancelled=lambda: _cancel_requested(prog), tmpdir=tmp)
    prog.check()
    _write_manifest(out, manifest, cfg)
    result = BatchResult(out, [manifest[k] for k in sorted(manifest)], skipped=skipped)
    result.stats = _reduce(out, units, manifest, cfg)
    prog.report(1.0, "batch done")
    return result


def _cancel_requested(prog: Progress) -> bool:
    return bool(prog.cancelled is not None and prog.cancelled())


def _reduce(out: Path, units: list[Unit], manifest: dict[str, dict], cfg: BatchConfig
            ) -> pd.DataFrame:
    from ...outputs.report import ReportSection, report_stats_table, write_report
    from ...outputs.tables import read_layer, write_table
    from ...schema import LAYER_RESIDUALS
    from ...validation.stats import block_stats

    frames = []
    for u in units:
        e = manifest.get(u.key)
        if e and e["status"] == "ok":
            frames.append(read_layer(out / e["files"][1]))
    if not frames:
        raise NoUsableDataError(
            "no unit produced validated blocks: " + "; ".join(
                f"{k}: {v['error']}" for k, v in sorted(manifest.items()) if v.get("error")))
    residuals = merged_residuals(frames)
    write_table(residuals, out / "residuals.parquet", layer=LAYER_RESIDUALS)
    stats = block_stats(pd.DataFrame(residuals))
    with atomic_output(out / "stats.csv") as tmp:
        stats.to_csv(tmp, index=False, float_format="%.6f")
    table = pd.DataFrame([{k: e[k] for k in ("key", "status", "n_blocks", "n_validated",
                                             "error")}
                          for e in [*(manifest[u.key] for u in units if u.key in manifest),
                                    *(e for e in manifest.values()
                                      if e["status"] == "skipped")]])
    who = "the paper's method" if cfg.preset == "paper" else f"the '{cfg.preset}' estimator"
    from ..chain.facts import pooled_facts_part
    from ..chain.glossary import glossary_section

    fwords, ftables = pooled_facts_part(pd.DataFrame(residuals), name=cfg.preset,
                                        reference="corridor", layer="stats.csv", out=out)
    write_report(out / "report.html", "canopyblocks batch validation", [
        ReportSection("Units", [f"{len(units)} units (granule, beam, tiles); block lengths "
                                f"{', '.join(f'{v:g}' for v in cfg.lengths)} m, corridor "
                                f"{cfg.width:g} m, preset {cfg.preset}."],
                      {"units": table}),
        ReportSection(f"{who[:1].upper() + who[1:]} against the corridor maximum", [
            f"Statistics of {who} (preset '{cfg.preset}') against the corridor maximum -- "
            "the highest DSM cell and the mean DTM of the cells the corridor touches; "
            "residual = block value minus reference value, metres, all units pooled. The "
            "corridor maximum sits above what sparse photons can see, so canopy heights "
            "look low against it; `run` also validates against the footprint-matched "
            "reference, the like-with-like one.", *fwords],
            {**ftables, f"{who} against the corridor maximum, all units pooled, every "
             "metric and group": report_stats_table(stats)}),
        glossary_section(["block", "Hmax", "corridor maximum", "bias", "RMSE",
                          "95 % interval", "R²", "low_confidence", "sparse",
                          "reference outside", "aspect class", "slope class"]),
    ])
    return stats


def merged_residuals(frames: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """Every unit's validated blocks in one table, in the order given.

    Units of granules in other UTM zones have other CRSs: the merged table is in the first
    unit's CRS, the other units' geometry reprojected and their ``x``/``y`` recomputed from
    their ``lon``/``lat`` (degrees WGS84) in it, so every row's x/y/geometry share one CRS.
    Tables without geometry or CRS are concatenated as they are.

    Parameters
    ----------
    frames : sequence of DataFrame or GeoDataFrame
        The units' residual tables (``parts/<granule>/<beam>/residuals.parquet``).

    Returns
    -------
    DataFrame or GeoDataFrame
        One row per block of every unit; a GeoDataFrame in the first unit's CRS when every
        frame has a geometry and a CRS.
    """
    import geopandas as gpd

    if not all(isinstance(f, gpd.GeoDataFrame) and f.crs is not None for f in frames):
        return pd.concat([pd.DataFrame(f) for f in frames], ignore_index=True)
    crs = frames[0].crs
    same = []
    for f in frames:
        if f.crs != crs:
            from pyproj import Transformer

            f = f.to_crs(crs)
            if {"lon", "lat", "x", "y"} <= set(f.columns):
                to = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
                x, y = to.transform(f["lon"].to_numpy(float), f["lat"].to_numpy(float))
                f = f.assign(x=x, y=y)
        same.append(f)
    return gpd.GeoDataFrame(pd.concat(same, ignore_index=True), crs=crs)
