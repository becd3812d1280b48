"""Footprint figures for the report: maps of RH98 and residuals, footprint vs reference.

* :func:`plot_footprint_map`: footprint circles coloured by a column (sequential for
  RH98, diverging and centred on 0 for residuals) over a hillshade of the DTM when a DTM
  GeoTIFF is given, else over the footprints' own extent; axes in metres of the
  residuals' CRS (the airborne points' CRS).
* :func:`plot_footprint_scatter`: footprint vs reference per metric (ground, RH98) with
  the 1:1 line and n / RMSE / bias (footprints with ``use`` only).
* :func:`write_footprint_plots`: all of them into a folder.

All PNGs are written atomically (Agg backend, no display).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..errors import DependencyError, FileFormatError, InputError
from ..validation.stats import error_stats
from .plotting import new_figure, save_figure

__all__ = ["plot_footprint_map", "plot_footprint_scatter", "write_footprint_plots",
           "hillshade"]

log = logging.getLogger(__name__)

_LABELS = {"rh98": "RH98 (m)", "ground": "ground (m)", "rh50": "RH50 (m)", "cover": "cover (fraction)",
           "res_rh98": "RH98 residual (m)", "res_ground": "ground residual (m)",
           "res_rh50": "RH50 residual (m)", "res_cover": "cover residual (fraction)",
           "res_hmax": "Hmax residual (m)", "res_top": "canopy-top residual (m)",
           "res_h90": "H90 residual (m)", "hmax": "Hmax (m)", "ref_hmax": "reference Hmax (m)"}


def hillshade(dem: np.ndarray, xres: float, yres: float, azimuth: float = 315.0,
              altitude: float = 45.0) -> np.ndarray:
    """Hillshade 0..1 of a north-up DEM (Horn slope/aspect; NaN where undefined)."""
    from ..reference.terrain import horn_slope_aspect

    slope, aspect = horn_slope_aspect(dem, xres, yres)
    s, a = np.radians(slope), np.radians(np.nan_to_num(aspect))
    az, alt = np.radians(azimuth), np.radians(altitude)
    hs = np.sin(alt) * np.cos(s) + np.cos(alt) * np.sin(s) * np.cos(az - a)
    return np.clip(hs, 0.0, 1.0)


def _dtm_window(dtm: str | os.PathLike[str], bounds: tuple[float, float, float, float]
                ) -> tuple[np.ndarray, tuple[float, float, float, float], float, float] | None:
    try:
        import rasterio
        from rasterio.windows import Window
    except ImportError:
        raise DependencyError("a DTM hillshade needs rasterio: pip install "
                              "'canopyblocks[raster]'") from None
    if not os.path.exists(dtm):
        raise FileFormatError(f"DTM raster {dtm}: no such file")
    try:
        with rasterio.open(dtm) as src:
            t = src.transform
            if t.b != 0 or t.d != 0 or t.a <= 0 or t.e >= 0:
                log.warning("the DTM %s is not a north-up grid; map without hillshade", dtm)
                return None
            c0 = max(int(np.floor((bounds[0] - t.c) / t.a)), 0)
            c1 = min(int(np.ceil((bounds[2] - t.c) / t.a)), src.width)
            r0 = max(int(np.floor((bounds[3] - t.f) / t.e)), 0)
            r1 = min(int(np.ceil((bounds[1] - t.f) / t.e)), src.height)
            if c1 <= c0 or r1 <= r0:
                return None  # the DTM does not reach the footprints
            data = src.read(1, window=Window(c0, r0, c1 - c0, r1 - r0),
                            masked=True).astype(float).filled(np.nan)
    except rasterio.errors.RasterioIOError as exc:
        raise FileFormatError(f"DTM raster {dtm}: cannot read ({exc})") from None
    extent = (t.c + c0 * t.a, t.c + c1 * t.a, t.f + r1 * t.e, t.f + r0 * t.e)
    return data, extent, abs(t.a), abs(t.e)


def _dtm_crs(dtm: str | os.PathLike[str]) -> Any:
    """The DTM's CRS (pyproj), or None when it states none or cannot be read."""
    try:
        import pyproj
        import rasterio

        with rasterio.open(dtm) as src:
            return None if src.crs is None else pyproj.CRS.from_user_input(src.crs.to_wkt())
    except Exception:  # the map then draws without a hillshade, with a warning
        return None


def _in_dtm_crs(gdf: Any, dtm: str | os.PathLike[str] | None) -> Any:
    """``gdf`` in the DTM's horizontal CRS when the two differ (so the hillshade lies under
    the polygons); unchanged when either CRS is unknown."""
    if dtm is None or getattr(gdf, "crs", None) is None or not os.path.exists(dtm):
        return gdf
    crs = _dtm_crs(dtm)
    if crs is None:
        return gdf
    horiz = crs.sub_crs_list[0] if crs.is_compound else crs
    gcrs = gdf.crs.sub_crs_list[0] if gdf.crs.is_compound else gdf.crs
    return gdf if horiz.equals(gcrs) else gdf.to_crs(horiz)


