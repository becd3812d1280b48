"""Block heights over many granules at once: one table, with area and time filters.

:func:`blocks_from_granules` runs :func:`~canopyblocks.workflows.blocks.blocks_from_file` on
each granule, all in one metric CRS, and writes one block table with a ``granule``
column (the file name).  Filters:

* ``bbox`` (lon/lat degrees): photons read only inside it (as ``blocks --bbox``);
* ``polygon`` (a vector file of polygons, any CRS): the blocks whose centre lies inside
  the polygons are kept (the same blocks, edges and values as without it);
* ``time_range`` (UTC): granules whose photons were all taken outside it are skipped
  (ATL03: UTC from ``delta_time``, :mod:`canopyblocks.readers.utc_time`).
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from ..errors import CanopyBlocksWarning, InputError, NoUsableDataError
from ..progress import Progress, as_progress

__all__ = ["blocks_from_granules", "granule_time_span", "read_polygon", "parse_utc"]

log = logging.getLogger(__name__)


def parse_utc(text: str, what: str, *, end: bool = False) -> np.datetime64:
    """``2022-04-01`` or ``2022-04-01T22:00:00`` (UTC) as datetime64[ns]; a date alone
    given as an ``end`` means the end of that day (its last nanosecond)."""
    if not isinstance(text, (str, np.datetime64)):
        raise InputError(f"{what}: give a UTC date or date and time as text, e.g. "
                         f"2022-04-01; got {type(text).__name__} {text!r}")
    try:
        t = np.datetime64(str(text).strip().rstrip("Z"))
    except (ValueError, OverflowError):
        raise InputError(f"{what} {text!r}: give a UTC date or date and time, e.g. "
                         "2022-04-01 or 2022-04-01T22:00:00") from None
    if np.isnat(t):
        raise InputError(f"{what} {text!r}: not a date")
    year = int(t.astype("datetime64[Y]").astype(np.int64)) + 1970
    if not 1990 <= year <= 2100:
        raise InputError(f"{what} {text!r}: the year {year} is outside 1990-2100 (ICESat-2 "
                         "and GEDI fly since 2018); give a date of the granules")
    unit = np.datetime_data(t.dtype)[0]
    ns = t.astype("datetime64[ns]")
    if end and unit in ("Y", "M", "W", "D"):
        ns = (t + np.timedelta64(1, unit)).astype("datetime64[ns]") - np.timedelta64(1, "ns")
    return ns


def _distinct(paths: Sequence[str | os.PathLike[str]]) -> list[str | os.PathLike[str]]:
    """``paths`` with a file given twice (the same file, however named) kept once, with a
    warning: blocking it twice would write every row twice."""
    from ..arguments import check_paths
    check_paths(paths, "blocks_from_granules: paths")
    seen: dict[str, str | os.PathLike[str]] = {}
    twice = []
    for p in paths:
        key = os.path.realpath(os.fspath(p))
        if key in seen:
            twice.append(str(p))
        else:
            seen[key] = p
    if twice:
        warnings.warn(f"{', '.join(twice)}: given more than once; each file is blocked once",
                      CanopyBlocksWarning, stacklevel=3)
    return list(seen.values())


def granule_time_span(path: str | os.PathLike[str]) -> tuple[np.datetime64, np.datetime64]:
    """First and last photon time (UTC) of an ATL03 granule, over all its beams."""
    from ..readers._h5 import open_h5
    from ..readers.remote import is_file_object, is_url, source_label
    from ..readers.utc_time import file_counts_from_sdp_epoch, utc_from_delta_time

    if not file_counts_from_sdp_epoch(path):
        raise InputError(f"{path}: written by canopyblocks (simulated), its delta_time "
                         "counts from its first shot; leave --time out")

    lo, hi = np.inf, -np.inf
    label = source_label(path)
    try:
        with open_h5(path) as f:  # the first and last time of each beam: two chunks
            for beam in (k for k in f.keys() if k.startswith("gt")):
                name = f"{beam}/heights/delta_time"
                n = f.shape(name)[0] if f.is_dataset(name) else 0
                if n:
                    ends = [float(f.read(name, np.s_[i:i + 1], dtype=np.float64)[0])
                            for i in (0, n - 1)]
                    lo, hi = min(lo, *ends), max(hi, *ends)
    except OSError:
        if is_url(path) or is_file_object(path):
            raise  # storage failed: its own message
        raise InputError(f"{label}: --time needs ATL03 granules (HDF5); this file is not "
                         "one") from None
    if not np.isfinite(lo):
        raise InputError(f"{path}: no ATL03 photon times (gt*/heights/delta_time); "
                         "--time needs ATL03 granules")
    span = utc_from_delta_time([lo, hi])
    if np.isnat(span).any():
        raise InputError(f"{path}: its delta_time is not on the ICESat-2 clock (a simulated "
                         "file?); leave --time out")
    return span[0], span[1]


def read_polygon(path: str | os.PathLike[str]) -> Any:
    """The union of the polygons of a vector file, as a one-row GeoSeries with its CRS."""
    import geopandas as gpd

    try:
        g = gpd.read_file(path)
    except Exception as exc:  # pyogrio/fiona raise their own types
        raise InputError(f"--polygon {path}: cannot read it as a vector file ({exc})") from None
    poly = g[g.geometry.geom_type.isin(["Polygon", "MultiPolygon"])]
    if not len(poly):
        raise InputError(f"--polygon {path}: it holds no polygon")
    if poly.crs is None:
        raise InputError(f"--polygon {path}: it states no CRS; save it with one")
    import shapely  # shapely's union_all: GeoSeries.union_all needs geopandas 1.0

    return gpd.GeoSeries([shapely.union_all(poly.geometry.to_numpy())], crs=poly.crs)


def blocks_from_granules(paths: Sequence[str | os.PathLike[str]], params: Any, *,
                         output: str | os.PathLike[str],
                         bbox: tuple[float, float, float, float] | None = None,
                         polygon: str | os.PathLike[str] | None = None,
                         time_range: tuple[str, str] | None = None,
                         crs: object = None, progress: Progress | None = None,
                         **kwargs: Any) -> pd.DataFrame:
    """One block table of several granules (column ``granule``), written to ``output``.

    Parameters
    ----------
    paths : sequence of path
        Photon files (ATL03 granules for ``time_range``).
    params : BlockParams
    output : path
        ``.gpkg`` (layer ``blocks``), ``.parquet`` or ``.csv``; written atomically.
    bbox : (lon_min, lat_min, lon_max, lat_max), optional
        Degrees WGS84.
    polygon : path, optional
        Vector file of polygons: blocks whose centre lies inside are kept.
    time_range : (start, end), optional
        UTC dates/times; granules with no photon inside are skipped.
    crs : CRS-like, optional
        Metric CRS of every granule's x/y (default: the UTM zone of the first one read).
    **kwargs
        Passed on to :func:`~canopyblocks.workflows.blocks.blocks_from_file` (estimators,
        beams, channel, ...).

    Returns
    -------
    GeoDataFrame
        The block table written.
    """
    import geopandas as gpd

    from ..outputs.tables import check_output_path, write_table
    from ..readers.remote import source_name
    from .blocks import blocks_from_file

    check_output_path(output)
    paths = _distinct(paths)
    start = end = None
    if time_range is not None:
        if isinstance(time_range, (str, bytes)) or not isinstance(time_range, (tuple, list)) \
                or len(time_range) != 2:
            raise InputError(f"time_range must be (start, end), two UTC dates such as "
                             f"('2022-04-01', '2022-04-30'); got {time_range!r}")
        start = parse_utc(time_range[0], "--time START")
        end = parse_utc(time_range[1], "--time END", end=True)
        if end < start:
            raise InputError(f"--time {time_range[0]} {time_range[1]}: the end comes "
                             "before the start")
    # the whole track is blocked and then filtered: a subset read would move the block
    # origin (the track's first photon) and so every block edge
    area = read_polygon(polygon) if polygon is not None else None
    prog = as_progress(progress)
    tables, skipped = [], []
    for i, p in enumerate(paths):
        part = prog.sub(i / len(paths), (i + 1) / len(paths))
        if start is not None and end is not None:
            t0, t1 = granule_time_span(p)
            if t1 < start or t0 > end:
                skipped.append(source_name(p))
                continue
        try:
            res = blocks_from_file(p, params, bbox=bbox, crs=crs, output=None,
                                   progress=part, **kwargs)
        except NoUsableDataError as exc:  # e.g. nothing inside the bbox: said, not fatal
            log.warning("%s: no blocks (%s)", source_name(p), exc)
            continue
        b = res.blocks
        crs = crs if crs is not None else b.crs
        if area is not None and len(b):
            b = b[b.geometry.within(area.to_crs(b.crs).iloc[0])]
        tables.append(b.assign(granule=source_name(p)))
    if skipped:
        log.warning("%d of %d granules taken outside the time range, skipped: %s",
                    len(skipped), len(paths), ", ".join(skipped))
    if not tables or not sum(len(t) for t in tables):
        raise NoUsableDataError("no block in the granules, area and time range given")
    table = gpd.GeoDataFrame(pd.concat(tables, ignore_index=True), geometry="geometry",
                             crs=tables[0].crs)
    write_table(table, output)
    prog.update(1.0, f"{len(table)} blocks from {len(tables)} granules")
    return table
