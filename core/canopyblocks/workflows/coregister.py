"""Co-registration from files: photons, a block table or a footprint table against rasters.

The one core call behind ``canopyblocks coregister``, ``validate --coregister``,
``run --coregister`` and the QGIS algorithm.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..atomic import atomic_output
from ..errors import CoverageError, CRSError, FileFormatError, InputError
from ..geo import as_crs
from ..progress import Progress, as_progress
from ..reference.datum import check_vertical_datums, sample_geoid
from ..reference.raster_sampling import read_surface
from ..schema import LAYER_BLOCKS, LAYER_FOOTPRINTS
from ..validation.coregistration import CoregParams, CoregResult, coregister
from ..validation.coregistration_offset import CoregOffset
from ..validation.coregistration_targets import (
    CoregTargets,
    targets_from_photons,
    targets_from_table,
)

__all__ = ["coregister_file", "table_targets", "write_offsets", "write_cost_surfaces",
           "vertical_shift", "offset_to_apply",
           "read_table_for_coregistration"]

log = logging.getLogger(__name__)

_TABLE_SUFFIXES = (".gpkg", ".parquet", ".csv")


def read_table_for_coregistration(path: str | os.PathLike[str]) -> pd.DataFrame | None:
    """The block or footprint table in ``path``, or None when ``path`` holds photons."""
    from ..outputs.tables import read_layer

    p = Path(path)
    if p.suffix.lower() not in _TABLE_SUFFIXES:
        return None
    if p.suffix.lower() == ".gpkg":
        from ..outputs.tables import gpkg_layer_names

        try:
            layers = gpkg_layer_names(p)
        except Exception as exc:  # noqa: BLE001 - any driver error means unreadable
            raise FileFormatError(f"{p}: not a readable GeoPackage ({exc})") from None
        for name in (LAYER_BLOCKS, LAYER_FOOTPRINTS):
            if name in layers:
                return read_layer(p, name)
        raise InputError(f"{p} has no '{LAYER_BLOCKS}' or '{LAYER_FOOTPRINTS}' layer (layers: "
                         f"{', '.join(layers)}); give photons, blocks or footprints")
    df = read_layer(p)
    if {"ground", "top"} <= set(df.columns):
        return df
    return None  # a photon table


def vertical_shift(lon: np.ndarray, lat: np.ndarray, geoid: str | os.PathLike[str] | None,
                    offset: float | None) -> np.ndarray | float:
    """N (m) to subtract from ellipsoidal heights: a constant, per-point geoid, or 0."""
    if offset is not None:
        return float(offset)
    if geoid is not None:
        return sample_geoid(geoid, lon, lat)
    return 0.0


def coregister_file(
    path: str | os.PathLike[str] | pd.DataFrame,
    dtm: str | os.PathLike[str],
    dsm_max: str | os.PathLike[str] | None = None,
    *,
    beams: tuple[str, ...] = (),
    crs: Any = None,
    table_crs: Any = None,
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    photon_vertical_crs: Any = "EPSG:4979",
    reference_vertical_crs: Any = None,
    min_signal_conf: int | None = None,
    length: float = 10.0,
    params: CoregParams | None = None,
    progress: Progress | None = None,
) -> CoregResult:
    """Search the geolocation offset of every track in ``path`` against the rasters.

    Parameters
    ----------
    path : path or DataFrame
        A photon file (ATL03, MABEL, photon table), a block table or a footprint table
        (GeoPackage layers ``blocks``/``footprints``, GeoParquet, CSV), or such a table
        already in memory.
    dtm, dsm_max : path
        Reference rasters (m). ``dsm_max`` enables the canopy-top term.
    beams : tuple of str
        ATL03 beams / table tracks to use (default all).
    crs : CRS-like, optional
        Metric CRS the photons are projected into (default UTM).
    table_crs : CRS-like, optional
        The CRS of a CSV table's x/y (CSV carries none; ``crs`` is taken when not given).
    geoid, offset : optional
        Conversion of ellipsoidal heights to the rasters' datum (DESIGN 2.6).
    photon_vertical_crs, reference_vertical_crs : CRS-like
        Vertical datums of the heights and of the rasters (default: the DTM's CRS);
        mixing known-different datums without ``geoid``/``offset`` is refused.
    min_signal_conf : int, optional
        ATL03 confidence threshold for photons.
    length : float
        Block length (m) of the windows that pick ground/top photons.
    params : CoregParams, optional
    progress : Progress, optional
    """
    from ..arguments import check_path, check_path_or_frame
    check_path_or_frame(path, "coregister_file: path", "a photon/block/footprint file path or a table (DataFrame)")
    check_path(dtm, "coregister_file: dtm", "a raster path")
    prog = as_progress(progress)
    surface = read_surface(dtm, what="DTM")
    dsm = read_surface(dsm_max, what="DSM") if dsm_max is not None else None
    check_vertical_datums(photon_vertical_crs,
                          reference_vertical_crs if reference_vertical_crs is not None
                          else surface.crs, geoid=geoid, offset=offset)
    prog.update(0.02, "reading")
    table = path if isinstance(path, pd.DataFrame) else read_table_for_coregistration(path)
    if table is not None:
        targets = table_targets(table, surface.crs, beams=beams,
                                crs=table_crs if table_crs is not None else crs, geoid=geoid,
                                offset=offset,
                                source="table" if isinstance(path, pd.DataFrame) else path)
    else:
        from .blocks import read_tracks

        tracks = read_tracks(path, beams=beams, crs=crs, min_signal_conf=min_signal_conf,
                             progress=prog.sub(0.02, 0.2))
        parts: list[CoregTargets] = []
        for i, t in enumerate(tracks):
            n = vertical_shift(t.lon, t.lat, geoid, offset)
            parts.append(targets_from_photons(t, surface.crs, length=length, heights=t.h - n,
                                              min_signal_conf=min_signal_conf, track_index=i))
        targets = CoregTargets.concat(parts)
    try:
        return coregister(targets, surface, dsm, params, progress=prog.sub(0.2, 1.0))
    except CoverageError as exc:  # name the files: the core knows only tracks
        src = "the table" if isinstance(path, pd.DataFrame) else str(path)
        raise CoverageError(f"{dtm} against {src}: {exc}") from None


def offset_to_apply(result: CoregResult, source: object, *, applying: bool = True
                    ) -> CoregOffset | None:
    """The joint offset (``all``, or the one track's) when it is determined; otherwise
    None, with a warning naming ``source`` and why (the one rule of every command).

    Parameters
    ----------
    result : CoregResult
    source : object
        What was co-registered (a path or a name), for the warning.
    applying : bool
        The caller would apply the offset (the warning says it was not); False for a
        command that only reports it.
    """
    import warnings

    from ..errors import CanopyBlocksWarning

    joint = result.offsets.get("all") or next(iter(result.offsets.values()))
    if joint.determined:
        return joint
    tail = ("validated without co-registration" if applying
            else "the offsets are reported as undetermined; do not apply them")
    warnings.warn(f"{source}: geolocation offset undetermined ({joint.reason}); {tail}",
                  CanopyBlocksWarning, stacklevel=2)
    return None


def table_targets(table: pd.DataFrame, raster_crs: Any, *, beams: tuple[str, ...] = (),
                  crs: Any = None, geoid: str | os.PathLike[str] | None = None,
                  offset: float | None = None, source: object = "table") -> CoregTargets:
    """Co-registration targets from a block or footprint table (heights converted to the
    rasters' datum with ``geoid``/``offset``; ``crs`` for a table that carries none)."""
    tcrs = getattr(table, "crs", None)
    if tcrs is None:
        if crs is None:
            raise CRSError(f"{source} carries no CRS (CSV); give its CRS (e.g. EPSG:32612)")
        tcrs = as_crs(crs, "crs")
    tcol = "track" if "track" in table.columns else "beam"
    if beams:
        table = table[table[tcol].astype(str).isin(beams)]
        if table.empty:
            raise InputError(f"{source}: none of the tracks {', '.join(beams)} is in the "
                             "table")
    heights = table[["ground", "top"]].copy()
    if geoid is not None or offset is not None:
        if {"lon", "lat"} <= set(table.columns):
            lon, lat = table["lon"].to_numpy(float), table["lat"].to_numpy(float)
        else:
            from ..geo import from_metric

            lon, lat = from_metric(table.geometry.x.to_numpy(float),
                                   table.geometry.y.to_numpy(float), as_crs(tcrs))
        n = vertical_shift(np.asarray(lon), np.asarray(lat), geoid, offset)
        heights = heights.sub(n, axis=0) if isinstance(n, np.ndarray) else heights - n
    return targets_from_table(table, tcrs, raster_crs, heights=heights)


def write_offsets(result: CoregResult, path: str | os.PathLike[str]) -> Path:
    """``offsets.json``: one entry per track and ``all`` (see :class:`CoregOffset`), plus
    ``_meta`` (sign convention, CRS, parameters); written atomically."""
    from ..arguments import check_instance, check_path
    check_instance(result, CoregResult, "write_offsets: result", "a CoregResult (coregister or coregister_file)")
    check_path(path, "write_offsets: path", "a .csv or .json path")
    p = Path(path)
    doc: dict[str, object] = dict(result.to_dict())
    doc["_meta"] = {
        "convention": ("east/north/along_track/cross_track/vertical (m): the shift to ADD to "
                       "the reported positions and heights to align them with the reference; "
                       "cross-track positive to the right of the direction of travel; "
                       "east/north in the reference rasters' CRS"),
        "crs": next(iter(result.offsets.values())).crs_wkt if result.offsets else None,
        "params": {k: getattr(result.params, k) for k in result.params.__dataclass_fields__},
    }
    with atomic_output(p) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=2), encoding="utf-8")
    return p


def write_cost_surfaces(result: CoregResult, path: str | os.PathLike[str]) -> Path:
    """The cost-surface figure of ``result`` (one panel per track and ``all``) as a PNG
    at ``path``, atomically."""
    from ..outputs.coregistration_plot import write_cost_surfaces as write

    return write(result, path)
