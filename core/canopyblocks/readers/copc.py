"""Cloud-optimised point clouds (COPC 1.0): read only the octree nodes an area needs.

A COPC file is a LAZ 1.4 file whose points are grouped by the cubes of an octree, one LAZ
chunk per node; the first VLR (``copc`` record 1) gives the root cube and where the
hierarchy (``copc`` EVLR 1000: for each node its key ``level-x-y-z``, byte offset, byte size
and point count; count -1 = a further page of entries) lies.  :func:`read_copc` reads the
header and the hierarchy pages whose cubes meet the area, then fetches only the chunks of the
nodes that meet it (neighbours coalesced), decompresses them with lazrs batch by batch
(memory: the batch plus the points kept) and keeps exactly the points inside the area: the
same points, bit for bit, as reading the survey's LAZ tiles and cropping them.

The source is a local path, an ``https://`` URL or an ``s3://`` URL; URLs go through
:mod:`~canopyblocks.readers.remote` (byte ranges, the same credentials, endpoint, retries,
time-outs and one-line :class:`~canopyblocks.readers.remote.StorageError` as granules).
Coordinates stay in the file's CRS (read as :func:`~canopyblocks.readers.las_crs.las_file_crs`
reads a LAZ tile), heights in its vertical datum.
"""

from __future__ import annotations

import io
import math
import os
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from ..errors import CRSError, FileFormatError, InputError, NoUsableDataError
from ..geo import require_metre_units, require_metric_crs
from ..progress import Progress, as_progress
from .cloud_checks import HeightTally, warn_if_normalised
from .copc_checks import (
    check_chunks,
    check_cube,
    check_node_points,
    check_page,
    check_total,
    check_whole_hierarchy,
    chunk_starts,
    page_entries,
)
from .las_crs import LasCRS, _laspy, crs_from_records
from .remote import is_url, open_source, source_label

__all__ = ["SourceExtent", "Area", "copc_extent", "read_copc", "BATCH_POINTS"]

#: Points decompressed at once (nodes are taken in batches up to this many points).
BATCH_POINTS = 2_000_000
_HEADER = 375
_INFO = struct.Struct("<5d2Q2d")


@dataclass(frozen=True)
class SourceExtent:
    """What a cloud-optimised source covers, from its header (no point read).

    Attributes
    ----------
    bounds : (minx, miny, maxx, maxy)
        Metres in ``crs``: the extent of the points the header states.
    crs : pyproj.CRS or None
        The horizontal CRS of x/y; None when the source states none.
    n_points : int
    source : str
        The source as messages name it (a URL without its query string).
    """

    bounds: tuple[float, float, float, float]
    crs: pyproj.CRS | None
    n_points: int
    source: str


