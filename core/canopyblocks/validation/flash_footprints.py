"""Validation of flash-lidar (ESFL) and dual-wavelength footprints against airborne
lidar points.

Each row of the footprints layer (``canopyblocks waveforms`` on an ESFL or dual file) is
compared with what the airborne points show where the instrument looked:

- ESFL (a row merges pixels; their centres are the ``pixels`` layer): the points under
  the row's pixels (:func:`~canopyblocks.reference.pixel_reference.pixel_reference`):
  ``ref_ground`` the class-2 TIN averaged over the pixel centres, ``ref_top`` the
  highest point under the pixels, ``ref_height = ref_top - ref_ground``;
- dual (a Gaussian footprint of sigma 5.5 m, as GEDI's): by default the points formed
  into the noise-free visible/near-infrared pair and read as the footprints' pairs were
  (the file's noise level, the ground finder's parameters, the layer's own centres;
  :mod:`~canopyblocks.reference.dual_reference`); ``definition="points"``: the
  footprint-matched weighted points (:func:`~canopyblocks.reference.footprint.footprint_reference`
  with :meth:`FootprintReferenceParams.gedi`): ``ref_ground`` the weighted mean of the
  ground points, ``ref_height`` its RH98, ``ref_top = ref_ground + ref_height``.

Residuals (estimate minus reference, m) of ``ground``, ``top`` and ``height``; a row
enters the statistics (``use``) when its own flag and the reference's are ``ok``.
Statistics (``schema.STATS_COLUMNS`` plus ``sd``, the residuals' standard deviation) per
metric for ``all``; ``length`` is the row's size (the 5 m cell, or the 22 m footprint).
The vertical-datum rule of :mod:`canopyblocks.reference.datum` applies as for GEDI.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence

import geopandas as gpd
import numpy as np
import pandas as pd
import pyproj
import shapely

from ..errors import InputError, NoUsableDataError
from ..progress import Progress, as_progress
from ..readers.las import LasPoints
from ..reference.datum import apply_vertical_offset, check_vertical_datums
from ..reference.footprint_params import REFERENCE_FLAG_OK, FootprintReferenceParams
from ..schema import FLAG_OK, STATS_COLUMNS
from .footprints import FootprintValidation, _read_points, _tiles_vertical
from .stats import GROUP_ALL, error_stats

__all__ = ["FLASH_METRICS", "validate_sensor_footprints", "sensor_of"]

log = logging.getLogger(__name__)

#: Validated metrics of ESFL and dual rows: footprint column -> reference column.
FLASH_METRICS: dict[str, str] = {"ground": "ref_ground", "height": "ref_height",
                                 "top": "ref_top"}


def sensor_of(footprints: pd.DataFrame) -> str | None:
    """``"ESFL"`` or ``"dual"`` when the layer holds such rows (its ``beam``), else None."""
    if "beam" not in footprints.columns or len(footprints) == 0:
        return None
    kinds = set(footprints["beam"].astype(str).unique())
    for s in ("ESFL", "dual"):
        if kinds == {s}:
            return s
    return None


def _pixel_ref(pts: LasPoints, fp: pd.DataFrame, pixels: pd.DataFrame | None,
               fp_crs: object) -> pd.DataFrame:
    from ..reference.pixel_reference import pixel_reference

    if pixels is None or len(pixels) == 0:
        raise InputError("flash-lidar footprints are validated against the points under "
                         "their pixels: give the pixels layer `canopyblocks waveforms` "
                         "wrote beside them (layer 'pixels' of the GeoPackage, or "
                         "<name>_pixels.parquet/.csv)")
    need = {"shot_number", "x", "y", "pixel_size", "along_x", "along_y"}
    if not need <= set(pixels.columns):
        raise InputError(f"the pixels layer lacks column(s) "
                         f"{', '.join(sorted(need - set(pixels.columns)))}")
    rows = {int(s): i for i, s in enumerate(fp["shot_number"].to_numpy(np.int64))}
    shots = pixels["shot_number"].to_numpy(np.int64)
    known = np.isin(shots, list(rows))
    group = np.array([rows[int(s)] for s in shots[known]], dtype=np.int64)
    px, py = pixels["x"].to_numpy(float)[known], pixels["y"].to_numpy(float)[known]
    ax, ay = float(pixels["along_x"].iloc[0]), float(pixels["along_y"].iloc[0])
    if fp_crs is not None and not pyproj.CRS(fp_crs).equals(pts.crs, ignore_axis_order=True):
        tr = pyproj.Transformer.from_crs(fp_crs, pts.crs, always_xy=True)
        px2, py2 = tr.transform(px, py)
        ex, ey = tr.transform(px + ax, py + ay)
        dx, dy = np.nanmean(np.asarray(ex) - px2), np.nanmean(np.asarray(ey) - py2)
        norm = float(np.hypot(dx, dy))
        px, py, ax, ay = np.asarray(px2), np.asarray(py2), dx / norm, dy / norm
    ref = pixel_reference(pts, px, py, group, len(fp), float(pixels["pixel_size"].iloc[0]),
                          (ax, ay))
    flag = np.where(np.isfinite(ref["ref_ground"].to_numpy(float))
                    & (ref["ref_points"].to_numpy() > 0), REFERENCE_FLAG_OK, "outside")
    return ref.assign(ref_flag=flag.astype(object))


def _footprint_ref(pts: LasPoints, x: np.ndarray, y: np.ndarray,
                   params: FootprintReferenceParams, prog: Progress) -> pd.DataFrame:
    from ..reference.footprint import FootprintCloud, footprint_reference

    ref = footprint_reference(FootprintCloud(pts, params), x, y, progress=prog)
    h = ref["ref_rh98"].to_numpy(float)
    g = ref["ref_ground"].to_numpy(float)
    return pd.DataFrame({"ref_ground": g, "ref_height": h, "ref_top": g + h,
                         "ref_flag": ref["ref_flag"].to_numpy(object)})


def _own_centres(footprints: pd.DataFrame, pts: LasPoints, x: np.ndarray,
                 y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The layer's own point geometry when it is in the points' CRS (the centres the file
    holds, not their round trip through lon/lat: the noise-free pair's reading moves by
    decimetres with nanometres of centre), else ``x, y``."""
    crs = getattr(footprints, "crs", None)
    geom = getattr(footprints, "geometry", None) if isinstance(footprints, gpd.GeoDataFrame) \
        else None
    if geom is None or crs is None or pts.crs is None \
            or not pyproj.CRS(crs).equals(pts.crs, ignore_axis_order=True):
        return x, y
    gx, gy = shapely.get_x(geom.to_numpy()), shapely.get_y(geom.to_numpy())
    ok = np.isfinite(gx) & np.isfinite(gy)
    return np.where(ok, gx, x), np.where(ok, gy, y)


