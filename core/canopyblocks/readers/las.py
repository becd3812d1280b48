"""Read airborne discrete-return lidar (LAS/LAZ) into columnar numpy arrays.

One or several tiles are read with laspy's chunk iterator (bounded memory), optionally
cropped to a bounding box while reading.  Coordinates stay in the files' CRS (which must
be the same for every tile); heights stay in the files' vertical datum.
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from ..errors import (
    CancelledError,
    CanopyBlocksWarning,
    CRSError,
    FileFormatError,
    InputError,
    NoUsableDataError,
)
from ..geo import as_crs, require_metre_units, require_metric_crs
from ..progress import Progress, as_progress
from .cloud_checks import HeightTally, warn_if_normalised
from .las_crs import _laspy, las_file_crs
from .las_header import (
    MAX_OFFSET,
    check_header_extent,
    check_las_file,
    check_nothing_beyond_count,
    points_unreadable,
)

__all__ = ["LasPoints", "read_las", "las_crs", "las_bounds", "as_area"]

log = logging.getLogger(__name__)

_CHUNK = 2_000_000


@dataclass(eq=False)
class LasPoints:
    """Airborne lidar points, one numpy array per dimension (equal lengths).

    Attributes
    ----------
    x, y : ndarray float64
        Metres in ``crs``.
    z : ndarray float64
        Heights, metres, in the files' vertical datum (``vertical_datum``).
    classification : ndarray uint8
        ASPRS class (2 = ground, 7/18 = noise).
    return_number, number_of_returns : ndarray uint8
    crs : pyproj.CRS
        Horizontal CRS of ``x``/``y`` (projected, metres).
    vertical_datum : str
        Name of the vertical datum when the file states one, else ``"unknown"``.
    sources : tuple of str
        The files read.
    row : ndarray int64 or None
        Each point's row in the input files taken in order (file 1's points, then file
        2's, ...), counted before any cropping or class filter; None = ``arange``.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    classification: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    crs: pyproj.CRS
    vertical_datum: str = "unknown"
    sources: tuple[str, ...] = ()
    row: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.x.size)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` in metres.

        Raises NoUsableDataError when the cloud is empty or its points cover no area
        (all at one place or on one line: nothing to place a track over or grid).
        """
        names = ", ".join(self.sources) or "the point cloud"
        if len(self) == 0:
            raise NoUsableDataError(f"{names}: the point cloud is empty")
        b = (float(self.x.min()), float(self.y.min()), float(self.x.max()),
             float(self.y.max()))
        if b[2] - b[0] < 0.01 or b[3] - b[1] < 0.01:
            raise NoUsableDataError(
                f"{names}: its {len(self)} points cover {b[2] - b[0]:.2f} x {b[3] - b[1]:.2f} m "
                "(all at one place or on one line): no surface to work on")
        return b

    def subset(self, mask: np.ndarray) -> LasPoints:
        """Points selected by a boolean mask or an index array."""
        return LasPoints(self.x[mask], self.y[mask], self.z[mask], self.classification[mask],
                         self.return_number[mask], self.number_of_returns[mask], self.crs,
                         self.vertical_datum, self.sources,
                         self.rows[mask])

    @property
    def rows(self) -> np.ndarray:
        """:attr:`row`, or ``arange(len(self))`` when it is None."""
        return np.arange(len(self), dtype=np.int64) if self.row is None else self.row

    @classmethod
    def from_arrays(cls, x: np.ndarray, y: np.ndarray, z: np.ndarray, *,
                    crs: pyproj.CRS | str | int, classification: np.ndarray | None = None,
                    vertical_datum: str = "unknown") -> LasPoints:
        """Build a cloud from arrays (metres in ``crs``); e.g. synthetic test clouds."""
        x_a = np.ascontiguousarray(x, dtype=np.float64)
        y_a = np.ascontiguousarray(y, dtype=np.float64)
        z_a = np.ascontiguousarray(z, dtype=np.float64)
        if not (x_a.shape == y_a.shape == z_a.shape) or x_a.ndim != 1:
            raise InputError(
                f"x, y, z must be 1-D arrays of equal length; got {x_a.shape}, {y_a.shape}, "
                f"{z_a.shape}")
        n = x_a.size
        cls_a = (np.ones(n, np.uint8) if classification is None
                 else np.asarray(classification, dtype=np.uint8))
        one = np.ones(n, np.uint8)
        return cls(x_a, y_a, z_a, cls_a, one, one.copy(),
                   require_metric_crs(as_crs(crs, "point cloud CRS"), "point cloud CRS"),
                   vertical_datum, ())


def las_crs(path: str | os.PathLike[str]) -> pyproj.CRS | None:
    """The horizontal CRS stated in a LAS/LAZ header (WKT or GeoTIFF keys), or None.

    The whole CRS (vertical part and units) is :func:`~canopyblocks.readers.las_crs.las_file_crs`.
    """
    return las_file_crs(path).horizontal


def las_bounds(paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]], *,
               verify: bool = True) -> tuple[float, float, float, float]:
    """Union of the extents ``(xmin, ymin, xmax, ymax)`` of LAS/LAZ files, metres.

    Used to place a track before reading a corridor.  With ``verify`` (the default) each
    header's extent is checked against the points (one streaming pass over their integer
    coordinates, :func:`~canopyblocks.readers.las_summary.las_summary`): a damaged header
    is refused as such (or, when its extent cannot be right at all, replaced by the
    points' with a warning) instead of placing the track by it -- a lying header used to
    surface as "the survey is smaller than the footprint" or "no points in the file".
    ``verify=False`` reads headers only and refuses extents that cannot be right.

    Raises
    ------
    FileFormatError
        Missing or damaged file; a header whose extent disagrees with its points.
    NoUsableDataError
        No file holds a point; terrain off the Earth.
    """
    laspy = _laspy()
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    if not paths:
        raise InputError("no LAS/LAZ file given")
    from .las_summary import las_summary

    refuse_urls(paths)
    lo = np.array([np.inf, np.inf])
    hi = -lo
    for path in (Path(p) for p in paths):
        if path.exists():
            check_las_file(path)
        try:
            with laspy.open(path) as reader:
                mins, maxs = reader.header.mins, reader.header.maxs
                count = int(reader.header.point_count)
                scale = float(max(reader.header.scales))
        except FileNotFoundError:
            raise FileFormatError(f"{path}: no such file") from None
        except Exception as exc:  # laspy raises several types for corrupt headers
            raise FileFormatError(f"{path}: not a readable LAS/LAZ file ({exc})") from None
        if count == 0:
            continue  # an empty tile has no extent (its header says 0, 0, 0, 0)
        ext = (float(mins[0]), float(mins[1]), float(maxs[0]), float(maxs[1]))
        plausible = all(np.isfinite(ext)) and max(map(abs, ext)) <= MAX_OFFSET and \
            ext[0] <= ext[2] and ext[1] <= ext[3]
        if verify or not plausible:
            summary = las_summary(path)
            if summary.n_points == 0:
                continue
            if not check_header_extent(path, ext, summary.bounds,
                                       tolerance=max(1.0, 2.0 * scale)):
                warnings.warn(f"{path}: the header's extent {ext} cannot be right; using "
                              f"the points' ({', '.join(f'{v:.2f}' for v in summary.bounds)})",
                              CanopyBlocksWarning, stacklevel=2)
                ext = summary.bounds
        lo = np.minimum(lo, np.asarray(ext[:2], dtype=float))
        hi = np.maximum(hi, np.asarray(ext[2:], dtype=float))
    if not np.all(np.isfinite(lo)):
        raise NoUsableDataError(
            f"no points in {', '.join(str(p) for p in paths)}; give tiles that hold points")
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def read_las(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    bbox: tuple[float, float, float, float] | None = None,
    crs: pyproj.CRS | str | int | None = None,
    exclude_classes: Sequence[int] = (),
    progress: Progress | None = None,
    polygon: Any = None,
) -> LasPoints:
    """Read points from one or several LAS/LAZ tiles.

    Parameters
    ----------
    paths : path or sequence of paths
        LAS/LAZ files, all in the same horizontal CRS.
    bbox : (xmin, ymin, xmax, ymax), optional
        Keep only points inside (inclusive), metres in the files' CRS; tiles whose
        header extent misses the box are skipped without decompressing.
    crs : CRS-like, optional
        The CRS to assume when a file states none.  When a file states a CRS that
        differs from ``crs``, :class:`~canopyblocks.errors.CRSError` is raised
        (reproject the tiles first, e.g. with PDAL).
    exclude_classes : sequence of int
        ASPRS classes to drop while reading (e.g. ``(7, 18)`` for noise).
    progress : Progress, optional
        Reports per tile/chunk; cancellable.
    polygon : shapely (Multi)Polygon, optional
        Keep only points inside (a corridor, footprints' discs), files' CRS; tiles whose
        header extent misses it are skipped without decompressing.  With ``bbox``, both
        apply.

    Returns
    -------
    LasPoints

    Raises
    ------
    FileFormatError
        Missing or unreadable file.
    CRSError
        No CRS in a file and none given; tiles in different CRSs; a non-metric CRS;
        positions or heights the file states in feet.
    NoUsableDataError
        No point left (empty files, or the box misses every tile); a tile whose terrain
        lies outside the heights found on Earth
        (:data:`~canopyblocks.readers.cloud_checks.PLAUSIBLE_HEIGHTS`).
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    if not isinstance(paths, (list, tuple)) or not all(
            isinstance(p, (str, os.PathLike)) for p in paths):
        from ..arguments import describe
        raise InputError(f"read_las needs LAS/LAZ paths (a str/Path or a list of them); got "
                         f"{describe(paths)}")
    refuse_urls(paths)
    laspy = _laspy()
    prog = as_progress(progress)
    files = [Path(p) for p in paths]
    if not files:
        raise InputError("no LAS/LAZ file given")
    if bbox is not None:
        box = tuple(float(v) for v in bbox)
        if len(box) != 4 or not (box[0] <= box[2] and box[1] <= box[3]):
            raise InputError(f"bbox must be (xmin, ymin, xmax, ymax) with min <= max; got {box}")
        bbox = (box[0], box[1], box[2], box[3])
    area = as_area(polygon)
    if area is not None:
        b0, b1, b2, b3 = (float(v) for v in area.bounds)
        pb = (b0, b1, b2, b3)
        bbox = pb if bbox is None else (max(bbox[0], pb[0]), max(bbox[1], pb[1]),
                                        min(bbox[2], pb[2]), min(bbox[3], pb[3]))
    given = None if crs is None else as_crs(crs, "point cloud CRS")
    excl = np.asarray(list(exclude_classes), dtype=np.int64)
    used_crs: pyproj.CRS | None = None
    vdatum = "unknown"
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("x", "y", "z", "c", "r", "n", "row")}
    offset = 0  # rows of the files before this one
    for i, path in enumerate(files):
        sub = prog.sub(i / len(files), (i + 1) / len(files))
        if not path.exists():
            raise FileFormatError(f"{path}: no such file")
        check_las_file(path)
        stated = las_file_crs(path)  # the one reading of a tile's CRS (vertical part, units)
        stated.require_metres()
        try:
            reader_cm = laspy.open(path)
        except FileNotFoundError:
            raise FileFormatError(f"{path}: no such file") from None
        except Exception as exc:
            raise FileFormatError(f"{path}: not a readable LAS/LAZ file ({exc})") from None
        with reader_cm as reader:
            header = reader.header
            file_crs_full = stated.crs
            file_crs = stated.horizontal
            if file_crs is None:
                if given is None:
                    raise CRSError(
                        f"{path}: the file states no CRS (no WKT or GeoTIFF keys); give the "
                        "CRS of its coordinates (--crs in rasters, --points-crs in simulate and "
                        "validate, crs='EPSG:...' in Python), or write it into the file "
                        "(e.g. pdal translate with writers.las.a_srs) for `run` and `batch`")
                file_crs = given
            elif given is not None and not file_crs.equals(given, ignore_axis_order=True):
                raise CRSError(
                    f"{path}: the file's CRS {file_crs.to_string()} differs from the CRS given, "
                    f"{given.to_string()}; reproject the tiles or drop the CRS argument")
            if file_crs_full is not None:
                require_metre_units(file_crs_full, f"tile {path}")
            if used_crs is None:
                used_crs = require_metric_crs(file_crs, f"{path} CRS")
                vdatum = stated.vertical_name
            elif not file_crs.equals(used_crs, ignore_axis_order=True):
                raise CRSError(
                    f"{path}: CRS {file_crs.to_string()} differs from the first tile's "
                    f"{used_crs.to_string()}; reproject the tiles to one CRS first")
            mins, maxs = header.mins, header.maxs
            hdr_ext = (float(mins[0]), float(mins[1]), float(maxs[0]), float(maxs[1]))
            plausible = (all(np.isfinite(hdr_ext)) and max(map(abs, hdr_ext)) <= MAX_OFFSET
                         and hdr_ext[0] <= hdr_ext[2] and hdr_ext[1] <= hdr_ext[3])
            if bbox is not None and plausible:  # a header that cannot be right skips nothing
                if (maxs[0] < bbox[0] or mins[0] > bbox[2] or maxs[1] < bbox[1]
                        or mins[1] > bbox[3]) or (area is not None and
                                                  not _meets(area, hdr_ext)):
                    log.debug("%s: outside the bbox, skipped", path)
                    offset += int(header.point_count)
                    continue
            total = max(int(header.point_count), 1)
            done = 0
            ext = [np.inf, np.inf, -np.inf, -np.inf]  # the points' own extent
            heights = HeightTally()
            try:
                for chunk in reader.chunk_iterator(_CHUNK):
                    e = _append_chunk(chunk, parts, bbox, excl, offset + done, heights,
                                      area)
                    ext = [min(ext[0], e[0]), min(ext[1], e[1]), max(ext[2], e[2]),
                           max(ext[3], e[3])]
                    done += len(chunk)
                    sub.update(done / total, f"{path.name}: {done:,} points")
            except CancelledError:
                raise
            except Exception as exc:
                raise points_unreadable(path, exc, int(header.point_count)) from None
            check_nothing_beyond_count(reader, path, done)
            heights.check(str(path))
            if done and not check_header_extent(
                    path, hdr_ext, (ext[0], ext[1], ext[2], ext[3]),
                    tolerance=max(1.0, 2.0 * float(max(header.scales)))):
                warnings.warn(f"{path}: the header's extent {hdr_ext} cannot be right; using "
                              f"the points' ({', '.join(f'{v:.2f}' for v in ext)})",
                              CanopyBlocksWarning, stacklevel=2)
            offset += int(header.point_count)
    if used_crs is None:  # pragma: no cover - files list non-empty implies a CRS
        raise CRSError("no CRS found")
    if not parts["x"] or sum(a.size for a in parts["x"]) == 0:
        where = "" if bbox is None else f" inside bbox {bbox}"
        raise NoUsableDataError(
            f"no points{where} in {', '.join(str(f) for f in files)}; check the files/bbox")
    pts = LasPoints(
        x=np.concatenate(parts["x"]), y=np.concatenate(parts["y"]), z=np.concatenate(parts["z"]),
        classification=np.concatenate(parts["c"]), return_number=np.concatenate(parts["r"]),
        number_of_returns=np.concatenate(parts["n"]), crs=used_crs, vertical_datum=vdatum,
        sources=tuple(str(f) for f in files), row=np.concatenate(parts["row"]))
    warn_if_normalised(pts.z, pts.classification, ", ".join(str(f) for f in files))
    prog.update(1.0, f"{len(pts):,} points read")
    log.info("read %d points from %d file(s)", len(pts), len(files))
    return pts


def refuse_urls(paths: Sequence[Any]) -> None:
    """Refuse a URL among LAS/LAZ tile paths (a path would mangle it into a missing file):
    these readers read local files (the COPC and EPT readers read URLs).

    Raises
    ------
    FileFormatError
        Naming the URL (without its query string) and what to do.
    """
    from .remote import is_url, source_label

    for p in paths:
        if is_url(p):
            raise FileFormatError(
                f"{source_label(p)}: a URL, and LAS/LAZ points are read here from local "
                "files only; download the tile and give the local copy")


def as_area(polygon: Any, what: str = "read_las: polygon") -> Any:
    """``polygon`` (shapely or WKT) checked and prepared for fast point tests; None for None.

    Raises
    ------
    InputError
        Not a non-empty polygon or multipolygon.
    """
    if polygon is None:
        return None
    import shapely

    try:
        geom = shapely.from_wkt(polygon) if isinstance(polygon, str) else polygon
    except shapely.errors.GEOSException as exc:
        raise InputError(f"{what} is not valid WKT ({exc})") from None
    if not isinstance(geom, shapely.Geometry) or geom.is_empty or \
            geom.geom_type not in ("Polygon", "MultiPolygon"):
        raise InputError(f"{what} must be a polygon or multipolygon (shapely or WKT) in the "
                         f"points' CRS; got {str(polygon)[:60]!r}")
    shapely.prepare(geom)
    return geom


def _meets(area: Any, box: tuple[float, float, float, float]) -> bool:
    import shapely

    return bool(shapely.intersects(area, shapely.box(*box)))


def _append_chunk(chunk: Any, parts: dict[str, list[np.ndarray]],
                  bbox: tuple[float, float, float, float] | None, excl: np.ndarray,
                  first_row: int, heights: HeightTally,
                  area: Any = None) -> tuple[float, float, float, float]:
    """Append the kept points of one laspy point record (untyped: ``Any``) to ``parts``;
    count its heights in ``heights``; return the extent of all its points (kept or not)."""
    x = np.asarray(chunk.x, dtype=np.float64)
    y = np.asarray(chunk.y, dtype=np.float64)
    z = np.asarray(chunk.z, dtype=np.float64)
    c = np.asarray(chunk.classification, dtype=np.uint8)
    r = np.asarray(chunk.return_number, dtype=np.uint8)
    n = np.asarray(chunk.number_of_returns, dtype=np.uint8)
    heights.add(z, c)
    keep = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    if bbox is not None:
        keep &= (x >= bbox[0]) & (x <= bbox[2]) & (y >= bbox[1]) & (y <= bbox[3])
    if excl.size:
        keep &= ~np.isin(c, excl)
    if area is not None and keep.any():
        import shapely

        keep[keep] = shapely.contains_xy(area, x[keep], y[keep])
    row = np.arange(first_row, first_row + x.size, dtype=np.int64)
    arrays: tuple[np.ndarray, ...] = (x, y, z, c, r, n, row)
    for key, arr in zip(("x", "y", "z", "c", "r", "n", "row"), arrays):
        parts[key].append(arr[keep])
    if x.size == 0:
        return (np.inf, np.inf, -np.inf, -np.inf)
    return (float(np.nanmin(x)), float(np.nanmin(y)), float(np.nanmax(x)), float(np.nanmax(y)))