# ---------------------------------------------------------------------------- the area
class Area:
    """The area to read: a box and/or a polygon (metres in the source's CRS).

    Points on the edge count as inside (``x >= minx``, ..., and shapely's ``covers``),
    as :func:`~canopyblocks.readers.las.read_las` crops by its ``bbox``.
    """

    def __init__(self, bounds: Sequence[float] | None, polygon: Any) -> None:
        self.box = _check_bounds(bounds)
        self.polygon = _check_polygon(polygon)
        if self.polygon is not None:
            pb = tuple(float(v) for v in self.polygon.bounds)
            b = self.box or pb
            self.box = (max(b[0], pb[0]), max(b[1], pb[1]), min(b[2], pb[2]), min(b[3], pb[3]))

    @property
    def everything(self) -> bool:
        return self.box is None and self.polygon is None

    def meets(self, lo: tuple[float, float], hi: tuple[float, float]) -> bool:
        """Whether the rectangle ``lo``-``hi`` (a node's cube seen from above) meets it."""
        b = self.box
        if b is None:
            return True
        if hi[0] < b[0] or lo[0] > b[2] or hi[1] < b[1] or lo[1] > b[3]:
            return False
        if self.polygon is None:
            return True
        import shapely

        return bool(self.polygon.intersects(shapely.box(lo[0], lo[1], hi[0], hi[1])))

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Boolean mask of the points inside (edges included)."""
        keep = np.isfinite(x) & np.isfinite(y)
        b = self.box
        if b is not None:
            keep &= (x >= b[0]) & (x <= b[2]) & (y >= b[1]) & (y <= b[3])
        if self.polygon is not None and keep.any():
            import shapely

            idx = np.flatnonzero(keep)
            keep[idx] = shapely.intersects_xy(self.polygon, x[idx], y[idx])
        return keep


def _check_bounds(bounds: Sequence[float] | None) -> tuple[float, float, float, float] | None:
    if bounds is None:
        return None
    try:
        box = tuple(float(v) for v in bounds)
    except (TypeError, ValueError):
        box = ()
    if len(box) != 4 or not all(math.isfinite(v) for v in box) or not (
            box[0] <= box[2] and box[1] <= box[3]):
        raise InputError(f"bounds must be (minx, miny, maxx, maxy) in metres with min <= max; "
                         f"got {bounds!r}")
    return (box[0], box[1], box[2], box[3])


def _check_polygon(polygon: Any) -> Any:
    if polygon is None:
        return None
    import shapely

    geom = polygon
    if isinstance(polygon, str):
        try:
            geom = shapely.from_wkt(polygon)
        except Exception:  # noqa: BLE001 - shapely raises its own GEOS errors
            raise InputError(f"polygon: not a WKT polygon ({polygon[:40]!r})") from None
    if not isinstance(geom, (shapely.Polygon, shapely.MultiPolygon)) or geom.is_empty:
        raise InputError(f"polygon must be a shapely Polygon/MultiPolygon or its WKT; got "
                         f"{type(polygon).__name__}")
    shapely.prepare(geom)
    return geom


# ---------------------------------------------------------------------------- bytes
class ByteSource:
    """Byte ranges of a local file or of an object in storage (``fetch``), counted."""

    def __init__(self, source: str | os.PathLike[str]) -> None:
        self.label = source_label(source)
        self.remote: Any = None
        self._fh: Any = None
        if is_url(source):
            self.remote = open_source(str(source))
            self.size = int(self.remote.size)
        else:
            path = Path(source)
            try:
                self._fh = path.open("rb")
            except FileNotFoundError:
                raise FileFormatError(f"{path}: no such file") from None
            except OSError as exc:
                raise FileFormatError(f"cannot read {path}: {exc.strerror or exc}") from None
            self.size = os.fstat(self._fh.fileno()).st_size
        self.nbytes = 0

    def fetch(self, ranges: Sequence[tuple[int, int]], what: str = "data") -> list[bytes]:
        """The bytes of each ``(start, end)``; a range beyond the end is a truncated file."""
        for a, b in ranges:
            if a < 0 or b > self.size or b < a:
                raise FileFormatError(
                    f"{self.label}: truncated or damaged ({what} at bytes {a}-{b}, the file "
                    f"has {self.size}); download or write it again")
        if self.remote is not None:
            out = list(self.remote.fetch(list(ranges), max_gap=node_gap(ranges)))
        else:
            out = [os.pread(self._fh.fileno(), b - a, a) for a, b in ranges]
        self.nbytes += sum(len(o) for o in out)
        return out

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()

    def __enter__(self) -> ByteSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------------- the header
@dataclass(frozen=True)
class CopcHeader:
    """What a COPC file's header, VLRs and info record say."""

    label: str
    n_points: int
    point_format: int
    record_length: int
    scales: tuple[float, float, float]
    offsets: tuple[float, float, float]
    bounds: tuple[float, float, float, float]
    laszip: bytes
    center: tuple[float, float, float]
    halfsize: float
    root: tuple[int, int]   # (offset, size) of the root hierarchy page
    stated: LasCRS
    points_at: int = 0      # offset to the point data (the chunk table's pointer)


