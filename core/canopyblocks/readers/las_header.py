"""Checks of a LAS/LAZ public header before any point is read.

A truncated or damaged file must be refused as such, not reported as "states no CRS" or
"no points inside the box", and a header whose scale, offset or point count cannot be
right must not turn the points into zeros, 1e300 or half a tile.  Checked, from the
public header (ASPRS LAS 1.0-1.4) and the file size:

* the signature ``LASF`` and a header of full length;
* the point data starting inside the file; for LAZ, the chunk-table pointer inside the
  file; for uncompressed LAS, the file holding exactly the points the header counts
  (up to the extended VLRs of LAS 1.4);
* x/y/z scale factors finite, positive and at most 1 m per unit; offsets finite and
  within 1e9 m (no projected coordinate is larger).

Both ``readers.las.read_las`` and the PDAL path (``reference.pdal``) use it.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from pathlib import Path

from ..errors import FileFormatError

__all__ = ["check_las_file", "check_header_extent", "check_nothing_beyond_count",
           "points_unreadable", "MAX_SCALE",
           "MAX_OFFSET"]

MAX_SCALE = 1.0
"""Largest plausible scale factor, metres per integer unit (surveys use 0.001-0.01)."""
MAX_OFFSET = 1.0e9
"""Largest plausible header offset, metres."""

_HEADER_MIN = 227  # LAS 1.0-1.2 public header size


def check_las_file(path: str | Path) -> None:
    """Refuse a LAS/LAZ file whose header cannot describe its points.

    Raises
    ------
    FileFormatError
        Not LAS/LAZ, truncated, or a header with impossible scale, offset or point
        count; the message names the file and what is wrong.
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        with p.open("rb") as f:
            head = f.read(375)
            if len(head) < _HEADER_MIN or head[:4] != b"LASF":
                raise FileFormatError(f"{p} is not a LAS/LAZ file (no LASF header) or is "
                                      f"truncated ({size} bytes)")
            offset = struct.unpack_from("<I", head, 96)[0]
            fmt = head[104]
            rec_len = struct.unpack_from("<H", head, 105)[0]
            n_legacy = struct.unpack_from("<I", head, 107)[0]
            scales = struct.unpack_from("<3d", head, 131)
            offsets = struct.unpack_from("<3d", head, 155)
            version = (head[24], head[25])
            n = n_legacy
            evlr_start = 0
            if version >= (1, 4) and len(head) >= 375:
                evlr_start = struct.unpack_from("<Q", head, 235)[0]
                if n_legacy == 0:
                    n = struct.unpack_from("<Q", head, 247)[0]
            if size < offset:
                raise FileFormatError(f"{p} is truncated: {size} bytes, its header says the "
                                      f"points start at byte {offset}")
            for axis, v in zip("xyz", scales):
                if not (math.isfinite(v) and 0.0 < v <= MAX_SCALE):
                    raise FileFormatError(
                        f"{p}: the header's {axis} scale factor is {v:g}, not a positive "
                        f"step of at most {MAX_SCALE:g} m; the header is corrupt (rewrite "
                        "the file with a LAS tool, e.g. las2las or PDAL)")
            for axis, v in zip("xyz", offsets):
                if not (math.isfinite(v) and abs(v) <= MAX_OFFSET):
                    raise FileFormatError(
                        f"{p}: the header's {axis} offset is {v:g} m, beyond any coordinate; "
                        "the header is corrupt (rewrite the file with a LAS tool)")
            if fmt & 0x80 or fmt & 0x40:  # LAZ: a chunk-table pointer opens the point data
                f.seek(offset)
                raw = f.read(8)
                table = struct.unpack("<q", raw)[0] if len(raw) == 8 else size + 1
                if table > size:
                    raise FileFormatError(f"{p} is truncated: {size} bytes, its LAZ chunk "
                                          f"table is at byte {table}")
            elif rec_len > 0:
                end = evlr_start if 0 < evlr_start <= size else size
                held = (end - offset) // rec_len
                if held < n:
                    raise FileFormatError(
                        f"{p} is truncated: {size} bytes hold {held} points of {rec_len} "
                        f"bytes, its header counts {n}; the file was cut short (copy or "
                        "download it again) or its header is wrong (write it again with a "
                        "LAS tool, e.g. las2las or PDAL)")
                if held > n and (end - offset) - n * rec_len >= rec_len:
                    raise FileFormatError(
                        f"{p}: the header counts {n} points but the file holds {held} "
                        f"(point records of {rec_len} bytes from byte {offset}); the header "
                        "is corrupt (rewrite the file with a LAS tool)")
    except FileFormatError:
        raise
    except OSError as exc:
        raise FileFormatError(f"cannot read {p}: {exc}") from None


