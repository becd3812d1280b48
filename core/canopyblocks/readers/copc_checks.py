"""A COPC file's octree checked against what it points to, as the nodes are read.

A COPC reader follows the hierarchy: for each node, the byte offset, byte size and point
count of its LAZ chunk.  A damaged hierarchy is read as it says, silently: a count of half
the node's points decompresses half of them, a count of 0 drops the node, an offset at
another node's chunk reads that node's points twice.  A moved octree centre or header
extent makes every node miss the area ("no points").  So, at no extra decompression:

* :func:`check_cube`: the header's extent must lie within the octree's root cube;
* :func:`check_chunks`: each node read must begin a chunk of the file's LAZ chunk table
  (a few bytes after the points, read once) with that chunk's exact point count and byte
  size, no two nodes sharing a chunk, and the table must hold the header's point count;
* :func:`check_node_points`: the decompressed points of each node must lie within its cube
  and within the header's extent.

* :func:`check_total`: the hierarchy's counts must add up to the header's.  A node whose
  entry was zeroed altogether (count, offset and size 0) or left out leaves its chunk
  unreferenced, which no check of the nodes read can see; so a read of a part of the file
  (a box, a corridor, a raster's window) loads the hierarchy pages it did not need too
  (:func:`check_whole_hierarchy`: their ranges fetched together, once per file and
  process: 32 bytes a node) and checks the whole hierarchy's total, as a whole read does.

Each refusal names the file, the node and what disagrees.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import FileFormatError

__all__ = ["check_cube", "chunk_starts", "check_chunks", "check_node_points", "check_total",
           "check_whole_hierarchy", "check_page", "page_entries"]

Node = tuple[int, int, int, int]
NodeEntry = tuple[Node, int, int, int]


def _key(k: Node) -> str:
    return "-".join(map(str, k))


def _pad(h: Any) -> float:
    return 2.0 * max(h.scales)


def check_cube(h: Any) -> None:
    """Refuse a header extent outside the octree's root cube (a moved centre or header)."""
    c, r, b, pad = h.center, h.halfsize, h.bounds, _pad(h)
    ok = (np.isfinite(r) and r > 0 and b[0] >= c[0] - r - pad and b[2] <= c[0] + r + pad
          and b[1] >= c[1] - r - pad and b[3] <= c[1] + r + pad)
    if not ok:
        raise FileFormatError(
            f"{h.label}: its header says the points lie in ({b[0]:.2f}, {b[1]:.2f}, "
            f"{b[2]:.2f}, {b[3]:.2f}) but its octree's cube is centred at ({c[0]:.2f}, "
            f"{c[1]:.2f}) with half-size {r:.2f} m, which does not hold that extent: the header "
            "or the COPC info record is damaged; write the file again")


class _Ranges(io.RawIOBase):
    """A read-only, seekable file over ``src.fetch`` (for lazrs' chunk table reader)."""

    def __init__(self, src: Any) -> None:
        self.src = src
        self.pos = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, pos: int, whence: int = 0) -> int:
        self.pos = {0: pos, 1: self.pos + pos, 2: self.src.size + pos}[whence]
        return self.pos

    def tell(self) -> int:
        return self.pos

    def readinto(self, buf: Any) -> int:
        end = min(self.src.size, self.pos + len(buf))
        if end <= self.pos:
            return 0
        data = self.src.fetch([(self.pos, end)], "the LAZ chunk table")[0]
        buf[:len(data)] = data
        self.pos += len(data)
        return len(data)


_TABLES: dict[tuple[str, int, int, tuple[int, int]], dict[int, tuple[int, int]]] = {}


def chunk_starts(src: Any, h: Any) -> dict[int, tuple[int, int]]:
    """``{byte offset: (points, bytes)}`` of every LAZ chunk of the file (read once per
    file and process: a raster's windows each read the same file).

    Raises
    ------
    FileFormatError
        No readable chunk table (a COPC file has one), or one that holds another point
        count than the header's.
    """
    key = (h.label, int(src.size), int(h.points_at), tuple(h.root))
    if key not in _TABLES:
        if len(_TABLES) > 64:
            _TABLES.clear()
        _TABLES[key] = _read_table(src, h)
    return _TABLES[key]


def _read_table(src: Any, h: Any) -> dict[int, tuple[int, int]]:
    import lazrs

    try:
        f = io.BufferedReader(_Ranges(src), 1 << 14)
        f.seek(h.points_at)
        table = list(lazrs.read_chunk_table(f, lazrs.LazVlr(h.laszip)) or [])
    except FileFormatError:
        raise
    except Exception as exc:  # noqa: BLE001 - lazrs raises its own error types
        raise FileFormatError(f"{h.label}: its LAZ chunk table cannot be read ({exc}); the "
                              "file is damaged: write it again") from None
    counts = np.array([int(c) for c, _ in table], np.int64)
    sizes = np.array([int(s) for _, s in table], np.int64)
    if int(counts.sum()) != h.n_points:
        raise FileFormatError(
            f"{h.label}: its LAZ chunks hold {int(counts.sum()):,} points, its header says "
            f"{h.n_points:,}; the file is damaged: write it again")
    starts = h.points_at + 8 + np.concatenate([[0], np.cumsum(sizes)[:-1]])
    return dict(zip(starts.tolist(), zip(counts.tolist(), sizes.tolist())))


