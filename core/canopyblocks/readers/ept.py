"""Entwine Point Tile (EPT 1.0) datasets: read only the octree nodes an area needs.

An EPT dataset is a folder (or a URL prefix) holding ``ept.json`` (the cubic root
``bounds``, ``boundsConforming``, ``points``, ``schema``, ``srs``, ``dataType``), the
hierarchy ``ept-hierarchy/D-X-Y-Z.json`` (``{"D-X-Y-Z": point count}``; -1 = the node's
entries continue in a file of its own) and one file per node in ``ept-data/``.
:func:`read_ept` walks the hierarchy down the cubes that meet the area (sub-hierarchy files
fetched only for those), reads those nodes' LAZ files one by one and keeps exactly the points
inside: the same as reading the survey's LAZ tiles and cropping them.  The hierarchy's counts
must add up to ``ept.json``'s ``points``, also in a read of a part of the dataset (the other
hierarchy files are read too, once per dataset and process): a node left out of the
hierarchy or counted 0 would else be missed silently.  Only the ``laszip``
data type is read; ``binary`` and ``zstandard`` datasets are refused in one line.

URLs (``https://``, ``s3://``) go through :mod:`~canopyblocks.readers.remote` (the same
credentials, retries, time-outs and one-line errors as granules).
"""

from __future__ import annotations

import io
import json
import logging
import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from ..errors import FileFormatError
from ..progress import Progress, as_progress
from .copc import Area, Columns, SourceExtent, _check_source, check_crs
from .las_crs import LasCRS, _from_wkt, _laspy
from .remote import StorageError, is_url, open_source, source_label

__all__ = ["ept_extent", "read_ept", "EptInfo", "FETCH_THREADS", "WHOLE_CHECK_FILES"]

log = logging.getLogger(__name__)

#: Node files fetched at once from storage (one batch in memory at a time).
FETCH_THREADS = 8
#: at most this many hierarchy files beyond those a read of a part needs are read to check
#: the whole hierarchy's total (a national survey's EPT has thousands: reading them all for a
#: 13 m corridor would cost more than the corridor)
WHOLE_CHECK_FILES = 64

Node = tuple[int, int, int, int]


