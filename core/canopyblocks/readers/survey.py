"""A survey as users give it: one list of point-cloud sources, and its points over an area.

A survey argument is any mix of

* LAS/LAZ files (a ``*.copc.laz`` too) and folders of them (``.las``/``.laz``, sorted);
* glob patterns (``tiles/*.laz``), expanded and sorted;
* a COPC file or an EPT dataset (``ept.json``, or the folder holding it) by path or by an
  ``https://``/``s3://`` URL;
* a virtual point cloud (``.vpc``: QGIS's catalog of tiles, a STAC ItemCollection in
  GeoJSON whose items' ``data`` asset names each tile, relative to the ``.vpc``), local
  or by URL.

:func:`survey_sources` turns it into the flat list of sources (paths and URL strings);
:func:`read_survey` reads the points of such a list inside a box and/or polygon, each
source by its own reader (LAS/LAZ tiles by :func:`~canopyblocks.readers.las.read_las`,
COPC and EPT by their node readers), in one CRS.
"""

from __future__ import annotations

import glob
import json
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..errors import CanopyBlocksWarning, CRSError, FileFormatError, InputError, NoUsableDataError
from ..progress import Progress, as_progress
from .las import refuse_urls
from .remote import is_url

__all__ = ["survey_sources", "source_kind", "source_crs", "survey_crs", "source_extent",
           "read_survey", "TILE_SUFFIXES"]

TILE_SUFFIXES = (".las", ".laz")

def source_kind(source: object) -> str:
    """``"copc"`` (``*.copc.laz``), ``"ept"`` (``ept.json``), ``"vpc"`` (``*.vpc``) or
    ``"las"`` for a path or URL."""
    text = str(source).split("?", 1)[0].rstrip("/").lower()
    if text.endswith(".copc.laz"):
        return "copc"
    if text.endswith("/ept.json") or text == "ept.json":
        return "ept"
    if text.endswith(".vpc"):
        return "vpc"
    return "las"


def source_crs(source: Any) -> Any:
    """The CRS records a source states (:class:`~canopyblocks.readers.las_crs.LasCRS`): a
    LAS/LAZ tile's header, a COPC file's (E)VLRs, an EPT dataset's ``srs``."""
    kind = source_kind(source)
    if kind == "copc":
        from .copc import ByteSource, _check_source, read_header

        with ByteSource(_check_source(source)) as src:
            return read_header(src).stated
    if kind == "ept":
        from .copc import _check_source
        from .ept import EptInfo

        return EptInfo(_check_source(source)).stated
    from .las_crs import las_file_crs

    return las_file_crs(source)


def survey_crs(sources: Sequence[Any]) -> Any:
    """The CRS records a survey states, whatever its sources' order: those of the first
    source stating a vertical datum (the sources stating one agree, or are refused by
    :func:`~canopyblocks.readers.tile_checks.check_vertical_datums`), else the first's."""
    first = None
    for source in sources:  # a loop over sources: one header each, until one states a datum
        stated = source_crs(source)
        if stated.vertical is not None:
            return stated
        first = stated if first is None else first
    return first


def source_extent(source: Any) -> tuple[tuple[float, float, float, float], Any]:
    """A source's extent ``(minx, miny, maxx, maxy)`` (its CRS) and horizontal CRS (None
    when it states none), from its header, COPC info or ``ept.json`` (no point read
    from a COPC or EPT source; a LAS/LAZ tile's header checked against its points)."""
    kind = source_kind(source)
    if kind in ("copc", "ept"):
        if kind == "copc":
            from .copc import copc_extent as extent
        else:
            from .ept import ept_extent as extent
        ext = extent(source)
        return ext.bounds, ext.crs
    from .las import las_bounds

    return las_bounds(source), source_crs(source).horizontal


def _vpc_items(source: str | Path) -> list[str | Path]:
    """The tiles a ``.vpc`` names (its features' ``data`` assets), in its order."""
    from .remote import open_source, source_label

    label = source_label(source) if is_url(source) else str(source)
    try:
        if is_url(source):
            with open_source(str(source)) as f:
                doc = json.loads(f.read())
        else:
            doc = json.loads(Path(source).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FileFormatError(f"{label}: no such file") from None
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"{label}: not a virtual point cloud (.vpc, GeoJSON) ({exc}); "
                              "write it again with QGIS or pdal wrench build_vpc") from None
    feats = doc.get("features") if isinstance(doc, dict) else None
    hrefs = []
    for f in feats if isinstance(feats, list) else []:
        assets = f.get("assets", {}) if isinstance(f, dict) else {}
        data = assets.get("data") or next(iter(assets.values()), None) \
            if isinstance(assets, dict) else None
        href = data.get("href") if isinstance(data, dict) else None
        if isinstance(href, str) and href.strip():
            hrefs.append(href.strip())
    if not hrefs:
        raise FileFormatError(f"{label}: a virtual point cloud that names no tile (no feature "
                              "with a data asset href); write it again with QGIS or pdal "
                              "wrench build_vpc")
    out: list[str | Path] = []
    for h in hrefs:
        if is_url(h):
            out.append(h)
        elif is_url(source):
            out.append(str(source).split("?", 1)[0].rsplit("/", 1)[0] + "/" +
                       h.removeprefix("./"))
        else:
            p = Path(h)
            p = p if p.is_absolute() else (Path(source).parent / p)
            if not p.exists():
                raise FileFormatError(
                    f"{label} names the tile {h}, but {p} does not exist; put the tile there "
                    "or write the .vpc again (QGIS or pdal wrench build_vpc) from the tiles")
            out.append(p)
    return out