def node_gap(ranges: Sequence[tuple[int, int]]) -> int:
    """The largest gap (bytes) between two nodes' chunks fetched in one request: half the
    median chunk, at most the storage reader's ``MAX_GAP`` (64 KiB).  Small nodes far
    apart are fetched one by one, not with the file between them: the bytes fetched follow
    the nodes needed (at most about twice them), while neighbouring large nodes still go
    in one request."""
    from .remote import MAX_GAP

    if not ranges:
        return 0
    sizes = np.asarray([b - a for a, b in ranges], dtype=np.int64)
    return int(min(MAX_GAP, int(np.median(sizes)) // 2))


def read_header(src: ByteSource) -> CopcHeader:
    """Parse and check a COPC header (one read of the header and VLRs)."""
    label = src.label
    head = src.fetch([(0, min(src.size, _HEADER))], "the header")[0]
    if len(head) < _HEADER or head[:4] != b"LASF":
        raise FileFormatError(f"{label}: not a COPC file (no LAS 1.4 header; {src.size} bytes)")
    version = (head[24], head[25])
    offset_to_points, n_vlrs = struct.unpack_from("<II", head, 96)
    fmt, rec_len = head[104] & 0x3F, struct.unpack_from("<H", head, 105)[0]
    if version != (1, 4):
        raise FileFormatError(f"{label}: not a COPC file (LAS {version[0]}.{version[1]}, "
                              "COPC is LAS 1.4); read it as a LAS/LAZ tile")
    if offset_to_points < _HEADER + 54:
        raise FileFormatError(f"{label}: not a COPC file (no VLR before the points); read it "
                              "as a LAS/LAZ tile")
    vlr_bytes = src.fetch([(0, offset_to_points)], "the VLRs")[0]
    user, record = struct.unpack_from("<16sH", vlr_bytes, _HEADER + 2)
    if user.rstrip(b"\0") != b"copc" or record != 1:
        raise FileFormatError(f"{label}: not a COPC file (its first VLR is not the COPC "
                              "info record); read it as a LAS/LAZ tile")
    try:
        laspy = _laspy()
        hdr = laspy.LasHeader.read_from(io.BytesIO(vlr_bytes))
    except Exception as exc:  # noqa: BLE001 - laspy raises several types for bad headers
        raise FileFormatError(f"{label}: not a readable COPC header ({exc})") from None
    info = _INFO.unpack_from(vlr_bytes, _HEADER + 54)
    laszip = next((data for user, record, data in _raw_vlrs(vlr_bytes, n_vlrs)
                   if user == b"laszip encoded" and record == 22204), None)
    if laszip is None or fmt not in (6, 7, 8):
        raise FileFormatError(f"{label}: not a COPC file (point format {fmt} "
                              f"{'without' if laszip is None else 'with'} LAZ compression; "
                              "COPC is LAZ with point format 6, 7 or 8)")
    wkt_bit = bool(getattr(hdr.global_encoding, "wkt", False))
    stated = crs_from_records(Path(label), list(hdr.vlrs or []), version, wkt_bit)
    if stated.horizontal is None:  # LAS 1.4 allows the CRS after the points
        stated = crs_from_records(Path(label), list(hdr.vlrs or []) + _crs_evlrs(src, head),
                                  version, wkt_bit)
    mins, maxs = hdr.mins, hdr.maxs
    h = CopcHeader(
        label=label, n_points=int(hdr.point_count), point_format=fmt, record_length=rec_len,
        scales=tuple(float(v) for v in hdr.scales),  # type: ignore[arg-type]
        offsets=tuple(float(v) for v in hdr.offsets),  # type: ignore[arg-type]
        bounds=(float(mins[0]), float(mins[1]), float(maxs[0]), float(maxs[1])),
        laszip=laszip, center=(info[0], info[1], info[2]), halfsize=float(info[3]),
        root=(int(info[5]), int(info[6])), stated=stated, points_at=int(offset_to_points))
    check_cube(h)
    return h


@dataclass(frozen=True)
class _Record:
    """A CRS record read from an extended VLR (what the LAS CRS reader looks at)."""

    record_id: int
    record_data: bytes


_EVLR_HEAD = struct.Struct("<H16sHQ32s")   # reserved, user, record, length, description


def _crs_evlrs(src: ByteSource, head: bytes) -> list[_Record]:
    """The WKT CRS records among the extended VLRs after the points (LAS 1.4 allows the
    CRS there; copc-lib writes it there): each EVLR's 60-byte head is read, only a CRS
    record's data."""
    start, count = struct.unpack_from("<QI", head, 235)
    out: list[_Record] = []
    pos = int(start)
    for _ in range(min(int(count), 64)):  # a handful of records
        if not 0 < pos <= src.size - _EVLR_HEAD.size:
            break
        _, user, record, length, _ = _EVLR_HEAD.unpack(
            src.fetch([(pos, pos + _EVLR_HEAD.size)], "the extended VLRs")[0])
        data = pos + _EVLR_HEAD.size
        if user.rstrip(b"\0") == b"LASF_Projection" and record == 2112 and \
                0 < length <= src.size - data:
            out.append(_Record(2112, src.fetch([(data, data + int(length))], "the CRS")[0]))
        pos = data + int(length)
    return out


def _raw_vlrs(blob: bytes, n: int) -> list[tuple[bytes, int, bytes]]:
    """``(user id, record id, data)`` of the VLRs in ``blob`` (header and VLRs)."""
    out, pos = [], _HEADER
    for _ in range(n):  # a handful of records
        if pos + 54 > len(blob):
            break
        user, record, length = struct.unpack_from("<16sHH", blob, pos + 2)
        out.append((user.rstrip(b"\0"), record, blob[pos + 54:pos + 54 + length]))
        pos += 54 + length
    return out


def copc_extent(source: str | os.PathLike[str]) -> SourceExtent:
    """The extent, CRS and point count a COPC file states (its header only).

    Parameters
    ----------
    source : path or ``https://``/``s3://`` URL

    Raises
    ------
    FileFormatError
        Missing, truncated, not COPC; storage failures (one line naming the URL).
    """
    with ByteSource(_check_source(source)) as src:
        h = read_header(src)
    return SourceExtent(h.bounds, h.stated.horizontal, h.n_points, h.label)


def _check_source(source: object) -> str:
    if isinstance(source, (str, os.PathLike)) and str(source).strip():
        return str(source).strip() if is_url(source) else os.fspath(source)
    raise InputError(f"a COPC/EPT source must be a path or an https:// or s3:// URL; got "
                     f"{type(source).__name__}")


# ---------------------------------------------------------------------------- the octree
Node = tuple[int, int, int, int]


def select_nodes(src: ByteSource, h: CopcHeader, area: Area) -> list[tuple[Node, int, int, int]]:
    """``(key, offset, byte size, point count)`` of the nodes whose cubes meet ``area``
    (hierarchy pages fetched only for cubes that meet it), in file order, checked against
    the LAZ chunks they point to (:mod:`~canopyblocks.readers.copc_checks`)."""
    entries: dict[Node, tuple[int, int, int]] = {}
    _add_page(src, h, entries, h.root)
    pad = 2.0 * max(h.scales)  # a point rounded onto its cube's face
    out: list[tuple[Node, int, int, int]] = []
    todo: list[Node] = [(0, 0, 0, 0)]
    while todo:  # one step per node of the octree, not per point
        key = todo.pop()
        got = entries.get(key)
        if got is None:
            continue
        side = 2.0 * h.halfsize / (1 << key[0])
        lo = (h.center[0] - h.halfsize + key[1] * side - pad,
              h.center[1] - h.halfsize + key[2] * side - pad)
        if not area.meets(lo, (lo[0] + side + 2 * pad, lo[1] + side + 2 * pad)):
            continue
        offset, size, count = got
        if count == -1:
            del entries[key]
            _add_page(src, h, entries, (offset, size))
            todo.append(key)
            continue
        if count > 0 or size > 0:  # a count of 0 with bytes is checked against its chunk
            out.append((key, offset, size, count))
        d, x, y, z = key
        todo.extend((d + 1, 2 * x + (i & 1), 2 * y + ((i >> 1) & 1), 2 * z + ((i >> 2) & 1))
                    for i in range(8))
    if out:  # each node read checked against the LAZ chunk it points to
        check_chunks(h, out, chunk_starts(src, h))
    if area.everything:
        check_total(h, entries)
    else:  # a node left out of the hierarchy or zeroed would be missed silently
        check_whole_hierarchy(src, h, entries)
    return sorted(out, key=lambda n: n[1])


def _add_page(src: ByteSource, h: CopcHeader, entries: dict[Node, tuple[int, int, int]],
              where: tuple[int, int]) -> None:
    offset, size = where
    check_page(h, where)
    entries.update(page_entries(src.fetch([(offset, offset + size)], "a hierarchy page")[0]))


def _batches(nodes: list[tuple[Node, int, int, int]]) -> list[list[tuple[Node, int, int, int]]]:
    out: list[list[tuple[Node, int, int, int]]] = []
    total = BATCH_POINTS
    for n in nodes:
        if total + n[3] > BATCH_POINTS and (not out or out[-1]):
            out.append([])
            total = 0
        out[-1].append(n)
        total += n[3]
    return out


def _dtype(record_length: int) -> np.dtype:
    """The fields read of a point format 6-8 record."""
    return np.dtype({"names": ["X", "Y", "Z", "returns", "classification"],
                     "formats": ["<i4", "<i4", "<i4", "u1", "u1"],
                     "offsets": [0, 4, 8, 14, 16], "itemsize": record_length})


def _decompress(h: CopcHeader, blobs: list[bytes],
                batch: list[tuple[Node, int, int, int]]) -> np.ndarray:
    import lazrs

    n = sum(b[3] for b in batch)
    out = np.zeros(n * h.record_length, np.uint8)
    sel = lazrs.DecompressionSelection(
        lazrs.SELECTIVE_DECOMPRESS_XY_RETURNS_CHANNEL | lazrs.SELECTIVE_DECOMPRESS_Z
        | lazrs.SELECTIVE_DECOMPRESS_CLASSIFICATION)
    try:
        lazrs.decompress_points_with_chunk_table(
            b"".join(blobs), h.laszip, out, [(b[3], b[2]) for b in batch], sel)
    except Exception:  # noqa: BLE001 - lazrs raises its own error types (not shown)
        raise _damaged_nodes(h, blobs, batch, sel) from None
    return out.view(_dtype(h.record_length))


def _damaged_nodes(h: CopcHeader, blobs: list[bytes], batch: list[tuple[Node, int, int, int]],
                   sel: Any) -> FileFormatError:
    """The refusal of a batch that failed to decompress, naming the nodes that fail on
    their own (each decompressed alone: on the failure path only)."""
    import lazrs

    bad = []
    for blob, node in zip(blobs, batch):
        try:
            lazrs.decompress_points_with_chunk_table(
                blob, h.laszip, np.zeros(node[3] * h.record_length, np.uint8),
                [(node[3], node[2])], sel)
        except Exception:  # noqa: BLE001 - this node's chunk is the damaged one
            bad.append("-".join(map(str, node[0])))
    key = "-".join
    if not bad:  # only together (never seen): name the batch
        which = (f"one of the octree nodes {key(map(str, batch[0][0]))} .. "
                 f"{key(map(str, batch[-1][0]))}")
    else:
        more = " ..." if len(bad) > 5 else ""
        which = f"octree node{'s' * (len(bad) > 1)} {', '.join(bad[:5])}{more}"
    return FileFormatError(
        f"{h.label}: the point data of {which} cannot be decompressed: the file is "
        "damaged; copy or download it again, or write it again")


def read_copc(source: str | os.PathLike[str], *, bounds: Sequence[float] | None = None,
              polygon: Any = None, progress: Progress | None = None,
              crs: object = None) -> Any:
    """Read the points of a COPC file inside ``bounds`` and/or ``polygon``.

    Parameters
    ----------
    source : path or ``https://``/``s3://`` URL
    bounds : (minx, miny, maxx, maxy), optional
        Metres in the file's CRS; edges included.
    polygon : shapely Polygon/MultiPolygon or WKT, optional
        Metres in the file's CRS; points on its edge included.
    progress : Progress, optional
        Reports per batch of nodes; cancellable.
    crs : CRS-like, optional
        The CRS of a file that states none (a file that states another is refused).

    Returns
    -------
    LasPoints
        Exactly the points inside (the same as reading the LAZ tiles and cropping), in the
        file's order; x/y in its CRS, z in its vertical datum; ``row`` None.

    Raises
    ------
    FileFormatError
        Missing, truncated or damaged file, not COPC; storage failures (one line).
    CRSError
        No CRS stated; a non-metric CRS or heights in feet.
    NoUsableDataError
        No point inside the area.
    """
    area = Area(bounds, polygon)
    prog = as_progress(progress)
    with ByteSource(_check_source(source)) as src:
        h = read_header(src)
        crs = check_crs(h.stated, h.label, crs)
        nodes = select_nodes(src, h, area)
        cols = Columns(h.label)
        total = max(1, sum(n[3] for n in nodes))
        done = 0
        for batch in _batches(nodes):
            prog.check()
            blobs = src.fetch([(n[1], n[1] + n[2]) for n in batch], "point data")
            rec = _decompress(h, blobs, batch)
            check_node_points(h, rec, batch)
            cols.add(rec, h.scales, h.offsets, area)
            del blobs
            done += sum(n[3] for n in batch)
            prog.update(done / total, f"{h.label}: {done:,} points")
    return cols.points(crs, h.stated.vertical_name, area)


def check_crs(stated: LasCRS, label: str, given: object = None) -> pyproj.CRS:
    """The horizontal CRS, refused as a LAZ tile's is (none, not metric, feet); ``given``
    is the CRS of a source that states none (one that states another is refused)."""
    from ..geo import as_crs

    stated.require_metres()
    want = None if given is None else as_crs(given, "point cloud CRS")
    if stated.horizontal is None:
        if want is None:
            raise CRSError(f"{label}: the source states no CRS; give its CRS (--crs, "
                           "crs='EPSG:...' in Python) or write it into the source (its WKT "
                           "record or ept.json srs)")
        return require_metric_crs(want, f"{label} CRS")
    if want is not None and not want.equals(stated.horizontal, ignore_axis_order=True) \
            and not (want.is_compound and any(
                c.equals(stated.horizontal, ignore_axis_order=True) for c in want.sub_crs_list)):
        raise CRSError(f"{label}: the source's CRS {stated.horizontal.to_string()} differs "
                       f"from the CRS given, {want.to_string()}; drop the CRS argument")
    if stated.crs is not None:
        require_metre_units(stated.crs, label)
    return require_metric_crs(stated.horizontal, f"{label} CRS")


class Columns:
    """Kept points, batch by batch (the points a reader returns)."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.parts: dict[str, list[np.ndarray]] = {k: [] for k in "xyzcrn"}
        self.heights = HeightTally()

    def add(self, rec: np.ndarray, scales: Sequence[float], offsets: Sequence[float],
            area: Area) -> None:
        """Scale one batch's integers as laspy does (``X * scale + offset``), keep those inside."""
        x = rec["X"] * scales[0] + offsets[0]
        y = rec["Y"] * scales[1] + offsets[1]
        z = rec["Z"] * scales[2] + offsets[2]
        c = np.ascontiguousarray(rec["classification"])
        ret = rec["returns"]
        self.add_arrays(x, y, z, c, (ret & 0x0F).astype(np.uint8),
                        (ret >> 4).astype(np.uint8), area)

    def add_arrays(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, c: np.ndarray,
                   r: np.ndarray, n: np.ndarray, area: Area) -> None:
        self.heights.add(z, c)
        keep = area.inside(x, y) & np.isfinite(z)
        for k, a in zip("xyzcrn", (x, y, z, c, r, n)):
            self.parts[k].append(np.ascontiguousarray(a[keep]))

    def points(self, crs: pyproj.CRS, vertical: str, area: Area) -> Any:
        from .las import LasPoints

        self.heights.check(self.label)
        if sum(a.size for a in self.parts["x"]) == 0:
            where = "" if area.everything else f" inside {_describe(area)}"
            raise NoUsableDataError(f"{self.label}: no points{where}; check the area and the "
                                    "source's CRS")
        cat = {k: np.concatenate(v) for k, v in self.parts.items()}
        pts = LasPoints(cat["x"], cat["y"], cat["z"], cat["c"], cat["r"], cat["n"], crs,
                        vertical, (self.label,), None)
        warn_if_normalised(pts.z, pts.classification, self.label)
        return pts


def _describe(area: Area) -> str:
    if area.polygon is not None:
        return "the polygon"
    b = area.box or (0.0, 0.0, 0.0, 0.0)
    return f"bounds ({b[0]:.2f}, {b[1]:.2f}, {b[2]:.2f}, {b[3]:.2f})"