class EptInfo:
    """An EPT dataset's ``ept.json``, checked; ``get(rel)`` reads a file of the dataset."""

    def __init__(self, source: str) -> None:
        self.remote = is_url(source)
        text = source.rstrip("/")
        if not text.endswith("ept.json"):
            text = text + "/ept.json"
        self.url = text
        self.label = source_label(text)
        self.base = text[: -len("ept.json")]
        self.nbytes = 0
        meta = self._json("ept.json", "the dataset's description")
        try:
            self.bounds = [float(v) for v in meta["bounds"]]
            conf = [float(v) for v in meta.get("boundsConforming", meta["bounds"])]
            self.n_points = int(meta["points"])
            self.data_type = str(meta["dataType"])
            self.srs = dict(meta.get("srs") or {})
            if len(self.bounds) != 6 or len(conf) != 6:
                raise ValueError("bounds must hold 6 numbers")
        except (KeyError, TypeError, ValueError) as exc:
            raise FileFormatError(
                f"{self.label}: not an EPT description (missing or bad {exc}); give the "
                "ept.json of an Entwine dataset") from None
        self.conforming = (conf[0], conf[1], conf[3], conf[4])
        if self.data_type != "laszip":
            raise FileFormatError(
                f"{self.label}: EPT data type {self.data_type!r} is not supported (only "
                "'laszip'); convert the dataset (e.g. entwine build with dataType laszip) "
                "or read its source tiles")
        self.stated = self._crs()

    def get(self, rel: str, what: str) -> bytes:
        """The bytes of the dataset's file ``rel`` (``ept-data/0-0-0-0.laz``)."""
        where = self.base + rel
        try:
            if self.remote:
                f = open_source(where)
                blob = f.fetch([(0, f.size)])[0] if f.size else b""
            else:
                blob = Path(where).read_bytes()
        except (FileNotFoundError, NotADirectoryError):
            raise FileFormatError(f"{self.label}: {what} {rel} is missing; the dataset is "
                                  "incomplete (copy or download it again)") from None
        except StorageError as exc:
            if "not found (404)" in str(exc):
                raise FileFormatError(f"{self.label}: {what} {rel} is missing (404); the "
                                      "dataset is incomplete (copy or upload it again)") from None
            raise
        except OSError as exc:
            raise FileFormatError(f"cannot read {where}: {exc.strerror or exc}") from None
        self.nbytes += len(blob)
        return blob

    def _json(self, rel: str, what: str) -> dict[str, Any]:
        blob = self.get(rel, what)
        try:
            got = json.loads(blob)
        except ValueError as exc:
            raise FileFormatError(f"{self.base + rel}: not valid JSON ({exc}); the EPT dataset "
                                  "is damaged") from None
        if not isinstance(got, dict):
            raise FileFormatError(f"{self.base + rel}: not a JSON object; the EPT dataset is "
                                  "damaged")
        return got

    def _crs(self) -> LasCRS:
        wkt = self.srs.get("wkt")
        p = Path(self.label)
        if not wkt and self.srs.get("horizontal"):
            auth = self.srs.get("authority", "EPSG")
            code = f"{auth}:{self.srs['horizontal']}"
            if self.srs.get("vertical"):
                code += f"+{self.srs['vertical']}"
            try:
                wkt = pyproj.CRS(code).to_wkt()
            except pyproj.exceptions.CRSError:
                wkt = None
        if not wkt:
            return LasCRS(p, None, None, "unknown", None, None, "none")
        return _from_wkt(p, str(wkt))

    def hierarchy(self, key: Node) -> dict[Node, int]:
        """One hierarchy file's counts."""
        name = "-".join(map(str, key))
        raw = self._json(f"ept-hierarchy/{name}.json", "hierarchy file")
        out: dict[Node, int] = {}
        try:
            for k, v in raw.items():
                d, x, y, z = (int(t) for t in k.split("-"))
                out[(d, x, y, z)] = int(v)
        except (ValueError, TypeError, AttributeError):
            raise FileFormatError(f"{self.base}ept-hierarchy/{name}.json: not an EPT hierarchy "
                                  "(keys D-X-Y-Z, counts); the dataset is damaged") from None
        return out


def ept_extent(source: str | os.PathLike[str]) -> SourceExtent:
    """The extent (``boundsConforming``), CRS and point count of an EPT dataset.

    Parameters
    ----------
    source : path or URL of ``ept.json`` (or of the folder holding it)

    Raises
    ------
    FileFormatError
        Missing or damaged ``ept.json``, unsupported data type, storage failures.
    """
    info = EptInfo(_check_source(source))
    return SourceExtent(info.conforming, info.stated.horizontal, info.n_points, info.label)


def select_nodes(info: EptInfo, area: Area) -> list[tuple[Node, int]]:
    """``(key, count)`` of the nodes whose cubes meet ``area`` (sub-hierarchy files read
    only for cubes that meet it)."""
    counts = info.hierarchy((0, 0, 0, 0))
    if (0, 0, 0, 0) not in counts:
        raise FileFormatError(f"{info.label}: its hierarchy (ept-hierarchy/0-0-0-0.json) has no "
                              "root node 0-0-0-0, so no point can be found; the dataset is "
                              "damaged: write it again")
    b = info.bounds
    out: list[tuple[Node, int]] = []
    todo: list[Node] = [(0, 0, 0, 0)]
    while todo:  # one step per node, not per point
        key = todo.pop()
        n = counts.get(key)
        if n is None:
            continue
        side = (b[3] - b[0]) / (1 << key[0])
        lo = (b[0] + key[1] * side - 0.01, b[1] + key[2] * side - 0.01)
        if not area.meets(lo, (lo[0] + side + 0.02, lo[1] + side + 0.02)):
            continue
        if n == -1:
            del counts[key]
            counts.update(info.hierarchy(key))
            if counts.get(key) == -1:
                raise FileFormatError(f"{info.label}: hierarchy file {'-'.join(map(str, key))} "
                                      "points to itself; the dataset is damaged")
            todo.append(key)
            continue
        if n > 0:
            out.append((key, n))
        d, x, y, z = key
        todo.extend((d + 1, 2 * x + (i & 1), 2 * y + ((i >> 1) & 1), 2 * z + ((i >> 2) & 1))
                    for i in range(8))
    if area.everything:
        _check_total(info, counts)
    else:  # a node left out of the hierarchy or zeroed would be missed silently
        _check_whole(info, counts)
    return sorted(out)