def _folder(p: Path) -> list[str | Path]:
    found: list[str | Path] = sorted(q for q in p.iterdir()
                                     if q.is_file() and q.suffix.lower() in TILE_SUFFIXES)
    if found:
        return found
    if (p / "ept.json").is_file():
        return [str(p / "ept.json")]
    raise InputError(f"the folder {p} holds no .las or .laz file (nor an ept.json); give a "
                     "folder of LAS/LAZ tiles, the tiles, a .vpc, a COPC or an ept.json")


def survey_sources(sources: Any) -> list[Any]:
    """The flat list of point-cloud sources of a survey argument (see the module notes).

    Local files come back as :class:`~pathlib.Path`, URLs and EPT datasets as strings;
    a URL or dataset given twice is kept once, with a warning (local files given twice, or
    their copies, are left to :func:`~canopyblocks.readers.tile_checks.duplicate_tiles`).

    Raises
    ------
    InputError
        No source at all; a folder or a glob pattern that matches no tile.
    FileFormatError
        A ``.vpc`` that cannot be read or names no tile.
    """
    items = [sources] if isinstance(sources, (str, os.PathLike)) else list(sources or [])
    out: list[Any] = []
    for item in items:
        text = str(item).strip()
        kind = source_kind(text)
        if is_url(text):
            out.extend(_vpc_items(text) if kind == "vpc" else [text])
            continue
        p = Path(text)
        if kind == "vpc":
            out.extend(_vpc_items(p))
        elif p.is_dir():
            out.extend(_folder(p))
        elif kind == "ept":
            out.append(str(p))
        elif not p.exists() and glob.has_magic(text):
            found = sorted(glob.glob(text))
            if not found:
                raise InputError(f"the pattern {text} matches no file; give the tiles, their "
                                 "folder or a pattern that matches them")
            out.extend(survey_sources(found))
        elif p.exists():
            out.append(p)
        else:
            raise FileFormatError(f"{p}: no such file or folder")
    # a plain LAS/LAZ tile is read from a local file (COPC and EPT by URL): named, not mangled
    refuse_urls([s for s in out if is_url(s) and source_kind(s) == "las"])
    if not out:
        raise InputError("no point-cloud source given; give LAS/LAZ tiles, a folder, a .vpc, "
                         "a COPC or an ept.json")
    # a URL or dataset given twice is read once, with a warning; local files (the same
    # file, a copy, a link, a crop) are told apart by readers.tile_checks.duplicate_tiles
    seen: set[str] = set()
    unique = []
    for s in out:
        if isinstance(s, str) and s in seen:
            warnings.warn(f"the survey source {s} is given twice: read once",
                          CanopyBlocksWarning, stacklevel=2)
            continue
        seen.add(str(s))
        unique.append(s)
    return unique