def plausible_box(box: Sequence[float]) -> bool:
    """Whether a header extent can be right (finite, within 1e9 m, min <= max)."""
    b = [float(v) for v in box]
    return (all(math.isfinite(v) and abs(v) <= MAX_OFFSET for v in b)
            and b[0] <= b[2] and b[1] <= b[3])


def check_header_extent(path: str | Path, header: tuple[float, float, float, float],
                        points: tuple[float, float, float, float], tolerance: float) -> bool:
    """Compare the header's extent with the points'; True when they agree.

    A header extent that cannot be right (NaN, beyond 1e9 m, min above max) is a lie the
    points correct: False is returned and the caller uses the points' extent (with a
    warning).  A plausible header extent that disagrees with the points by more than
    ``tolerance`` (m) is refused: either the extent or the header's scale/offset is
    corrupt, and the two cannot be told apart (a flipped offset bit moves every point).

    Raises
    ------
    FileFormatError
        A plausible header extent that disagrees with the points.
    """
    h = [float(v) for v in header]
    broken = not all(math.isfinite(v) and abs(v) <= MAX_OFFSET for v in h) or \
        h[0] > h[2] or h[1] > h[3]
    if broken:
        return False
    worst = max(abs(a - b) for a, b in zip(h, points))
    if worst <= tolerance:
        return True
    raise FileFormatError(
        f"{path}: its header says the points lie in ({h[0]:.2f}, {h[1]:.2f}, {h[2]:.2f}, "
        f"{h[3]:.2f}) but they lie in ({points[0]:.2f}, {points[1]:.2f}, {points[2]:.2f}, "
        f"{points[3]:.2f}): the header's extent or its scale/offset is corrupt; rewrite the "
        "file with a LAS tool (e.g. las2las or PDAL) after checking where it should be")


def check_nothing_beyond_count(reader: object, path: str | Path, count: int) -> None:
    """Check that a LAZ file holds no more points than the ``count`` its header states.

    A header that counts fewer points than the file holds makes every reader stop early,
    silently (half a tile).  The LAZ chunk table (read by lazrs, a few bytes at the end of
    the file) says how many points the file holds: exactly, with variable-size chunks;
    with fixed-size chunks (``chunk_size`` points each, the last one partial), more than
    ``(chunks - 1) * chunk_size``.  No point is decompressed beyond the count (asking the
    decompressor for one more point returned one for valid laspy-written files, and made
    older lazrs releases panic).  Uncompressed LAS files are checked by size in
    :func:`check_las_file`.

    Raises
    ------
    FileFormatError
        The chunk table holds more points than the header counts.
    """
    if Path(path).suffix.lower() != ".laz":
        return
    table, chunk_size, variable = _chunk_table(reader, path)
    if not table:
        return  # no table to read (another backend, or none written): nothing to tell
    if variable:
        held = sum(int(c[0]) for c in table)
        more = held > count
        what = f"its chunk table holds {held:,} points"
    else:
        held = (len(table) - 1) * chunk_size
        more = held >= count
        what = f"its chunk table holds {len(table)} chunks of {chunk_size:,} points"
    if more:
        raise FileFormatError(
            f"{path}: the file holds more points than the {count:,} its header counts "
            f"({what}); the header is corrupt (rewrite the file with a LAS tool, e.g. "
            "las2las or PDAL)")


def _chunk_table(reader: object, path: str | Path) -> tuple[list, int, bool]:
    """The LAZ chunk table ``[(points, bytes), ...]``, the chunk size and whether chunks
    vary in size; an empty table when it cannot be read (then nothing is claimed).  The
    header is read afresh (laspy drops the laszip record from an open reader's header once
    its points are read)."""
    if getattr(reader, "header", None) is None:
        return [], 0, False  # not a laspy reader: nothing to ask
    return _read_chunk_table(path)