def _check_total(info: EptInfo, counts: dict[Node, int]) -> None:
    """With the whole hierarchy loaded, its counts must add up to ``ept.json``'s."""
    total = sum(n for n in counts.values() if n > 0)
    if -1 not in counts.values() and total != info.n_points:
        raise FileFormatError(f"{info.label}: its hierarchy's nodes hold {total:,} points, "
                              f"ept.json says {info.n_points:,}; the hierarchy is damaged (a "
                              "node is missing from it or miscounted): write the dataset again")


_WHOLE: set[tuple[str, int]] = set()


def _check_whole(info: EptInfo, counts: dict[Node, int]) -> None:
    """The whole hierarchy's total, also in a read of a part of the dataset: the
    hierarchy files not loaded yet are read too (in parallel from storage), once per
    dataset and process, up to :data:`WHOLE_CHECK_FILES` of them (beyond, the check is
    left out and said in the log)."""
    key = (info.url, info.n_points)
    if key in _WHOLE:
        return
    every = dict(counts)
    seen: set[Node] = set()
    with ThreadPoolExecutor(max_workers=FETCH_THREADS if info.remote else 1) as pool:
        while todo := [k for k, n in every.items() if n == -1 and k not in seen]:
            if len(seen) + len(todo) > WHOLE_CHECK_FILES:
                log.info("%s: its hierarchy's total is not checked (more than %d hierarchy "
                         "files beyond those the area needs)", info.label, WHOLE_CHECK_FILES)
                _WHOLE.add(key)
                return
            for k in todo:  # one round per level of hierarchy files (a few)
                del every[k]
                seen.add(k)
            for got in pool.map(info.hierarchy, todo):
                every.update({k: n for k, n in got.items() if k not in seen or n != -1})
    every = {k: n for k, n in every.items() if n != -1}
    _check_total(info, every)
    if len(_WHOLE) > 64:
        _WHOLE.clear()
    _WHOLE.add(key)


def _outside(info: EptInfo, key: Node, las: Any) -> np.ndarray:
    """Which points of node ``key`` lie outside its cube (from ept.json's bounds)."""
    b = info.bounds
    side = (b[3] - b[0]) / (1 << key[0])
    out = np.zeros(len(las.points), dtype=bool)
    for i, v in enumerate((las.x, las.y, las.z)):  # three axes
        lo = b[i] + key[i + 1] * side - 0.01
        a = np.asarray(v)
        out |= (a < lo) | (a > lo + side + 0.02)
    return out


def _check_cube(info: EptInfo, key: Node, las: Any) -> None:
    """Refuse a node file whose points lie outside the node's cube: another node's data
    (they fit in one other cube of the node's level), or ept.json's bounds (the root
    node's points, or a node's points spread over several cubes)."""
    out = _outside(info, key, las)
    if not out.any():
        return
    if key == (0, 0, 0, 0) or not _in_one_cube(info, key[0], las):
        raise FileFormatError(
            f"{info.label}: {int(out.sum()):,} of the {out.size:,} points of node "
            f"ept-data/{'-'.join(map(str, key))}.laz lie outside its cube and do not fit "
            "in any one node's cube: ept.json's bounds "
            f"({', '.join(f'{v:.2f}' for v in info.bounds)}) do not match the node files; "
            "correct ept.json's bounds or write the dataset again")
    raise FileFormatError(
        f"{info.label}: {int(out.sum()):,} of the {out.size:,} points of node "
        f"ept-data/{'-'.join(map(str, key))}.laz lie outside its cube: the file holds "
        "another node's points; the dataset is damaged: write it again")