def read_survey(sources: Sequence[Any], *, bbox: Sequence[float] | None = None,
                polygon: Any = None, crs: object = None, exclude_classes: Sequence[int] = (),
                progress: Progress | None = None, to_crs: object = None) -> Any:
    """The points of a survey's sources inside ``bbox`` and/or ``polygon`` (their CRS, or
    ``to_crs``).

    With ``to_crs`` (a metric CRS) the area is in ``to_crs``: it is carried into the
    sources' CRS (widened by a metre to cover the curvature of its edges) to read them,
    the points are reprojected to ``to_crs`` and kept exactly inside the area there.

    LAS/LAZ tiles are read by :func:`~canopyblocks.readers.las.read_las` (``crs`` the CRS
    of tiles that state none), COPC files and EPT datasets by their node readers (only
    the nodes that meet the area).  Every source must be in the same CRS.

    Returns
    -------
    LasPoints
        ``row`` None when a COPC/EPT source is among them.

    Raises
    ------
    NoUsableDataError
        No source holds a point inside the area.
    CRSError
        Sources in different CRSs; see the readers for the rest.
    """
    if to_crs is not None:
        return _read_reprojected(sources, bbox, polygon, crs, exclude_classes, progress,
                                 to_crs)
    import numpy as np

    from ..geo import as_crs
    from .las import LasPoints, read_las

    prog = as_progress(progress)
    tiles = [s for s in sources if source_kind(s) == "las"]
    clouds = [s for s in sources if source_kind(s) in ("copc", "ept")]
    parts = []
    n = len(clouds) + (1 if tiles else 0)
    if tiles:
        try:
            box = None if bbox is None else (float(bbox[0]), float(bbox[1]), float(bbox[2]),
                                             float(bbox[3]))
            parts.append(read_las(tiles, bbox=box, crs=None if crs is None else as_crs(crs),
                                  exclude_classes=exclude_classes, polygon=polygon,
                                  progress=prog.sub(0.0, 1.0 / n)))
        except NoUsableDataError:
            if not clouds:
                raise
    for i, src in enumerate(clouds, start=1 if tiles else 0):
        part = _read_cloud(src, bbox, polygon, crs, prog.sub(i / n, (i + 1) / n))
        if part is not None:
            if exclude_classes:
                part = part.subset(~np.isin(part.classification, np.asarray(exclude_classes)))
            parts.append(part)
    if not parts:
        raise NoUsableDataError(f"no point of {', '.join(map(str, sources))} lies in the area "
                                "read; check the sources' position and CRS")
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    for p in parts[1:]:
        if not p.crs.equals(first.crs, ignore_axis_order=True):
            raise CRSError(f"{p.sources[0]} is in {p.crs.to_string()}, {first.sources[0]} in "
                           f"{first.crs.to_string()}; give the sources of one CRS")
    cat = {k: np.concatenate([getattr(p, k) for p in parts]) for k in
           ("x", "y", "z", "classification", "return_number", "number_of_returns")}
    return LasPoints(cat["x"], cat["y"], cat["z"], cat["classification"], cat["return_number"],
                     cat["number_of_returns"], first.crs, first.vertical_datum,
                     tuple(s for p in parts for s in p.sources), None)


def _read_cloud(src: Any, bbox: Sequence[float] | None, polygon: Any, crs: object,
                prog: Progress) -> Any:
    """One COPC/EPT source's points inside the area (None when it holds none there)."""
    if source_kind(src) == "copc":
        from .copc import read_copc as read
    else:
        from .ept import read_ept as read
    try:
        return read(src, bounds=bbox, polygon=polygon, progress=prog, crs=crs)
    except NoUsableDataError:
        return None


def _read_reprojected(sources: Sequence[Any], bbox: Sequence[float] | None, polygon: Any,
                      crs: object, exclude_classes: Sequence[int], progress: Progress | None,
                      to_crs: object) -> Any:
    """:func:`read_survey` with the area in ``to_crs`` and the points reprojected to it."""
    import dataclasses

    import numpy as np
    import pyproj
    import shapely

    from ..geo import as_crs, require_metric_crs
    from .las import as_area

    dst = require_metric_crs(as_crs(to_crs, "working CRS"), "working CRS")
    src = source_crs(sources[0]).horizontal or (None if crs is None else as_crs(crs))
    if src is None or src.equals(dst, ignore_axis_order=True):
        return read_survey(sources, bbox=bbox, polygon=polygon, crs=crs,
                           exclude_classes=exclude_classes, progress=progress)
    area = as_area(polygon)
    if bbox is not None:
        box = shapely.box(*(float(v) for v in bbox))
        area = box if area is None else area.intersection(box)
    there = None
    if area is not None:
        fwd = pyproj.Transformer.from_crs(dst, src, always_xy=True)
        there = shapely.transform(shapely.segmentize(area, 5.0),
                                  lambda xy: np.column_stack(fwd.transform(xy[:, 0], xy[:, 1])))
        there = there.buffer(1.0 * _scale(src, there))
    pts = read_survey(sources, polygon=there, crs=crs, exclude_classes=exclude_classes,
                      progress=progress)
    back = pyproj.Transformer.from_crs(pts.crs, dst, always_xy=True)
    x, y = back.transform(pts.x, pts.y)
    moved = dataclasses.replace(pts, x=np.asarray(x, float), y=np.asarray(y, float), crs=dst)
    if area is None:
        return moved
    keep = shapely.covers(area, shapely.points(moved.x, moved.y))
    if not keep.any():
        raise NoUsableDataError(f"no point of {', '.join(map(str, sources))} lies in the area "
                                "read; check the sources' position and CRS")
    return moved.subset(keep)


def _scale(crs: Any, area: Any) -> float:
    """Source-CRS units per ground metre near ``area`` (1/cos(lat) for Mercator)."""
    import math

    import pyproj

    c = area.centroid
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(c.x, c.y)
    return 1.0 / max(math.cos(math.radians(lat)), 0.01)