def check_chunks(h: Any, nodes: Sequence[NodeEntry], starts: dict[int, tuple[int, int]]
                 ) -> None:
    """Refuse nodes whose entry does not match the chunk at its offset (count, size)."""
    owner: dict[int, Node] = {}
    for key, offset, size, count in nodes:  # a loop over the nodes read
        got = starts.get(offset)
        if got is None:
            raise FileFormatError(
                f"{h.label}: the hierarchy puts node {_key(key)} at byte {offset:,}, where no "
                "LAZ chunk begins; the hierarchy is damaged: write the file again")
        if got != (count, size):
            raise FileFormatError(
                f"{h.label}: the hierarchy says node {_key(key)} holds {count:,} points in "
                f"{size:,} bytes, its LAZ chunk holds {got[0]:,} points in {got[1]:,} bytes; "
                "the hierarchy is damaged (its nodes would be read wrong): write the file "
                "again")
        if offset in owner:
            raise FileFormatError(
                f"{h.label}: the hierarchy points nodes {_key(owner[offset])} and {_key(key)} at "
                f"the same LAZ chunk (byte {offset:,}); the hierarchy is damaged: write the "
                "file again")
        owner[offset] = key


def check_total(h: Any, entries: dict[Node, tuple[int, int, int]]) -> None:
    """With the whole hierarchy loaded, its counts must add up to the header's."""
    if any(c == -1 for _, _, c in entries.values()):
        return  # pages not loaded: not the whole hierarchy
    total = sum(c for _, _, c in entries.values() if c > 0)
    if total != h.n_points:
        raise FileFormatError(
            f"{h.label}: its hierarchy's nodes hold {total:,} points, its header says "
            f"{h.n_points:,}; the hierarchy is damaged (a node's count is wrong or a node is "
            "missing from it): write the file again")


def check_page(h: Any, where: tuple[int, int]) -> None:
    """Refuse a hierarchy page entry of an impossible size."""
    offset, size = where
    if size % 32 or size <= 0:
        raise FileFormatError(f"{h.label}: a damaged COPC hierarchy (a page of {size} bytes at "
                              f"{offset}); write the file again")


def page_entries(blob: bytes) -> dict[Node, tuple[int, int, int]]:
    """``{key: (offset, byte size, count)}`` of one hierarchy page's 32-byte entries."""
    rows = np.frombuffer(blob, dtype=np.dtype([("key", "<i4", 4), ("offset", "<u8"),
                                               ("size", "<i4"), ("count", "<i4")]))
    return {(k[0], k[1], k[2], k[3]): (o, s, c) for k, o, s, c in zip(
        rows["key"].tolist(), rows["offset"].tolist(), rows["size"].tolist(),
        rows["count"].tolist())}


_WHOLE: set[tuple[str, int, int, tuple[int, int]]] = set()


def check_whole_hierarchy(src: Any, h: Any, entries: dict[Node, tuple[int, int, int]]
                          ) -> None:
    """The whole hierarchy's counts must add up to the header's, also in a read of a part
    of the file: the pages not loaded yet are fetched (each round's ranges together: one
    round per level of nested pages), once per file and process."""
    key = (h.label, int(src.size), int(h.points_at), tuple(h.root))
    if key in _WHOLE:
        return
    every = dict(entries)
    seen: set[tuple[int, int]] = set()
    while True:  # one round per level of nested pages (a few)
        pages = {k: (o, s) for k, (o, s, c) in every.items() if c == -1}
        todo = sorted({p for p in pages.values() if p not in seen})
        for k in pages:
            del every[k]
        if not todo:
            break
        for where in todo:  # a loop over pages, not entries
            check_page(h, where)
            seen.add(where)
        for blob in src.fetch([(o, o + s) for o, s in todo], "the hierarchy pages"):
            every.update(page_entries(blob))
    check_total(h, every)
    if len(_WHOLE) > 64:
        _WHOLE.clear()
    _WHOLE.add(key)


def check_node_points(h: Any, rec: np.ndarray, batch: Sequence[NodeEntry]) -> None:
    """Refuse a node whose decompressed points lie outside its cube or the header's extent."""
    counts = np.array([n[3] for n in batch], np.int64)
    if counts.sum() == 0:
        return
    keys = np.array([n[0] for n in batch], np.float64).reshape(-1, 4)
    side = 2.0 * h.halfsize / np.exp2(keys[:, 0])
    pad = _pad(h)
    lo = np.column_stack([h.center[i] - h.halfsize + keys[:, i + 1] * side - pad
                          for i in range(3)])
    hi = lo + side[:, None] + 2 * pad
    node = np.repeat(np.arange(len(batch)), counts)
    b = h.bounds
    bad = np.zeros(node.size, dtype=bool)
    for i, name in enumerate("XYZ"):  # three axes
        v = rec[name] * h.scales[i] + h.offsets[i]
        bad |= (v < lo[node, i]) | (v > hi[node, i])
        if i < 2:
            bad |= (v < b[i] - pad) | (v > b[i + 2] + pad)
    if bad.any():
        first = int(node[np.argmax(bad)])
        k = batch[first][0]
        n_bad = int(np.count_nonzero(bad & (node == first)))
        raise FileFormatError(
            f"{h.label}: {n_bad:,} of the {int(counts[first]):,} points read for node "
            f"{_key(k)} lie outside its octree cube or the header's extent: the hierarchy "
            "points at another node's data, or the octree's centre or the header is damaged; "
            "write the file again")