def _dual_read(attrs: dict[str, object]) -> tuple[object, object]:
    """The formation and ground-finder parameters the footprints' pairs were read with
    (the layer's ``noise``, ``bin_size`` and ``dual_params``, from its file); the
    paper's 5 % noise and default reading, with a warning, when the layer does not say."""
    from ..reference.dual_reference import PAPER_NOISE, DualFormParams

    try:
        noise = float(attrs.get("noise", np.nan))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        noise = float("nan")
    if not (np.isfinite(noise) and noise >= 0):
        log.warning("the dual-wavelength footprints do not say their file's noise level: "
                    "the reference reads its pairs with the paper's 5 % noise; for a file "
                    "of another noise level, validate it with `canopyblocks run --photons "
                    "FILE` (its pairs' noise is read from the file)")
        noise = PAPER_NOISE
    kw: dict[str, float] = {"noise": noise}
    try:
        bin_size = float(attrs.get("bin_size", np.nan))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        bin_size = float("nan")
    if np.isfinite(bin_size) and bin_size > 0:
        kw["bin_size"] = bin_size
    return DualFormParams(**kw), attrs.get("dual_params")  # type: ignore[arg-type]


def _dual_formed(ref: pd.DataFrame, pts: LasPoints, x: np.ndarray, y: np.ndarray,
                 attrs: dict[str, object]) -> pd.DataFrame:
    """``ref`` with the dual-wavelength reference's ground, top and height, its pairs read
    as the footprints' were (:func:`_dual_read`); footprints whose pair the ground finder
    reads no ground in are flagged ``no_ground``."""
    from ..reference.dual_reference import dual_reference
    from ..reference.footprint_params import REFERENCE_FLAG_NO_GROUND

    form, params = _dual_read(attrs)
    d = dual_reference(pts, x, y, form, params)  # type: ignore[arg-type]
    ref = ref.copy()
    for c in ("ref_ground", "ref_top", "ref_height"):
        ref[f"{c}_points"] = ref[c].to_numpy(float)   # the points' own, kept beside
        ref[c] = d[c].to_numpy(float)
    flag = ref["ref_flag"].to_numpy(object).copy()
    flag[(flag == REFERENCE_FLAG_OK)
         & (d["ref_waveform_flag"].to_numpy(object) != "ok")] = REFERENCE_FLAG_NO_GROUND
    ref["ref_flag"] = flag
    return ref