def _crs_label(gdf: Any) -> str:
    """' EPSG:NNNN' of a GeoDataFrame's horizontal CRS for the axis labels, or ''."""
    crs = getattr(gdf, "crs", None)
    if crs is None:
        return ""
    horiz = crs.sub_crs_list[0] if crs.is_compound else crs
    code = horiz.to_epsg()
    return f", EPSG:{code}" if code else ""


def _hatched_label(gdf: pd.DataFrame, hatched: np.ndarray, only_used: bool) -> str:
    """The legend of the hatched (uncoloured) shapes, counted by reason as the report's
    counts are (one reason a block, by ``validation.residuals.LEFT_OUT_PRECEDENCE``: the
    reference's flag, else the block's, else not used, else no value)."""
    from ..validation.residuals import block_reasons

    n = len(gdf)
    flag = (gdf["flag"].astype(str).to_numpy(object) if "flag" in gdf
            else np.full(n, "ok", object))
    rflag = (gdf["ref_flag"].astype(str).to_numpy(object) if "ref_flag" in gdf
             else np.full(n, "ok", object))
    use = (gdf["use"].fillna(False).to_numpy(bool) if (only_used and "use" in gdf)
           else np.ones(n, bool))
    why = block_reasons(flag, rflag, use)
    why = np.where(why == "", "no value", why)
    reasons, counts = np.unique(why[hatched].astype(str), return_counts=True)
    return "not in the statistics: " + "; ".join(
        f"{r} {int(c)}" for r, c in zip(reasons, counts, strict=True))


def plot_footprint_map(residuals: Any, column: str, path: str | os.PathLike[str], *,
                       dtm: str | os.PathLike[str] | None = None, only_used: bool = True,
                       title: str | None = None) -> Path:
    """Footprint circles coloured by ``column`` (residuals ``res_*`` diverging around 0).

    Parameters
    ----------
    residuals : GeoDataFrame
        From :func:`~canopyblocks.validation.footprints.validate_footprints` (polygons in
        a metric CRS; drawn in the DTM's CRS when a DTM in another CRS is given).
    column : str
        Column to colour by.
    path : path
        PNG to write (atomically).
    dtm : path, optional
        DTM GeoTIFF, drawn as a hillshade underneath (the polygons are reprojected to
        its CRS when it differs).
    only_used : bool
        Colour only footprints with ``use``; the others are drawn as grey outlines.
    """
    if column not in residuals.columns:
        raise InputError(f"no column {column!r} in the footprint residuals")
    from matplotlib.collections import PatchCollection
    from matplotlib.colors import TwoSlopeNorm
    from matplotlib.patches import Polygon as MplPolygon

    gdf = _in_dtm_crs(residuals, dtm)
    use = gdf["use"].to_numpy(bool) if (only_used and "use" in gdf.columns) else \
        np.ones(len(gdf), bool)
    vals = gdf[column].to_numpy(float)
    col = use & np.isfinite(vals)
    x0, y0, x1, y1 = (float(v) for v in gdf.total_bounds)
    pad = 0.05 * max(x1 - x0, y1 - y0, 1.0)
    # a narrow track still gets a readable map: at least half as wide as tall (and v.v.)
    side = max(x1 - x0, y1 - y0, 1.0)
    wx, wy = max(0.5 * side - (x1 - x0), 0.0) / 2, max(0.5 * side - (y1 - y0), 0.0) / 2
    bounds = (x0 - pad - wx, y0 - pad - wy, x1 + pad + wx, y1 + pad + wy)
    fig, ax = new_figure(figsize=(7.0, 6.0))
    if dtm is not None:
        got = _dtm_window(dtm, bounds)
        if got is not None:
            data, extent, xr, yr = got
            ax.imshow(hillshade(data, xr, yr), extent=extent, cmap="gray", vmin=0, vmax=1,
                      origin="upper", interpolation="nearest")
        else:
            log.warning("the DTM %s does not reach the footprints; map without hillshade", dtm)
    patches = [MplPolygon(np.asarray(g.exterior.coords), closed=True) for g in gdf.geometry]
    diverging = column.startswith("res_")
    if col.any():
        v = vals[col]
        if diverging:
            lim = float(np.nanmax(np.abs(v))) or 1.0
            norm: Any = TwoSlopeNorm(vcenter=0.0, vmin=-lim, vmax=lim)
            cmap = "RdBu_r"
        else:
            from matplotlib.colors import Normalize

            norm = Normalize(vmin=float(v.min()), vmax=float(v.max()) if v.max() > v.min()
                             else float(v.min()) + 1.0)
            cmap = "viridis"
        pc = PatchCollection([p for p, c in zip(patches, col) if c], cmap=cmap, norm=norm,
                             edgecolor="k", linewidth=0.3, alpha=0.9)
        pc.set_array(v)
        ax.add_collection(pc)
        fig.colorbar(pc, ax=ax, shrink=0.8, label=_LABELS.get(column, column))
    if (~col).any():
        from matplotlib.patches import Patch

        ax.add_collection(PatchCollection([p for p, c in zip(patches, col) if not c],
                                          facecolor="none", edgecolor="0.3", linewidth=0.8,
                                          hatch="///"))
        ax.legend(handles=[Patch(facecolor="none", edgecolor="0.3", hatch="///",
                                 label=_hatched_label(gdf, ~col, only_used))],
                  loc="upper left", bbox_to_anchor=(0.0, -0.16), frameon=False, fontsize=8)
    from matplotlib.ticker import MaxNLocator

    ax.set_xlim(bounds[0], bounds[2])
    ax.set_ylim(bounds[1], bounds[3])
    ax.set_aspect("equal")
    where = _crs_label(gdf)
    ax.set_xlabel(f"x (m{where})")
    ax.set_ylabel(f"y (m{where})")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.xaxis.set_major_locator(MaxNLocator(nbins=4))  # six-digit eastings must not touch
    ax.tick_params(axis="x", labelrotation=30)
    import textwrap

    ax.set_title("\n".join(textwrap.wrap(title or f"Footprints: {_LABELS.get(column, column)} "
                                          f"({int(col.sum())} of {len(gdf)})", 48)),
                 fontsize=10)
    return save_figure(fig, path)


