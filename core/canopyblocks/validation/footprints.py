"""Validation of waveform footprints (GEDI) against airborne lidar points (DESIGN 4.10).

Each footprint is compared with a footprint-matched reference from the airborne points,
by default defined as the waveform is formed (``FootprintReferenceParams.definition =
"waveform"``, :mod:`canopyblocks.reference.waveform_reference`): the points under the
footprint formed into the waveform the sensor would record (the same Gaussian beam, the
returns' energy, the pulse; no noise) and read by the same L2A algorithm, so ``ground``
is its lowest mode and ``rh98``/``rh50`` the heights above it where its energy,
accumulated from the bottom of its signal, reaches 98/50 % -- the GEDI simulator's truth,
the same function. ``definition="points"`` compares with the weighted points of DESIGN
2.7 instead (:mod:`canopyblocks.reference.footprint`: class-2 weighted mean ground,
weighted percentiles of all returns). Residuals footprint minus reference of ``ground``
(m, absolute, after the vertical-datum conversion), ``rh98``, ``rh50`` (m above ground)
and ``cover`` (0..1), and statistics (``validation.stats.error_stats``) per metric and
group: ``all``, ``beam:<beam>``, ``aspect:<class>``, ``slope:<class>`` and
``cover:<class>`` (classes of the reference cover, a fraction: ``0-0.25``, ``0.25-0.5``,
``0.5-0.75``, ``0.75-1``).  Slope and aspect are the ground plane's through the class-2 points
(both definitions).

A footprint enters the statistics (``use``) when its own ``flag`` is ``ok`` and the
reference's is ``ok``; ``flag`` in the residuals is the footprint's flag when it is not
``ok``, else the reference's (``ok``, ``outside``, ``no_ground``).  The statistics
table has the block statistics' columns (``schema.STATS_COLUMNS``) with ``length`` =
the footprint diameter (m).

Heights: GEDI elevations are WGS84 ellipsoidal (EPSG:4979); airborne lidar is often
orthometric.  The rule of :mod:`canopyblocks.reference.datum` applies: a known
difference without ``geoid``/``offset`` is refused; the footprint ``ground`` (and
``top``) are converted, ``H = h - N``.

:func:`validate_blocks_footprint` is the photon-block counterpart (``validate
--reference footprint``): the block table against
:func:`~canopyblocks.reference.footprint.block_footprint_reference` instead of the
raster corridor values, with the same residual and statistics layers as
:func:`~.block_validation.validate_blocks`.
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import geopandas as gpd
import numpy as np
import pandas as pd
import pyproj
import shapely

from ..errors import CanopyBlocksWarning, CRSError, InputError, NoUsableDataError
from ..geo import as_crs, ground_metres
from ..progress import Progress, as_progress
from ..readers.las import LasPoints
from ..readers.survey import read_survey, source_crs
from ..readers.tile_checks import check_ground_read
from ..reference.datum import apply_vertical_offset, check_vertical_datums
from ..reference.footprint import FootprintCloud, footprint_reference
from ..reference.footprint_blocks import block_footprint_reference, estimate_statistic
from ..reference.footprint_index import footprints_area
from ..reference.footprint_params import (
    REFERENCE_FLAG_NO_GROUND,
    REFERENCE_FLAG_OK,
    REFERENCE_FLAG_OUTSIDE,
    FootprintReferenceParams,
)
from ..reference.terrain import aspect_class, slope_class
from ..schema import FLAG_OK, STATS_COLUMNS
from .block_validation import ValidationResult
from .residuals import compute_residuals
from .stats import GROUP_ALL, _sorted_classes, _used_rows, block_stats, error_stats

__all__ = [
    "FootprintValidation",
    "FootprintOutsideWarning",
    "validate_footprints",
    "validate_blocks_footprint",
    "footprint_stats",
    "cover_class",
    "FOOTPRINT_METRICS",
    "LAYER_RESIDUALS_FOOTPRINTS",
    "LAYER_STATS_FOOTPRINTS",
    "GEDI_VERTICAL_CRS",
    "reference_words",
]

log = logging.getLogger(__name__)

#: Validated footprint metrics: footprint column -> reference column.
FOOTPRINT_METRICS: dict[str, str] = {"ground": "ref_ground", "rh98": "ref_rh98",
                                     "rh50": "ref_rh50", "cover": "ref_cover"}
LAYER_RESIDUALS_FOOTPRINTS = "residuals_footprints"
LAYER_STATS_FOOTPRINTS = "stats_footprints"
#: GEDI elevations: WGS84 ellipsoidal heights.
GEDI_VERTICAL_CRS = "EPSG:4979"
_SETTINGS = ("a1", "a2", "a3", "a4", "a5", "a6")
COVER_CLASSES: tuple[str, ...] = ("0-0.25", "0.25-0.5", "0.5-0.75", "0.75-1")
_ABSOLUTE = ("ground", "top")


class FootprintOutsideWarning(CanopyBlocksWarning):
    """Footprints outside the airborne tiles were excluded from the statistics."""


@dataclass(frozen=True, eq=False)
class FootprintValidation:
    """Residuals per footprint (circles in the points' CRS) and statistics."""

    residuals: gpd.GeoDataFrame
    stats: pd.DataFrame
    datum: str = "unknown"


def cover_class(cover: np.ndarray | float) -> np.ndarray:
    """Cover classes ``0-0.25``, ``0.25-0.5``, ``0.5-0.75``, ``0.75-1`` (cover is a fraction;
    ``unknown`` NaN)."""
    c = np.atleast_1d(np.asarray(cover, dtype=float))
    k = np.clip(np.floor(np.nan_to_num(c) * 4.0).astype(int), 0, 3)
    out = np.asarray(COVER_CLASSES, dtype=object)[k]
    out[~np.isfinite(c)] = "unknown"
    return out


def _positions(fp: pd.DataFrame, crs: pyproj.CRS, table_crs: object
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Footprint centres in ``crs`` (metres) and lon/lat (degrees WGS84)."""
    if {"lon", "lat"} <= set(fp.columns):
        lon, lat = fp["lon"].to_numpy(float), fp["lat"].to_numpy(float)
        tr = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        x, y = tr.transform(lon, lat)
        return np.asarray(x, float), np.asarray(y, float), lon, lat
    geom = getattr(fp, "geometry", None) if isinstance(fp, gpd.GeoDataFrame) else None
    gcrs = getattr(fp, "crs", None) or (as_crs(table_crs, "footprint CRS")
                                        if table_crs is not None else None)
    if geom is None or gcrs is None:
        raise CRSError("the footprint table has no lon/lat columns and no geometry with a "
                       "CRS; give lon/lat or the table's CRS")
    pts = gpd.GeoSeries(geom, crs=gcrs)
    xy = pts.to_crs(crs)
    ll = pts.to_crs("EPSG:4326")
    return (xy.x.to_numpy(float), xy.y.to_numpy(float), ll.x.to_numpy(float),
            ll.y.to_numpy(float))


def _read_points(points: LasPoints | str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
                 fp: pd.DataFrame, params: FootprintReferenceParams, table_crs: object,
                 points_crs: object, prog: Progress
                 ) -> tuple[LasPoints, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    if isinstance(points, LasPoints):
        x, y, lon, lat = _positions(fp, points.crs, table_crs)
        return points, x, y, lon, lat
    paths = [points] if isinstance(points, (str, os.PathLike)) else list(points)
    if not paths:
        raise InputError("no LAS/LAZ tile given; pass --points TILE.laz")
    crs = source_crs(paths[0]).horizontal
    if crs is None:
        if points_crs is None:
            raise CRSError(f"{paths[0]}: the file states no CRS; give the points' CRS")
        crs = as_crs(points_crs, "points CRS")
    given = crs if points_crs is not None else None
    x, y, lon, lat = _positions(fp, crs, table_crs)
    to_crs = None
    if not ground_metres(crs):  # Web Mercator: read into the footprints' UTM zone
        from ..geo import utm_crs_for

        ok = np.isfinite(lon) & np.isfinite(lat)
        to_crs = crs = utm_crs_for(lon[ok], lat[ok]) if ok.any() else crs
        x, y, lon, lat = _positions(fp, crs, table_crs)
    fin = np.isfinite(x) & np.isfinite(y)
    if not fin.any():
        raise NoUsableDataError("no footprint has a finite position; nothing to validate")
    m = params.cut_radius + 5.0
    bbox = (float(x[fin].min() - m), float(y[fin].min() - m), float(x[fin].max() + m),
            float(y[fin].max() + m))
    try:
        pts = read_survey(paths, bbox=bbox, crs=given, to_crs=to_crs,
                       exclude_classes=params.exclude_classes, progress=prog,
                       polygon=footprints_area(x[fin], y[fin], m))  # discs, not the box
    except NoUsableDataError:
        raise NoUsableDataError(
            f"none of the {len(fp)} footprints lies over the airborne tiles "
            f"({', '.join(str(p) for p in paths)}): footprints span {tuple(round(v) for v in bbox)} "
            f"in {crs.to_string()}; give tiles under the footprints") from None
    check_ground_read(pts, "under the footprints", params.ground_class)
    return pts, x, y, lon, lat


def _tiles_vertical(pts: LasPoints) -> str | None:
    """The tiles' vertical CRS when the files state an EPSG code, else None (unknown)."""
    return pts.vertical_datum if pts.vertical_datum.startswith("EPSG:") else None


def validate_footprints(
    footprints: pd.DataFrame,
    points: LasPoints | str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    params: FootprintReferenceParams | None = None,
    photon_vertical_crs: object = None,
    reference_vertical_crs: object = None,
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    table_crs: object = None,
    points_crs: object = None,
    slope_threshold: float = 2.0,
    progress: Progress | None = None,
) -> FootprintValidation:
    """Validate waveform footprints against the footprint-matched airborne reference.

    Parameters
    ----------
    footprints : DataFrame or GeoDataFrame
        Footprint table (``schema.FOOTPRINT_COLUMNS``): at least ``ground``, ``rh98``,
        ``rh50`` and positions (``lon``/``lat`` degrees, or a point geometry with a CRS).
        ``cover``, ``beam``, ``shot_number`` and ``flag`` are used when present.
    points : LasPoints or path(s) of LAS/LAZ tiles
        Airborne points (metric CRS); tiles are read only around the footprints.
    params : FootprintReferenceParams, optional
        Default :meth:`FootprintReferenceParams.gedi` (22 m, points within 1.5 R,
        density weights, ``definition="waveform"``: each footprint against the airborne
        points formed into its waveform and read by the same algorithm -- ground = the
        lowest mode, RH from the energy accumulated from the bottom of the signal, cover
        from the energy; ``definition="points"``: against the weighted points -- ground =
        the class-2 weighted mean, RH = weighted percentiles of all returns). Slope,
        aspect, coverage and the ``outside``/``no_ground`` flags come from the points in
        both; with ``waveform`` the residuals also hold the points' ground and RH98
        (``ref_ground_points``, ``ref_rh98_points``), where a waveform's lowest mode is not
        the terrain (a ground return lost in the noise).
    photon_vertical_crs : CRS-like, optional
        Datum of the footprint elevations; default the table's ``attrs["vertical_datum"]``
        (a simulated file's: its tiles' datum), else GEDI's EPSG:4979 (WGS84 ellipsoid).
    reference_vertical_crs : CRS-like, optional
        Datum of the airborne heights; default the tiles' vertical CRS (unknown ->
        warned, compared as they are).
    geoid, offset
        Conversion ``H = h - N`` (geoid raster of N, or constant N in metres).
    table_crs : CRS-like, optional
        CRS of the footprints' geometry when the table carries none (CSV without lon/lat).
    points_crs : CRS-like, optional
        CRS of tiles that state none.
    slope_threshold : float
        Degrees below which the aspect class is ``flat``.
    Returns
    -------
    FootprintValidation

    Raises
    ------
    DatumError
        Known-different vertical datums without ``geoid``/``offset``.
    NoUsableDataError
        No footprint usable (all outside the tiles, flagged, or without ground points).
    """
    from ..arguments import check_instance

    prog = as_progress(progress)
    params = FootprintReferenceParams.gedi() if params is None else params
    check_instance(params, FootprintReferenceParams, "validate_footprints: params",
                   "a FootprintReferenceParams (e.g. FootprintReferenceParams.gedi())")
    if not (isinstance(points, (LasPoints, str, os.PathLike)) or (
            isinstance(points, (list, tuple)) and points
            and all(isinstance(p, (str, os.PathLike)) for p in points))):
        from ..arguments import describe
        raise InputError(f"validate_footprints: points must be airborne points (read_las) or "
                         f"LAS/LAZ path(s); got {describe(points)}")
    if not isinstance(footprints, pd.DataFrame) or len(footprints) == 0:
        raise NoUsableDataError("the footprint table is empty; nothing to validate")
    missing = [c for c in ("ground", "rh98", "rh50") if c not in footprints.columns]
    if missing:
        raise InputError(f"the footprint table lacks column(s) {', '.join(missing)}; pass "
                         "the footprints layer written by `canopyblocks waveforms`")
    fp = footprints.reset_index(drop=True)
    prog.update(0.0, "reading airborne points")
    pts, x, y, lon, lat = _read_points(points, fp, params, table_crs, points_crs,
                                       prog.sub(0.0, 0.3))
    ref_v = reference_vertical_crs if reference_vertical_crs is not None \
        else _tiles_vertical(pts)
    # the footprints' own datum (a simulated file keeps its tiles'), else GEDI's ellipsoid
    pv = photon_vertical_crs or footprints.attrs.get("vertical_datum") or GEDI_VERTICAL_CRS
    if pv == "unknown":   # simulated from tiles that state no vertical datum: warned
        pv = "EPSG:4326"   # horizontal only: the rule's 'unknown'
    decision = check_vertical_datums(pv, ref_v, geoid=geoid, offset=offset)
    heights = pd.DataFrame({"lon": lon, "lat": lat,
                            **{c: fp[c].to_numpy(float) for c in _ABSOLUTE if c in fp}})
    if geoid is not None or offset is not None:
        heights = apply_vertical_offset(heights, geoid=geoid, offset=offset,
                                        columns=_ABSOLUTE)
    cloud = FootprintCloud(pts, params)
    ref = footprint_reference(cloud, x, y, progress=prog.sub(0.3, 0.8))
    if params.definition == "waveform":
        ref = _waveform_formed(ref, pts, x, y, lon, lat, params, fp)
        prog.update(0.95, "waveform-formed reference")
    n = len(fp)
    out = pd.DataFrame({
        "beam": fp["beam"].astype(str).to_numpy() if "beam" in fp else np.full(n, ""),
        "shot_number": (fp["shot_number"].to_numpy() if "shot_number" in fp
                        else np.arange(n, dtype=np.int64)),
    })
    values = {"ground": heights["ground"].to_numpy(float),
              "rh98": fp["rh98"].to_numpy(float), "rh50": fp["rh50"].to_numpy(float),
              "cover": fp["cover"].to_numpy(float) if "cover" in fp else np.full(n, np.nan)}
    for m, r in FOOTPRINT_METRICS.items():
        out[m] = values[m]
        out[r] = ref[r].to_numpy(float)
        out[f"res_{m}"] = values[m] - out[r].to_numpy(float)
    out["slope"] = ref["ref_slope"].to_numpy(float)
    out["aspect"] = ref["ref_aspect"].to_numpy(float)
    out["aspect_class"] = aspect_class(out["aspect"].to_numpy(), out["slope"].to_numpy(),
                                       slope_threshold)
    out["slope_class"] = slope_class(out["slope"].to_numpy())
    out["cover_class"] = cover_class(out["ref_cover"].to_numpy())
    own = fp["flag"].astype(str).to_numpy(object) if "flag" in fp else np.full(n, FLAG_OK,
                                                                                  object)
    rflag = ref["ref_flag"].to_numpy(object)
    out["flag"] = np.where(own != FLAG_OK, own, rflag)
    out["ref_flag"] = rflag
    out["ref_n_points"] = ref["ref_n_points"].to_numpy()
    out["ref_coverage"] = ref["ref_coverage"].to_numpy(float)
    out["use"] = (own == FLAG_OK) & (rflag == REFERENCE_FLAG_OK)
    out["reference"] = params.definition
    for c in ("ref_ground_points", "ref_rh98_points", "ref_rh50_points"):   # beside the
        # waveform-formed values
        if c in ref:
            out[c] = ref[c].to_numpy(float)
    n_out = int((rflag == REFERENCE_FLAG_OUTSIDE).sum())
    if n_out:
        warnings.warn(f"{n_out} of {n} footprints lie (partly) outside the airborne tiles "
                      f"(less than {params.min_coverage:.0%} of their circle covered); they "
                      "are flagged 'outside' and excluded", FootprintOutsideWarning,
                      stacklevel=2)
    if not out["use"].any():
        counts = pd.Series(out["flag"]).value_counts().to_dict()
        raise NoUsableDataError(
            f"none of the {n} footprints is usable (flags: {counts}); give tiles that cover "
            "footprints flagged ok")
    geom = shapely.buffer(shapely.points(x, y), params.radius, quad_segs=8)
    residuals = gpd.GeoDataFrame(out, geometry=geom, crs=pts.crs)
    stats = footprint_stats(residuals, length=params.diameter)
    prog.update(1.0, "footprint validation done")
    return FootprintValidation(residuals, stats, decision)


def reference_words(definition: str = "waveform", diameter: float = 22.0) -> str:
    """One sentence for a report: what a footprint is compared with (``definition`` of
    :class:`FootprintReferenceParams`)."""
    if definition == "waveform":
        return (f"the airborne points under each footprint formed into the waveform the "
                f"sensor would record (a Gaussian beam {diameter:g} m across, sigma "
                f"{diameter / 4:g} m; each return's energy, canopy 1.5 times ground; the "
                "15.6 ns pulse; no noise added) and read by the same GEDI L2A algorithm, "
                "the simulator's noise level setting only its detection thresholds: ground = its lowest mode, RH = the height above "
                "it where the energy accumulated from the bottom of its signal reaches the "
                "percentile, cover = its canopy share of the energy")
    return (f"the airborne points weighted by a Gaussian footprint {diameter:g} m across: "
            "ground = the weighted mean of the ground points, RH = weighted percentiles of "
            "all returns above a plane through them, cover = the weighted share of returns "
            "more than 2 m above it")


def _waveform_formed(ref: pd.DataFrame, pts: LasPoints, x: np.ndarray, y: np.ndarray,
                     lon: np.ndarray, lat: np.ndarray, params: FootprintReferenceParams,
                     fp: pd.DataFrame) -> pd.DataFrame:
    """``ref`` with ground, RH and cover of the waveform-formed reference; footprints whose
    formed waveform the reading finds no ground in are flagged ``no_ground``."""
    from ..reference.waveform_reference import WaveformFormParams, waveform_reference

    setting = str(fp["setting"].iloc[0]) if "setting" in fp and len(fp) else "a1"
    form = WaveformFormParams.for_diameter(
        params.diameter, setting=setting if setting in _SETTINGS else "a1")
    wref = waveform_reference(pts, x, y, lon, lat, form)
    ref = ref.copy()
    ref["ref_ground_points"] = ref["ref_ground"].to_numpy(float)   # the class-2 mean
    ref["ref_rh98_points"] = ref["ref_rh98"].to_numpy(float)
    ref["ref_rh50_points"] = ref["ref_rh50"].to_numpy(float)
    for c in ("ref_ground", *(f"ref_rh{q}" for q in (50, 75, 90, 95, 98, 100)), "ref_cover"):
        ref[c] = wref[c].to_numpy(float)
    flag = ref["ref_flag"].to_numpy(object).copy()
    lost = (flag == REFERENCE_FLAG_OK) & (wref["ref_waveform_flag"].to_numpy(object) != "ok")
    flag[lost] = REFERENCE_FLAG_NO_GROUND
    ref["ref_flag"] = flag
    return ref


def footprint_stats(residuals: pd.DataFrame, *, length: float,
                    metrics: Sequence[str] = tuple(FOOTPRINT_METRICS),
                    groups: Sequence[tuple[str, str]] = (("beam", "beam"),
                                                         ("aspect", "aspect_class"),
                                                         ("slope", "slope_class"),
                                                         ("cover", "cover_class")),
                    only_used: bool = True) -> pd.DataFrame:
    """Statistics (``schema.STATS_COLUMNS``) per metric and group of footprint residuals.

    ``length`` fills the ``length`` column (the footprint diameter, m).
    """
    df = _used_rows(residuals, metrics, tuple(FOOTPRINT_METRICS), only_used)
    subsets: list[tuple[str, pd.DataFrame]] = [(GROUP_ALL, df)]
    for prefix, col in groups:
        if col not in df.columns:
            continue
        labels = df[col].astype(str)
        for cls in _sorted_classes(labels.tolist()):
            subsets.append((f"{prefix}:{cls}", df[(labels == cls).to_numpy()]))
    rows = []
    for m in metrics:
        for name, sub in subsets:
            st = error_stats(sub[m].to_numpy(float), sub[FOOTPRINT_METRICS[m]].to_numpy(float),
                             allow_empty=True)
            rows.append({"length": float(length), "metric": m, "group": name, **st})
    out = pd.DataFrame(rows, columns=list(STATS_COLUMNS))
    out["n"] = out["n"].astype(np.int64)
    return out


def validate_blocks_footprint(
    blocks: gpd.GeoDataFrame,
    points: LasPoints | str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    params: FootprintReferenceParams | None = None,
    spacing: float = 0.7,
    statistic: str = "pooled",
    top_level: int | None = None,
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    photon_vertical_crs: object = None,
    reference_vertical_crs: object = None,
    slope_threshold: float = 2.0,
    points_crs: object = None,
    progress: Progress | None = None,
) -> ValidationResult:
    """Validate photon blocks against the footprint-matched reference (``validate
    --reference footprint``): like :func:`~.block_validation.validate_blocks`, with
    the reference of :func:`~canopyblocks.reference.footprint_blocks.block_footprint_reference`
    and slope/aspect from the footprints' ground planes; residual polygons are corridors
    one diameter wide. ``statistic`` ``pooled`` (the default) takes the blocks' own
    statistic of the returns pooled over each block (for the ``atl08`` estimators the
    98th / 90th percentile of the returns above the classifier's canopy threshold; for a
    ``pNN`` top, that percentile of all returns; :func:`~canopyblocks.reference.
    footprint_blocks.estimate_statistic` of the table's ``estimators`` column);
    ``footprint-mean`` the mean over the footprints of their RH. ``top_level``
    overrides the percentile. The residuals name the statistic (``ref_statistic``).
    ``points_crs`` is the tiles' CRS when their files state none (``--points-crs``).
    """
    from ..reference.corridor import block_corridors

    prog = as_progress(progress)
    params = params or FootprintReferenceParams()
    if not isinstance(blocks, pd.DataFrame) or len(blocks) == 0:
        raise InputError("the block table is empty; nothing to validate")
    if blocks.crs is None:
        raise CRSError("the block table has no CRS; set it first")
    if isinstance(points, LasPoints):
        pts = points
    else:
        paths = [points] if isinstance(points, (str, os.PathLike)) else list(points)
        if not paths:
            raise InputError("no LAS/LAZ tile given; pass --points TILE.laz")
        tiles_crs = source_crs(paths[0]).horizontal if points_crs is None \
            else as_crs(points_crs, "points CRS")
        # a survey whose metre is not a ground metre (Web Mercator) is read into the
        # blocks' CRS; any other is used in its own
        to_crs = blocks.crs if tiles_crs is not None and not ground_metres(tiles_crs) \
            else None
        if to_crs is None and tiles_crs is not None and blocks.crs is not None and \
                not tiles_crs.equals(blocks.crs, ignore_axis_order=True):
            blocks = blocks.to_crs(tiles_crs)   # the tiles' bbox is in their own CRS
            blocks = blocks.assign(x=blocks.geometry.x, y=blocks.geometry.y)
        m = params.cut_radius + float(blocks["length"].max()) + 5.0
        xb, yb = blocks["x"].to_numpy(float), blocks["y"].to_numpy(float)
        bbox = (float(np.nanmin(xb) - m), float(np.nanmin(yb) - m), float(np.nanmax(xb) + m),
                float(np.nanmax(yb) + m))
        pts = read_survey(paths, bbox=bbox, exclude_classes=params.exclude_classes,
                          crs=tiles_crs if points_crs is not None else None,
                          progress=prog.sub(0.0, 0.3), to_crs=to_crs,
                          polygon=footprints_area(xb, yb, m))  # the corridor, not the box
        check_ground_read(pts, "near the blocks", params.ground_class)
    if not pts.crs.equals(blocks.crs, ignore_axis_order=True):
        blocks = blocks.to_crs(pts.crs)
        blocks = blocks.assign(x=blocks.geometry.x, y=blocks.geometry.y)
    ref_v = reference_vertical_crs if reference_vertical_crs is not None \
        else _tiles_vertical(pts)
    pv = photon_vertical_crs or blocks.attrs.get("vertical_datum") or GEDI_VERTICAL_CRS
    decision = check_vertical_datums(pv, ref_v, geoid=geoid, offset=offset)
    work = apply_vertical_offset(blocks, geoid=geoid, offset=offset)
    label = blocks["estimators"].iloc[0] if "estimators" in blocks.columns else None
    threshold, level = estimate_statistic(None if pd.isna(label) else str(label))
    ref = block_footprint_reference(blocks, pts, params, spacing=spacing,
                                    statistic=statistic,
                                    top_level=level if top_level is None else top_level,
                                    canopy_threshold=threshold,
                                    slope_threshold=slope_threshold,
                                    progress=prog.sub(0.3, 0.95))
    corridors = block_corridors(blocks, width=params.diameter)
    residuals = compute_residuals(work, ref, ref, corridors=corridors)
    residuals["ref_rh98"] = ref["ref_rh98"].to_numpy(float)
    residuals["ref_cover"] = ref["ref_cover"].to_numpy(float)
    residuals["ref_statistic"] = ref["ref_statistic"].to_numpy(object)
    stats = block_stats(residuals)
    prog.update(1.0, "validation done")
    return ValidationResult(residuals, stats, decision)


def __getattr__(name: str) -> object:
    """Names that moved up to a workflow keep working here (see canopyblocks._aliases)."""
    from .._aliases import moved_name

    return moved_name(__name__, name)
