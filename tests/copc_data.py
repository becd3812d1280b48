"""Cloud-optimised surveys made from LAS/LAZ tiles, for the COPC/EPT tests and the bench.

Neither PDAL 2.2 (no ``writers.copc``) nor laspy writes COPC, so this is a small writer of
the two layouts, following their specifications:

* COPC 1.0 (copc.io): a LAS 1.4 file, point format 6 (7/8 with colour), LAZ with chunks of
  variable size, one chunk per octree node; the ``copc`` info VLR (record 1, 160 bytes) is
  the first VLR, the hierarchy is an EVLR (``copc``, record 1000) of 32-byte entries (voxel
  key d, x, y, z; offset; byte size; point count; -1 = a page of further entries).
* Entwine Point Tile 1.0: ``ept.json`` (cubic ``bounds``, ``boundsConforming``, ``schema``,
  ``srs``, ``dataType`` laszip), ``ept-hierarchy/D-X-Y-Z.json`` (counts; -1 = a
  sub-hierarchy file) and one LAZ file per node in ``ept-data/``.

The octree: a node keeps at most ``capacity`` points (a random sample, fixed by ``seed``), the
rest go down to its eight children; the deepest level keeps all.  The points are the tiles'
own integers (same scale and offset), so a reader's coordinates equal the tiles' exactly.
"""

from __future__ import annotations

import io
import json
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import laspy
import lazrs
import numpy as np
import pyproj

__all__ = ["Octree", "build_octree", "write_copc", "write_ept", "tile_points",
           "shifted_grid", "copc_damaged", "garbled_node", "sibling_box", "root_node", "NODE",
           "node_box",
           "node_entry", "ept_node_damaged", "copc_node_damaged", "NODE_EDITS"]


@dataclass(frozen=True)
class Octree:
    """Points (a laspy point record in format 6) sorted by node, and the nodes in order."""

    points: laspy.LasData
    keys: np.ndarray        # (n_nodes, 4) int32: level, x, y, z
    counts: np.ndarray      # (n_nodes,) points per node
    center: np.ndarray      # (3,) cube centre, metres
    halfsize: float         # metres
    spacing: float          # metres at the root


def tile_points(paths: Sequence[Path]) -> laspy.LasData:
    """The tiles' points in one LAS 1.4 point-format-6 record (scales/offsets of the first;
    every tile must share them)."""
    datas = [laspy.read(p) for p in paths]
    first = datas[0].header
    for d in datas[1:]:
        if not (np.array_equal(d.header.scales, first.scales)
                and np.array_equal(d.header.offsets, first.offsets)):
            raise ValueError("tiles with different scales/offsets")
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = first.scales, first.offsets
    n = sum(len(d.points) for d in datas)
    out = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(
        n, header=header))
    i = 0
    for d in datas:
        k = len(d.points)
        for name in ("X", "Y", "Z", "intensity", "return_number", "number_of_returns",
                     "classification", "gps_time", "point_source_id", "user_data"):
            if name in d.point_format.dimension_names:
                out.points[name][i:i + k] = d.points[name]
        i += k
    return out


def shifted_grid(points: laspy.LasData, nx: int, ny: int, dx: float, dy: float
                 ) -> laspy.LasData:
    """``nx`` x ``ny`` copies of ``points`` shifted by ``dx``/``dy`` metres (whole integer
    steps of the scale): a bigger survey made of the same forest."""
    arr = points.points.array
    sx, sy = (round(dx / points.header.scales[0]), round(dy / points.header.scales[1]))
    copies = []
    for i in range(nx):
        for j in range(ny):
            c = arr.copy()
            c["X"] += np.int32(i * sx)
            c["Y"] += np.int32(j * sy)
            copies.append(c)
    return laspy.LasData(points.header, points=laspy.ScaleAwarePointRecord(
        np.concatenate(copies), points.header.point_format, points.header.scales,
        points.header.offsets))


def _full_crs(paths: Sequence[Path]) -> pyproj.CRS | None:
    """The first tile's whole CRS (compound when it states a vertical datum), as
    canopyblocks reads it."""
    from canopyblocks.readers.las_crs import las_file_crs

    return las_file_crs(paths[0]).crs