def _in_one_cube(info: EptInfo, level: int, las: Any) -> bool:
    """Whether the points' extent fits in one cube of ``level`` (within 1 cm)."""
    b = info.bounds
    side = (b[3] - b[0]) / (1 << level)
    for i, v in enumerate((las.x, las.y, las.z)):
        a = np.asarray(v)
        if math.floor((a.min() - b[i] + 0.01) / side) != \
                math.floor((a.max() - b[i] - 0.01) / side):
            return False
    return True


def _node_points(info: EptInfo, key: Node) -> Any:
    name = "-".join(map(str, key))
    blob = info.get(f"ept-data/{name}.laz", "node")
    laspy = _laspy()
    try:
        return laspy.read(io.BytesIO(blob))
    except Exception as exc:  # noqa: BLE001 - laspy/lazrs raise several types
        raise FileFormatError(f"{info.label}: node ept-data/{name}.laz is not readable LAZ "
                              f"({exc}): the file is truncated or damaged; copy or download "
                              "the dataset again") from None


def read_ept(source: str | os.PathLike[str], *, bounds: Sequence[float] | None = None,
             polygon: Any = None, progress: Progress | None = None,
             crs: object = None) -> Any:
    """Read the points of an EPT dataset inside ``bounds`` and/or ``polygon``.

    Parameters
    ----------
    source : path or ``https://``/``s3://`` URL of ``ept.json`` (or its folder)
    bounds : (minx, miny, maxx, maxy), optional
        Metres in the dataset's CRS; edges included.
    polygon : shapely Polygon/MultiPolygon or WKT, optional
        Metres in the dataset's CRS; points on its edge included.
    progress : Progress, optional
        Reports per node; cancellable.
    crs : CRS-like, optional
        The CRS of a dataset that states none (one that states another is refused).

    Returns
    -------
    LasPoints
        Exactly the points inside, node by node; x/y in the dataset's CRS (``srs``), z in
        its vertical datum; ``row`` None.

    Raises
    ------
    FileFormatError
        Missing or damaged ``ept.json``/hierarchy/node, unsupported data type, storage
        failures (one line).
    CRSError
        No CRS stated; a non-metric CRS or heights in feet.
    NoUsableDataError
        No point inside the area.
    """
    area = Area(bounds, polygon)
    prog = as_progress(progress)
    info = EptInfo(_check_source(source))
    crs = check_crs(info.stated, info.label, crs)
    nodes = select_nodes(info, area)
    cols = Columns(info.label)
    total = max(1, sum(n for _, n in nodes))
    done = 0
    step = FETCH_THREADS if info.remote else 1
    with ThreadPoolExecutor(max_workers=step) as pool:
        for i in range(0, len(nodes), step):
            prog.check()
            batch = nodes[i:i + step]
            for (key, n), las in zip(batch, pool.map(lambda k: _node_points(info, k[0]), batch)):
                if len(las.points) != n:
                    raise FileFormatError(
                        f"{info.label}: node ept-data/{'-'.join(map(str, key))}.laz holds "
                        f"{len(las.points):,} points, its hierarchy says {n:,}; the dataset "
                        "is damaged: write it again (or copy or download it again)")
                _check_cube(info, key, las)
                cols.add_arrays(np.asarray(las.x), np.asarray(las.y), np.asarray(las.z),
                                np.asarray(las.classification, dtype=np.uint8),
                                np.asarray(las.return_number, dtype=np.uint8),
                                np.asarray(las.number_of_returns, dtype=np.uint8), area)
                done += n
            prog.update(done / total, f"{info.label}: {done:,} points")
    return cols.points(crs, info.stated.vertical_name, area)