def validate_sensor_footprints(
    footprints: pd.DataFrame,
    points: LasPoints | str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    pixels: pd.DataFrame | None = None,
    photon_vertical_crs: object = None,
    reference_vertical_crs: object = None,
    geoid: str | os.PathLike[str] | None = None,
    offset: float | None = None,
    points_crs: object = None,
    definition: str = "waveform",
    progress: Progress | None = None,
) -> FootprintValidation:
    """Validate ESFL or dual-wavelength footprints against the airborne points.

    Parameters
    ----------
    footprints : GeoDataFrame
        The layer ``canopyblocks waveforms`` wrote for an ESFL or dual file (``beam``
        ``ESFL`` or ``dual``; ``ground``, ``top``, ``height``, ``flag``, a point geometry
        with its CRS).
    points : LasPoints or path(s) of LAS/LAZ tiles
        Airborne points (metric CRS; class 2 = ground).
    pixels : DataFrame, optional
        ESFL: the pixels layer (required for ESFL rows).
    photon_vertical_crs, reference_vertical_crs, geoid, offset
        The datum rule, as :func:`~.footprints.validate_footprints` (default: the layer's
        ``attrs["vertical_datum"]``, a simulated file's tiles' datum).
    points_crs : CRS-like, optional
        CRS of tiles that state none.
    definition : {"waveform", "points"}
        Dual rows: ``waveform`` (default) compares them with the points formed into the
        noise-free visible/near-infrared pair and read by the same ground finder with the
        file's noise level and the footprints' parameters (the layer's ``attrs`` ``noise``,
        ``bin_size``, ``dual_params``, which ``canopyblocks waveforms`` sets; the paper's
        5 % noise, with a warning, when absent)
        (:mod:`~canopyblocks.reference.dual_reference`); ``points`` with the weighted points
        (class-2 weighted mean ground, height = RH98 of all returns). ESFL rows: the points
        under their pixels either way.

    Returns
    -------
    FootprintValidation
        Residuals (one row per footprint; circles of the footprint's size) and statistics.

    Raises
    ------
    InputError, DatumError, NoUsableDataError
    """
    from ..arguments import check_frame

    check_frame(footprints, "validate_sensor_footprints: footprints")
    prog = as_progress(progress)
    sensor = sensor_of(footprints)
    if sensor is None:
        raise InputError("the table holds no flash-lidar (ESFL) or dual-wavelength rows "
                         "(column beam = ESFL or dual); validate GEDI footprints with "
                         "validate_footprints")
    missing = [c for c in ("ground", "top", "height", "shot_number") if c not in footprints]
    if missing:
        raise InputError(f"the footprint table lacks column(s) {', '.join(missing)}; pass "
                         "the footprints layer written by `canopyblocks waveforms`")
    fp = footprints.reset_index(drop=True)
    n = len(fp)
    ref_params = FootprintReferenceParams.gedi()
    prog.update(0.0, "reading airborne points")
    pts, x, y, lon, lat = _read_points(points, fp, ref_params, None, points_crs,
                                       prog.sub(0.0, 0.3))
    ref_v = reference_vertical_crs if reference_vertical_crs is not None \
        else _tiles_vertical(pts)
    pv = photon_vertical_crs or footprints.attrs.get("vertical_datum") or "unknown"
    if pv == "unknown":
        pv = "EPSG:4326"   # horizontal only: the datum rule's 'unknown'
    decision = check_vertical_datums(pv, ref_v, geoid=geoid, offset=offset)
    heights = pd.DataFrame({"lon": lon, "lat": lat, "ground": fp["ground"].to_numpy(float),
                            "top": fp["top"].to_numpy(float)})
    if geoid is not None or offset is not None:
        heights = apply_vertical_offset(heights, geoid=geoid, offset=offset,
                                        columns=("ground", "top"))
    prog.update(0.3, "reference")
    if sensor == "ESFL":
        ref = _pixel_ref(pts, fp, pixels, getattr(footprints, "crs", None))
        size = float(footprints.attrs.get("grid_cell", 5.0) or 5.0)
    else:
        if definition not in ("waveform", "points"):
            raise InputError(f"definition={definition!r}; use 'waveform' or 'points'")
        ref = _footprint_ref(pts, x, y, ref_params, prog.sub(0.3, 0.9))
        if definition == "waveform":
            ox, oy = _own_centres(footprints, pts, x, y)
            ref = _dual_formed(ref, pts, ox, oy, dict(footprints.attrs))
        size = ref_params.diameter
    values = {"ground": heights["ground"].to_numpy(float),
              "top": heights["top"].to_numpy(float),
              "height": fp["height"].to_numpy(float)}
    out = pd.DataFrame({"beam": fp["beam"].astype(str).to_numpy(),
                        "shot_number": fp["shot_number"].to_numpy(np.int64)})
    for m, r in FLASH_METRICS.items():
        out[m] = values[m]
        out[r] = ref[r].to_numpy(float)
        out[f"res_{m}"] = values[m] - out[r].to_numpy(float)
    for c in ("ref_ground_points", "ref_height_points", "ref_top_points"):
        if c in ref:   # the dual pair's formed reference keeps the points' values beside
            out[c] = ref[c].to_numpy(float)
    own = fp["flag"].astype(str).to_numpy(object) if "flag" in fp else \
        np.full(n, FLAG_OK, object)
    rflag = ref["ref_flag"].to_numpy(object)
    out["flag"] = np.where(own != FLAG_OK, own, rflag)
    out["ref_flag"] = rflag
    out["use"] = (own == FLAG_OK) & (rflag == REFERENCE_FLAG_OK)
    if not out["use"].any():
        counts = pd.Series(out["flag"]).value_counts().to_dict()
        raise NoUsableDataError(f"none of the {n} {sensor} footprints is usable (flags: "
                                f"{counts}); give tiles under footprints flagged ok")
    geom = shapely.buffer(shapely.points(x, y), size / 2, quad_segs=8)
    residuals = gpd.GeoDataFrame(out, geometry=geom, crs=pts.crs)
    stats = sensor_stats(residuals, length=size)
    prog.update(1.0, "validation done")
    return FootprintValidation(residuals, stats, decision)


def sensor_stats(residuals: pd.DataFrame, *, length: float) -> pd.DataFrame:
    """Statistics per metric of :data:`FLASH_METRICS` over the rows in use
    (``schema.STATS_COLUMNS`` plus ``sd``: the residuals' standard deviation, m)."""
    df = residuals[residuals["use"].to_numpy(bool)]
    rows = []
    for m, r in FLASH_METRICS.items():
        est, ref = df[m].to_numpy(float), df[r].to_numpy(float)
        st = error_stats(est, ref, allow_empty=True)
        d = (est - ref)[np.isfinite(est - ref)]
        rows.append({"length": float(length), "metric": m, "group": GROUP_ALL, **st,
                     "sd": float(d.std(ddof=1)) if d.size > 1 else float("nan")})
    out = pd.DataFrame(rows, columns=[*STATS_COLUMNS, "sd"])
    out["n"] = out["n"].astype(np.int64)
    return out