def build_octree(points: laspy.LasData, capacity: int = 20_000, max_level: int = 8,
                 seed: int = 1) -> Octree:
    """Assign every point to one node (level by level, a random ``capacity`` per node)."""
    xyz = np.column_stack([np.asarray(points.x), np.asarray(points.y), np.asarray(points.z)])
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    center = (lo + hi) / 2.0
    halfsize = float((hi - lo).max() / 2.0 + 1.0)
    cube_lo = center - halfsize
    n = len(xyz)
    rng = np.random.default_rng(seed)
    node_of = np.full(n, -1, np.int64)
    keys: list[np.ndarray] = []
    todo = np.arange(n)
    for level in range(max_level + 1):
        side = 2.0 * halfsize / 2 ** level
        ijk = np.clip(((xyz[todo] - cube_lo) // side).astype(np.int64), 0, 2 ** level - 1)
        code = (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]
        uniq, inv = np.unique(code, return_inverse=True)
        perm = rng.permutation(todo.size)  # a random order inside each node
        order = perm[np.argsort(inv[perm], kind="stable")]
        starts = np.searchsorted(inv[order], np.arange(uniq.size))
        rank = np.empty(todo.size, np.int64)
        rank[order] = np.arange(todo.size) - starts[inv[order]]
        keep = np.ones(todo.size, bool) if level == max_level else rank < capacity
        node_of[todo[keep]] = inv[keep] + sum(len(k) for k in keys)
        kk = np.column_stack([np.full(uniq.size, level), uniq >> 42, (uniq >> 21) & 0x1FFFFF,
                              uniq & 0x1FFFFF]).astype(np.int32)
        keys.append(kk)
        todo = todo[~keep]
        if todo.size == 0:
            break
    all_keys = np.concatenate(keys)
    used = np.unique(node_of)
    remap = np.full(all_keys.shape[0], -1, np.int64)
    remap[used] = np.arange(used.size)
    node = remap[node_of]
    order = np.argsort(node, kind="stable")
    arr = points.points.array
    rows = arr.view(np.uint8).reshape(arr.size, arr.dtype.itemsize)[order]  # fast row take
    sorted_pts = laspy.LasData(points.header, points=laspy.ScaleAwarePointRecord(
        rows.reshape(-1).view(arr.dtype), points.header.point_format, points.header.scales,
        points.header.offsets))
    counts = np.bincount(node, minlength=used.size)
    return Octree(sorted_pts, all_keys[used], counts, center, halfsize,
                  spacing=2.0 * halfsize / 128.0)


def _vlr(user: bytes, record: int, data: bytes, desc: bytes = b"") -> bytes:
    return struct.pack("<H16sHH32s", 0, user, record, len(data), desc) + data


def _evlr(user: bytes, record: int, data: bytes) -> bytes:
    return struct.pack("<H16sHQ32s", 0, user, record, len(data), b"") + data


def _header(pts: laspy.LasData, offset_to_points: int, n_vlrs: int, evlr_start: int,
            n_evlrs: int) -> bytes:
    h = pts.header
    x, y, z = (np.asarray(pts.x), np.asarray(pts.y), np.asarray(pts.z))
    rn = np.asarray(pts.return_number)
    by_return = [int(np.count_nonzero(rn == k)) for k in range(1, 16)]
    out = struct.pack("<4sHH16sBB32s32sHHHIIBHI5I", b"LASF", 0, 16, b"\0" * 16, 1, 4,
                      b"canopyblocks tests", b"canopyblocks copc_data", 1, 2024, 375,
                      offset_to_points, n_vlrs, 6 | 0x80, 30, 0, 0, 0, 0, 0, 0)
    out += struct.pack("<3d3d6d", *h.scales, *h.offsets, x.max(), x.min(), y.max(), y.min(),
                       z.max(), z.min())
    out += struct.pack("<QQIQ15Q", 0, evlr_start, n_evlrs, len(x), *by_return)
    assert len(out) == 375
    return out


def _entry(key: Sequence[int], offset: int, size: int, count: int) -> bytes:
    return struct.pack("<4iQii", *[int(k) for k in key], offset, size, count)


def write_copc(paths: Sequence[Path], out: Path, *, capacity: int = 20_000,
               page_level: int | None = None, seed: int = 1, tree: Octree | None = None,
               crs: str = "vlr") -> Octree:
    """Write the tiles' points as one COPC file; the octree written.

    ``page_level``: nodes at this level and below go into hierarchy pages of their own (one
    per node of that level), so a reader must follow page entries.  ``tree``: an octree
    already built from ``paths`` (the CRS is still read from ``paths``).  ``crs``: where
    the tiles' CRS (WKT) is written: ``"vlr"`` (before the points), ``"evlr"`` (an extended
    VLR after the hierarchy, as copc-lib writes it) or ``"none"`` (not at all).
    """
    tree = tree or build_octree(tile_points(paths), capacity=capacity, seed=seed)
    pts = tree.points
    wkt = _full_crs(paths) if crs != "none" else None
    wkt_data = (wkt.to_wkt().encode() + b"\0") if wkt is not None else b""
    in_evlr = crs == "evlr" and bool(wkt_data)
    vlr = lazrs.LazVlr.new_for_compression(6, 0, use_variable_size_chunks=True)
    laz = _vlr(b"laszip encoded", 22204, bytes(vlr.record_data()))
    n_vlrs = 2 + (bool(wkt_data) and not in_evlr)
    info_len = 54 + 160
    offset_to_points = 375 + info_len + len(laz) + (
        (54 + len(wkt_data)) if wkt_data and not in_evlr else 0)
    raw = pts.points.array.tobytes()
    rec = 30
    with out.open("w+b") as fh:
        fh.write(b"\0" * offset_to_points)
        comp = lazrs.LasZipCompressor(fh, vlr)
        comp.reserve_offset_to_chunk_table()
        first = 0
        for c in tree.counts:
            comp.compress_many(raw[first * rec:(first + int(c)) * rec])
            comp.finish_current_chunk()
            first += int(c)
        comp.done()
        fh.seek(offset_to_points)
        table = lazrs.read_chunk_table(fh, vlr)
        sizes = np.array([b for _, b in table], np.int64)
        offsets = offset_to_points + 8 + np.concatenate([[0], np.cumsum(sizes)[:-1]])
        fh.seek(0, io.SEEK_END)
        evlr_start = fh.tell()
        hier = _hierarchy(tree, offsets, sizes, evlr_start + 60, page_level)
        fh.write(_evlr(b"copc", 1000, hier[0]))
        if in_evlr:
            fh.write(_evlr(b"LASF_Projection", 2112, wkt_data))
        gps = np.asarray(pts.gps_time)
        info = struct.pack("<5d2Q2d11Q", *tree.center, tree.halfsize, tree.spacing,
                           evlr_start + 60, hier[1], float(gps.min()), float(gps.max()),
                           *([0] * 11))
        fh.seek(0)
        fh.write(_header(pts, offset_to_points, n_vlrs, evlr_start, 1 + in_evlr))
        fh.write(_vlr(b"copc", 1, info, b"copc info"))
        fh.write(laz)
        if wkt_data and not in_evlr:
            fh.write(_vlr(b"LASF_Projection", 2112, wkt_data))
    return tree


def _hierarchy(tree: Octree, offsets: np.ndarray, sizes: np.ndarray, base: int,
               page_level: int | None) -> tuple[bytes, int]:
    """The hierarchy EVLR's data (root page first) and the root page's size."""
    keys = tree.keys
    entries = [_entry(k, int(o), int(s), int(c))
               for k, o, s, c in zip(keys, offsets, sizes, tree.counts)]
    if page_level is None:
        blob = b"".join(entries)
        return blob, len(blob)
    deep = keys[:, 0] >= page_level
    shift = keys[:, 0] - page_level
    anc = np.column_stack([np.full(len(keys), page_level), keys[:, 1] >> np.maximum(shift, 0),
                           keys[:, 2] >> np.maximum(shift, 0), keys[:, 3] >> np.maximum(shift, 0)])
    pages = sorted({tuple(a) for a in anc[deep]})
    root = [e for e, d in zip(entries, deep) if not d]
    root_size = 32 * (len(root) + len(pages))
    blobs, pos = [], base + root_size
    for p in pages:
        mine = [e for e, d, a in zip(entries, deep, anc) if d and tuple(a) == p]
        blob = b"".join(mine)
        root.append(_entry(p, pos, len(blob), -1))
        blobs.append(blob)
        pos += len(blob)
    return b"".join(root) + b"".join(blobs), root_size


def write_ept(paths: Sequence[Path], out_dir: Path, *, capacity: int = 20_000,
              split_level: int | None = None, seed: int = 1, tree: Octree | None = None
              ) -> Octree:
    """Write the tiles' points as an EPT dataset (laszip nodes) under ``out_dir``.

    ``split_level``: nodes at this level and below are listed in sub-hierarchy files.
    """
    tree = tree or build_octree(tile_points(paths), capacity=capacity, seed=seed)
    pts = tree.points
    (out_dir / "ept-data").mkdir(parents=True, exist_ok=True)
    (out_dir / "ept-hierarchy").mkdir(exist_ok=True)
    names = ["-".join(str(int(v)) for v in k) for k in tree.keys]
    first = 0
    for name, c in zip(names, tree.counts):
        node = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
        node.header.scales, node.header.offsets = pts.header.scales, pts.header.offsets
        node.header.global_encoding.wkt = True  # PDAL insists for point format 6
        node.points = laspy.ScaleAwarePointRecord(
            pts.points.array[first:first + int(c)].copy(), node.header.point_format,
            pts.header.scales, pts.header.offsets)
        node.update_header()
        node.write(out_dir / "ept-data" / f"{name}.laz")
        first += int(c)
    counts = {n: int(c) for n, c in zip(names, tree.counts)}
    if split_level is None:
        (out_dir / "ept-hierarchy" / "0-0-0-0.json").write_text(json.dumps(counts))
    else:
        root: dict[str, int] = {}
        subs: dict[str, dict[str, int]] = {}
        for k, n in zip(tree.keys, names):
            if k[0] < split_level:
                root[n] = counts[n]
                continue
            s = int(k[0] - split_level)
            a = f"{split_level}-{k[1] >> s}-{k[2] >> s}-{k[3] >> s}"
            subs.setdefault(a, {})[n] = counts[n]
            root[a] = -1
        (out_dir / "ept-hierarchy" / "0-0-0-0.json").write_text(json.dumps(root))
        for a, d in subs.items():
            (out_dir / "ept-hierarchy" / f"{a}.json").write_text(json.dumps(d))
    x, y, z = np.asarray(pts.x), np.asarray(pts.y), np.asarray(pts.z)
    lo = tree.center - tree.halfsize
    hi = tree.center + tree.halfsize
    crs = _full_crs(paths)
    sc, of = pts.header.scales, pts.header.offsets
    schema = [{"name": n, "type": "signed", "size": 4, "scale": float(s), "offset": float(o)}
              for n, s, o in zip("XYZ", sc, of)]
    schema += [{"name": "Intensity", "type": "unsigned", "size": 2},
               {"name": "ReturnNumber", "type": "unsigned", "size": 1},
               {"name": "NumberOfReturns", "type": "unsigned", "size": 1},
               {"name": "Classification", "type": "unsigned", "size": 1},
               {"name": "GpsTime", "type": "float", "size": 8}]
    srs: dict[str, str] = {}
    if crs is not None:
        srs["wkt"] = crs.to_wkt()
        subs = crs.sub_crs_list if crs.is_compound else [crs]
        codes = [c.to_epsg() for c in subs]
        if all(codes):
            srs.update(authority="EPSG", horizontal=str(codes[0]))
            if len(codes) > 1:
                srs["vertical"] = str(codes[1])
    meta = {"bounds": [*lo.tolist(), *hi.tolist()],
            "boundsConforming": [float(x.min()), float(y.min()), float(z.min()),
                                 float(x.max()), float(y.max()), float(z.max())],
            "dataType": "laszip", "hierarchyType": "json", "points": int(len(x)),
            "schema": schema, "span": 128, "srs": srs, "version": "1.0.0"}
    (out_dir / "ept.json").write_text(json.dumps(meta, indent=1))
    return tree


_E = struct.Struct("<4iQii")
_INFO_AT = 375 + 54  # the COPC info record's data


def _level2(raw: bytes) -> list[tuple[int, tuple[int, ...]]]:
    """(entry position, entry) of the level-2 nodes with points (in hierarchy pages)."""
    root_at, root_size = struct.unpack_from("<2Q", raw, _INFO_AT + 40)
    root = [_E.unpack_from(raw, root_at + 32 * i) for i in range(root_size // 32)]
    out = []
    for page in (e for e in root if e[6] == -1):
        out += [(page[4] + 32 * i, _E.unpack_from(raw, page[4] + 32 * i))
                for i in range(page[5] // 32)]
    return [(at, e) for at, e in out if e[0] == 2 and e[6] > 0]


def sibling_box(raw: bytes) -> tuple[float, float, float, float]:
    """A box inside the cube of the node that the ``"sibling"`` edit points elsewhere."""
    cx, cy, _, half = struct.unpack_from("<4d", raw, _INFO_AT)
    key = _level2(raw)[1][1]
    side = half / 2.0
    x0, y0 = cx - half + key[1] * side, cy - half + key[2] * side
    return (x0 + 0.4 * side, y0 + 0.4 * side, x0 + 0.6 * side, y0 + 0.6 * side)


def root_node(raw: bytes) -> tuple[int, ...]:
    """The root page's first node with points: (d, x, y, z, offset, byte size, count) (the
    node the ``"half"`` and ``"none"`` edits change; its byte size depends on the lazrs
    that wrote the file)."""
    root_at, root_size = struct.unpack_from("<2Q", raw, _INFO_AT + 40)
    return next(e for e in (_E.unpack_from(raw, root_at + 32 * i)
                            for i in range(root_size // 32)) if e[6] > 0)


def copc_damaged(raw: bytes, edit: str) -> bytes:
    """The COPC bytes with one lie: a node's count halved or zeroed, a node pointed at
    another node's chunk (its parent's: ``"other"``, its sibling's: ``"sibling"``), two
    siblings' chunks exchanged (``"swap"``), the octree centre or the header extent moved
    5 km; or one node's compressed bytes garbled (``"garbled"``)."""
    b = bytearray(raw)
    root_at, root_size = struct.unpack_from("<2Q", raw, _INFO_AT + 40)
    root = [(root_at + 32 * i, _E.unpack_from(raw, root_at + 32 * i))
            for i in range(root_size // 32)]
    at0, e0 = next((at, e) for at, e in root if e[6] > 0)
    page = next(e for _, e in root if e[6] == -1)
    inner = [(page[4] + 32 * i, _E.unpack_from(raw, page[4] + 32 * i))
             for i in range(page[5] // 32)]
    inner = [(at, e) for at, e in inner if e[6] > 0]
    if edit == "half":
        _E.pack_into(b, at0, *e0[:6], e0[6] // 2)
    elif edit == "none":
        _E.pack_into(b, at0, *e0[:6], 0)
    elif edit == "other":
        (_, e1), (at2, e2) = inner[0], inner[-1]
        _E.pack_into(b, at2, *e2[:4], e1[4], e1[5], e1[6])
    elif edit == "sibling":
        (_, e1), (at2, e2) = _level2(raw)[:2]
        _E.pack_into(b, at2, *e2[:4], e1[4], e1[5], e1[6])
    elif edit == "swap":  # two siblings' chunks exchanged: every count still adds up
        (at1, e1), (at2, e2) = _level2(raw)[:2]
        _E.pack_into(b, at2, *e2[:4], e1[4], e1[5], e1[6])
        _E.pack_into(b, at1, *e1[:4], e2[4], e2[5], e2[6])
    elif edit == "centre":
        cx = struct.unpack_from("<d", raw, _INFO_AT)[0]
        struct.pack_into("<d", b, _INFO_AT, cx + 5000.0)
    elif edit == "header":
        mx, mnx = struct.unpack_from("<2d", raw, 179)
        struct.pack_into("<2d", b, 179, mx + 5000.0, mnx + 5000.0)
    elif edit == "garbled":  # 64 bytes inside a level-2 node's chunk inverted
        e = _level2(raw)[0][1]
        mid = e[4] + e[5] // 2
        b[mid:mid + 64] = bytes(v ^ 0xFF for v in b[mid:mid + 64])
    return bytes(b)


def garbled_node(raw: bytes) -> str:
    """The key (``level-x-y-z``) of the node whose chunk the ``"garbled"`` edit damages."""
    return "-".join(map(str, _level2(raw)[0][1][:4]))


# ---- one node's data that the hierarchy does not hold: for whole and window reads ----------
NODE = (2, 0, 0, 1)
"""The node damaged by :func:`ept_node_damaged` and :func:`copc_node_damaged` (a leaf of the
Topography tile's octree at capacity 5,000: 523 points, listed in a sub-hierarchy)."""

NODE_EDITS = {
    "ept": ("node-missing", "node-truncated", "node-count", "node-counts-swapped",
            "node-left-out", "node-zero"),
    "copc": ("node-past-end", "node-size-past-end", "node-into-other", "node-zeroed",
             "node-cut"),
}
"""The edits of each kind: a node's data file deleted or cut in half, its hierarchy count
400, its count and its sibling's (2-0-1-1, 563 points) exchanged, its entry left out or
counted 0; a COPC node's offset past the file's end, its byte size
past it, its offset inside its parent's chunk, its entry zeroed, the file cut inside it."""


def node_box(cube: Sequence[float], key: Sequence[int] = NODE
             ) -> tuple[float, float, float, float]:
    """The middle fifth of a node's cube seen from above (``cube``: the root cube's
    minx, miny, minz, maxx, ...): a window read there reads the node."""
    side = (cube[3] - cube[0]) / 2 ** key[0]
    x0, y0 = cube[0] + key[1] * side, cube[1] + key[2] * side
    return (x0 + 0.4 * side, y0 + 0.4 * side, x0 + 0.6 * side, y0 + 0.6 * side)


def _entries(raw: bytes) -> dict[tuple[int, ...], tuple[int, tuple[int, ...]]]:
    """Every node entry of a COPC file: key -> (its position, the entry)."""
    root_at, root_size = struct.unpack_from("<2Q", raw, _INFO_AT + 40)
    out, todo = {}, [(root_at, root_size)]
    while todo:  # pages, not points
        at, size = todo.pop()
        for i in range(size // 32):
            e = _E.unpack_from(raw, at + 32 * i)
            if e[6] == -1:
                todo.append((e[4], e[5]))
            else:
                out[tuple(e[:4])] = (at + 32 * i, e)
    return out


def node_entry(raw: bytes, key: Sequence[int] = NODE) -> tuple[int, ...]:
    """A COPC node's entry: (d, x, y, z, offset, byte size, count)."""
    return _entries(raw)[tuple(key)][1]


def copc_node_damaged(raw: bytes, edit: str, key: Sequence[int] = NODE) -> bytes:
    """The COPC bytes with node ``key``'s entry (or data) damaged by ``edit``
    (:data:`NODE_EDITS`)."""
    at, e = _entries(raw)[tuple(key)]
    parent = node_entry(raw, (key[0] - 1, key[1] // 2, key[2] // 2, key[3] // 2))
    if edit == "node-cut":  # the file ends in the middle of the node's chunk
        return raw[:e[4] + e[5] // 2]
    o, s, c = {"node-past-end": (len(raw) + e[4], e[5], e[6]),
               "node-size-past-end": (e[4], len(raw), e[6]),
               "node-into-other": (parent[4] + parent[5] // 2, e[5], e[6]),
               "node-zeroed": (0, 0, 0)}[edit]
    b = bytearray(raw)
    _E.pack_into(b, at, *e[:4], o, s, c)
    return bytes(b)


def ept_node_damaged(folder: Path, edit: str, key: Sequence[int] = NODE) -> None:
    """Damage node ``key`` of the EPT dataset in ``folder`` in place (:data:`NODE_EDITS`)."""
    name = "-".join(map(str, key))
    data = folder / "ept-data" / f"{name}.laz"
    if edit == "node-missing":
        data.unlink()
        return
    if edit == "node-truncated":
        raw = data.read_bytes()
        data.write_bytes(raw[:len(raw) // 2])
        return
    hier = next(h for h in sorted((folder / "ept-hierarchy").glob("*.json"))
                if name in json.loads(h.read_text()))
    counts = json.loads(hier.read_text())
    if edit == "node-left-out":
        del counts[name]
    elif edit == "node-counts-swapped":  # the hierarchy's total still adds up
        other = f"{key[0]}-{key[1]}-{key[2] + 1}-{key[3]}"
        counts[name], counts[other] = counts[other], counts[name]
    else:
        counts[name] = {"node-count": 400, "node-zero": 0}[edit]
    hier.write_text(json.dumps(counts))
