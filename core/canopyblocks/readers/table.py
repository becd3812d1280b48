"""Photon tracks from plain tables: CSV or (Geo)Parquet.

Two shapes are accepted:

* geographic: ``lon``, ``lat`` (WGS84 degrees) and ``h`` (metres) columns;
* metric: ``x``, ``y`` and ``z`` (or ``h``) columns plus the CRS of ``x``/``y``
  (the ``crs`` argument; GeoParquet carries its own).  A table without a CRS for
  ``x``/``y`` is refused (:class:`~canopyblocks.errors.CRSError`).

Optional columns: ``time`` (s; default the row order), ``s`` (along-track metres;
default fitted), ``track``, ``signal_conf``, ``classification``.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj

from ..errors import CRSError, DependencyError, FileFormatError, InputError, NoUsableDataError
from ..geo import WGS84, as_crs
from ..photons import PhotonTrack
from ._common import bbox_mask, check_bbox, check_s_range, s_mask
from .photon_checks import drop_invalid_photons, valid_photon_mask

__all__ = ["read_table", "TABLE_SUFFIXES"]

log = logging.getLogger(__name__)

TABLE_SUFFIXES = (".csv", ".txt", ".parquet", ".geoparquet")


def _load(path: Path) -> tuple[pd.DataFrame, pyproj.CRS | None]:
    """Read the table; return it and the CRS a GeoParquet file carries (if any)."""
    if not path.exists():
        raise FileFormatError(f"{path}: file does not exist")
    suf = path.suffix.lower()
    if suf not in TABLE_SUFFIXES:
        raise InputError(f"{path}: unknown table suffix {suf!r}; use one of "
                         f"{', '.join(TABLE_SUFFIXES)}")
    if suf in (".parquet", ".geoparquet"):
        try:
            import pyarrow.parquet as pq
        except ImportError:
            raise DependencyError(
                "reading Parquet needs pyarrow: pip install 'canopyblocks[parquet]'") from None
        try:
            meta = pq.read_schema(path).metadata or {}
            if b"geo" in meta:
                import geopandas as gpd

                gdf = gpd.read_parquet(path)
                crs = gdf.crs
                if gdf.geometry.notna().any() and (gdf.geom_type.dropna() == "Point").all():
                    gdf = gdf.assign(_gx=gdf.geometry.x, _gy=gdf.geometry.y)
                return pd.DataFrame(gdf.drop(columns=gdf.geometry.name)), crs
            return pd.read_parquet(path), None
        except (OSError, ValueError, TypeError) as exc:
            raise FileFormatError(f"{path}: cannot read as Parquet ({exc})") from None
    try:
        return pd.read_csv(path, sep=None if suf == ".txt" else ",", engine="python"
                           if suf == ".txt" else "c"), None
    except (OSError, ValueError, pd.errors.ParserError, UnicodeDecodeError) as exc:
        # one line: pandas 1.5's tokenizer messages end in a newline
        why = " ".join(str(exc).split())
        raise FileFormatError(f"{path}: cannot read as CSV ({why})") from None


def _num(df: pd.DataFrame, col: str, path: Path) -> np.ndarray:
    try:
        return pd.to_numeric(df[col]).to_numpy(dtype=np.float64)
    except (ValueError, TypeError):
        raise FileFormatError(f"{path}: column {col!r} is not numeric") from None


def read_table(
    path: str | os.PathLike[str],
    *,
    crs: pyproj.CRS | str | int | None = None,
    lon: str = "lon",
    lat: str = "lat",
    h: str = "h",
    x: str = "x",
    y: str = "y",
    z: str = "z",
    time: str = "time",
    track: str | None = None,
    bbox: Sequence[float] | None = None,
    s_range: Sequence[float] | None = None,
    vertical_datum: str = "unknown",
) -> PhotonTrack:
    """Read photons from a CSV or Parquet table.

    Parameters
    ----------
    path : path-like
        ``.csv``, ``.txt`` (delimiter sniffed), ``.parquet`` or ``.geoparquet``.
    crs : CRS-like, optional
        For a lon/lat table: the metric CRS for ``x``/``y`` (default: UTM of the
        track centre).  For an x/y table: the CRS of ``x``/``y`` (required unless
        the file is GeoParquet); a metric projected CRS is kept, any other is
        transformed to WGS84 and projected to UTM.
    lon, lat, h, x, y, z, time : str
        Column names.  Heights: ``h``, else ``z``.
    track : str, optional
        Track id; with a ``track`` column, selects those rows.  Default: the single
        value of the ``track`` column, else the file stem.
    bbox : (lon_min, lat_min, lon_max, lat_max), optional
        WGS84 degrees, applied after reading.
    s_range : (s_min, s_max), optional
        Metres along track, applied after ``s`` was computed on the whole track.
    vertical_datum : str
        Vertical reference of the heights (a table does not say; ``"unknown"``).

    Raises
    ------
    FileFormatError
        Unreadable file, missing or non-numeric columns.
    CRSError
        An x/y table without a CRS.
    InputError
        Several tracks in the file and none chosen, bad bbox/s_range.
    NoUsableDataError
        No rows (after the track/bbox/s_range selection).
    """
    from ..arguments import check_path
    check_path(path, "read_table: path", "a CSV or Parquet file path")
    p = Path(path)
    bb = check_bbox(bbox)
    sr = check_s_range(s_range)
    df, file_crs = _load(p)
    cols = set(df.columns)
    if "track" in cols:
        values = pd.unique(df["track"].astype(str))
        if track is not None:
            df = df[df["track"].astype(str) == str(track)]
            if df.empty:
                raise InputError(f"{p}: no rows with track {track!r}; the file has "
                                 f"{', '.join(values[:20])}")
        elif len(values) > 1:
            raise InputError(f"{p}: holds {len(values)} tracks ({', '.join(values[:20])}); "
                             "choose one with track=...")
        elif len(values) == 1:
            track = values[0]
    name = str(track) if track is not None else p.stem
    if df.empty:
        raise NoUsableDataError(f"{p}: the table has no rows")
    hcol = h if h in cols else (z if z in cols else None)
    if hcol is None:
        raise FileFormatError(f"{p}: no height column {h!r} or {z!r}; columns are "
                              f"{', '.join(map(str, df.columns))}")
    hv = _num(df, hcol, p)
    t = _num(df, time, p) if time in cols else np.arange(len(df), dtype=np.float64)
    s_in = _num(df, "s", p) if "s" in cols else None
    opt = {}
    for c in ("signal_conf", "classification"):
        if c in cols:
            opt[c] = _num(df, c, p).astype(np.int8)
    if lon in cols and lat in cols:
        lo, la = _num(df, lon, p), _num(df, lat, p)
        out_crs = None if crs is None else as_crs(crs, f"CRS for {p}")
    elif {x, y} <= cols or {"_gx", "_gy"} <= cols:
        xc, yc = (x, y) if {x, y} <= cols else ("_gx", "_gy")
        src = file_crs if file_crs is not None else crs
        if src is None:
            raise CRSError(f"{p}: columns {xc!r}/{yc!r} have no CRS; give crs= (e.g. "
                           "EPSG:32612) or store the table as GeoParquet")
        src_crs = as_crs(src, f"CRS of {p}")
        xv, yv = _num(df, xc, p), _num(df, yc, p)
        lo, la = pyproj.Transformer.from_crs(src_crs, WGS84, always_xy=True).transform(xv, yv)
        # keep a metric projected CRS; anything else (degrees, feet) goes to UTM
        out_crs = src_crs if not src_crs.is_geographic and _is_metric(src_crs) else None
        lo, la = np.asarray(lo, np.float64), np.asarray(la, np.float64)
    else:
        raise FileFormatError(
            f"{p}: needs columns {lon!r}/{lat!r} (WGS84 degrees) or {x!r}/{y!r} plus a CRS; "
            f"columns are {', '.join(map(str, df.columns))}"
        )
    masks = {hcol: valid_photon_mask("h_ph", hv), "latitude": valid_photon_mask("lat_ph", la),
             "longitude": valid_photon_mask("lon_ph", lo)}
    if time in cols:
        masks[time] = np.isfinite(t)
    try:
        usable = drop_invalid_photons(p, "the table's rows", masks)
    except FileFormatError as exc:  # a column without one valid value
        raise NoUsableDataError(str(exc).replace("the file is damaged",
                                                 "no row is usable")) from None
    ok = np.ones(len(hv), bool) if usable is None else usable
    tr = PhotonTrack.from_lonlat(
        t[ok], la[ok], lo[ok], hv[ok], track=name,
        s=None if s_in is None or not np.all(np.isfinite(s_in[ok])) else s_in[ok],
        crs=out_crs, source=str(p), vertical_datum=vertical_datum,
        **{k: v[ok] for k, v in opt.items()},
    )
    keep = bbox_mask(tr.lon, tr.lat, bb) & s_mask(tr.s, sr)
    if not keep.any():
        raise NoUsableDataError(f"{p}: no rows inside bbox={bb} s_range={sr}")
    return tr if keep.all() else tr.subset(keep)


def _is_metric(crs: pyproj.CRS) -> bool:
    try:
        from ..geo import require_metric_crs

        require_metric_crs(crs)
        return True
    except CRSError:
        return False