def plot_footprint_scatter(residuals: pd.DataFrame, path: str | os.PathLike[str], *,
                           metrics: Sequence[str] = ("ground", "rh98"),
                           datum: str | None = None) -> Path:
    """Footprint value vs footprint-matched reference, one panel per metric; ``datum``
    (e.g. 'CGVD28 height', the reference's) is named on the ground elevation axes."""
    sub = residuals[residuals["use"].to_numpy(bool)] if "use" in residuals else residuals
    fig, axes = new_figure(figsize=(3.8 * len(metrics), 3.9), ncols=len(metrics),
                           squeeze=False)
    for ax, m in zip(axes[0], metrics):
        if m not in residuals.columns or f"ref_{m}" not in residuals.columns:
            raise InputError(f"no columns {m!r}/'ref_{m}' in the footprint residuals")
        x = sub[f"ref_{m}"].to_numpy(float)
        y = sub[m].to_numpy(float)
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok], y[ok]
        st = error_stats(y, x, allow_empty=True)
        ax.scatter(x, y, s=12, alpha=0.7, color="tab:blue", edgecolor="none")
        if x.size:
            lo, hi = float(min(x.min(), y.min())), float(max(x.max(), y.max()))
            p = 0.05 * (hi - lo if hi > lo else 1.0)
            lim = (lo - p, hi + p)
            ax.plot(lim, lim, color="0.4", lw=1, ls="--")
            ax.set_xlim(lim)
            ax.set_ylim(lim)
            ax.set_aspect("equal")
        label = _LABELS.get(m, m)
        if m == "ground" and datum:
            label = f"ground (m, {datum})"
        ax.set_xlabel(f"ALS reference {label}")
        ax.set_ylabel(f"footprint {label}")
        unit = "" if m == "cover" else " m"   # cover is a fraction of the footprint
        ax.text(0.03, 0.97, f"n = {st['n']}\nRMSE = {st['rmse']:.2f}{unit}\n"
                f"bias = {st['bias']:+.2f}{unit}",
                transform=ax.transAxes, va="top", ha="left", fontsize=8,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.8"})
    fig.suptitle("Footprints vs footprint-matched ALS reference")
    return save_figure(fig, path)


def write_footprint_plots(residuals: Any, folder: str | os.PathLike[str], *,
                          dtm: str | os.PathLike[str] | None = None,
                          datum: str | None = None) -> list[Path]:
    """``footprints_scatter.png``, ``footprints_rh98.png``, ``footprints_res_rh98.png``,
    ``footprints_res_ground.png`` into ``folder`` (``datum``: the reference's vertical
    datum, named on the ground axes)."""
    out = Path(folder)
    paths = [plot_footprint_scatter(residuals, out / "footprints_scatter.png", datum=datum)]
    for c in ("rh98", "res_rh98", "res_ground"):
        paths.append(plot_footprint_map(residuals, c, out / f"footprints_{c}.png", dtm=dtm))
    log.info("wrote %d footprint figures to %s", len(paths), out)
    return paths