def points_unreadable(path: str | Path, exc: BaseException, count: int) -> FileFormatError:
    """The refusal of a LAS/LAZ file whose points cannot be decompressed (``exc``, the
    decompressor's error, is not shown): a header counting more points than the LAZ chunk
    table holds is named as such, else the file is damaged."""
    import logging

    logging.getLogger(__name__).debug("%s: %s", path, exc)
    table, chunk_size, variable = (_read_chunk_table(path) if Path(path).suffix.lower()
                                   == ".laz" else ([], 0, False))
    held = sum(int(c[0]) for c in table) if variable else len(table) * chunk_size
    if table and held < count:
        most = "" if variable else "at most "
        return _counts_more(path, count, f"the file holds {most}{held:,} (its LAZ chunk "
                                         "table)")
    if table and not variable:
        first = (len(table) - 1) * chunk_size
        last = _points_decoded(path, first, count - first)
        if last is not None and last < count - first:
            return _counts_more(path, count, f"the LAZ data runs out about {last:,} points "
                                             f"into its last chunk, {count - first - last:,} "
                                             "short of that count")
    return FileFormatError(
        f"{path}: cannot decompress its points: the file is damaged or cut short; copy or "
        "download it again, or write it again with a LAS tool (e.g. las2las or PDAL)")


def _counts_more(path: str | Path, count: int, why: str) -> FileFormatError:
    return FileFormatError(
        f"{path}: its header counts {count:,} points, more than the file holds ({why}): "
        "the tile is damaged or its header is wrong; write it again with a LAS tool (e.g. "
        "las2las or PDAL) from a good copy")


def _points_decoded(path: str | Path, start: int, wanted: int) -> int | None:
    """How many of ``wanted`` points from point ``start`` (the last LAZ chunk's first)
    decompress (bisection, on the failure path only; the coder may yield a few points
    past the data's end); None when the decompressor cannot be set up."""
    try:
        import laspy
        import lazrs

        with laspy.open(path) as r:
            vlr = next(v for v in r.header.vlrs if getattr(v, "record_id", None) == 22204)
            offset, size = int(r.header.offset_to_point_data), int(r.header.point_format.size)

        def decodes(k: int) -> bool:
            with open(path, "rb") as fh:
                fh.seek(offset)
                d = lazrs.LasZipDecompressor(fh, vlr.record_data)
                d.seek(start)
                try:
                    d.decompress_many(bytearray(k * size))
                except Exception:  # noqa: BLE001 - lazrs's error: the data ran out
                    return False
            return True

        lo, hi = 0, wanted
        while lo < hi:
            mid = (lo + hi + 1) // 2
            lo, hi = (mid, hi) if decodes(mid) else (lo, mid - 1)
        return lo
    except Exception:  # noqa: BLE001 - no decompressor: nothing is claimed
        return None


def _read_chunk_table(path: str | Path) -> tuple[list, int, bool]:
    """The LAZ chunk table of ``path`` as :func:`_chunk_table` returns it."""
    try:
        import laspy
        import lazrs

        with laspy.open(path) as fresh:
            header = fresh.header
            vlr = next((v for v in header.vlrs if getattr(v, "record_id", None) == 22204
                        and hasattr(v, "record_data")), None)
            if vlr is None:
                return [], 0, False
            laz_vlr = lazrs.LazVlr(vlr.record_data)
            offset = int(header.offset_to_point_data)
        with open(path, "rb") as fh:
            fh.seek(offset)
            table = list(lazrs.read_chunk_table(fh, laz_vlr) or [])
        chunk_size = int(laz_vlr.chunk_size())
        variable = bool(laz_vlr.uses_variable_size_chunks())
    except Exception:  # noqa: BLE001 - no readable table: the count cannot be judged here
        return [], 0, False
    if not all(isinstance(c, (tuple, list)) and len(c) == 2 for c in table):
        return [], 0, False
    return table, chunk_size, variable
