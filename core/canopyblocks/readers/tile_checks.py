"""A survey's tiles checked against each other and against their own headers, cheaply.

* :func:`duplicate_tiles`: the same points given twice (a renamed copy, the same path twice,
  a symlink, a copy with another suffix's case, a crop of another tile) are counted once,
  with a warning naming both files.  Tiles are compared by their content, not their names:
  the number of points, the extent and the first :data:`SAMPLE` points (x, y, z to the
  millimetre, whatever their classes: a reclassified copy holds the same points; one LAZ
  chunk's start, a few milliseconds a tile), as ``batch`` compares granules by their
  photons.  Tiles whose headers agree (count and extent) but whose first points differ (a
  copy with its points in another order) are compared by an order-free digest of all their
  points (read in full only for such pairs).  A tile whose header
  extent lies within another's and whose sampled points are all points of that tile is a
  crop of it (that tile's points are read in full to check; only for nested extents).
* :func:`check_first_points`: a tile skipped by its header extent (it does not meet the
  area) is never decompressed, so a header that lies about where the points are would
  drop the tile without a word.  Its first :data:`SAMPLE` points are read (one LAZ chunk's
  start, a few milliseconds) and must lie within the stated extent; otherwise the tile is
  refused as a decompressed tile with a wrong extent is.  A header that is right about its
  first points but wrong about others is caught only where the tile is decompressed.
* :func:`check_vertical_datums`: tiles that state different vertical datums (e.g. CGVD28
  and CGVD2013) are refused with both tiles named, as tiles in different horizontal CRSs
  are: their heights cannot be mixed in one DTM, and no CRS would be right for it.
"""

from __future__ import annotations

import functools
import hashlib
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CanopyBlocksWarning, CRSError, FileFormatError, NoUsableDataError
from .las_header import plausible_box
from .point_digest import MIX, file_point_hashes, mix, mm_keys, open_reader

__all__ = ["SAMPLE", "duplicate_tiles", "check_first_points", "check_vertical_datums",
           "check_survey_tiles", "vertical_names", "check_tile_datums", "warn_groundless",
           "check_ground_read"]

SAMPLE = 256
"""Points read at the start of a tile for its identity and to check its header extent."""

Box = tuple[float, float, float, float]
_MM = 1000.0  # coordinates compared to the millimetre


def _local(source: object) -> Path | None:
    """``source`` as a local LAS/LAZ path, or None (a URL, COPC, EPT: not compared)."""
    text = str(source)
    if "://" in text:
        return None
    low = text.split("?", 1)[0].rstrip("/").lower()
    if low.endswith((".copc.laz", "ept.json")):
        return None
    p = Path(source)  # type: ignore[arg-type]
    return p if p.is_file() and p.suffix.lower() in (".las", ".laz") else None


def _keys(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """One int64-like key per point (x, y, z to the millimetre), for set membership."""
    return np.ascontiguousarray(mm_keys(x, y, z)).view(np.dtype((np.void, 24))).ravel()


class _Tile:
    """A tile's header facts and its sampled points."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.digest: str | None = None
        self.header: tuple[int, ...] | None = None
        self.box: Box | None = None
        self.n = 0
        self.first = np.empty(0, np.dtype((np.void, 24)))
        self.xy = np.empty((0, 2))
        try:
            with open_reader(path) as reader:
                h = reader.header
                self.n = int(h.point_count)
                self.box = (float(h.mins[0]), float(h.mins[1]), float(h.maxs[0]),
                            float(h.maxs[1]))
                head = reader.read_points(min(SAMPLE, self.n))
                ext = np.r_[np.asarray(h.mins, float), np.asarray(h.maxs, float)]
        except Exception:  # noqa: BLE001 - an unreadable tile is reported by its reader
            return
        digest = hashlib.sha1(f"{self.n};".encode())
        digest.update(np.round(ext * _MM).astype(np.int64).tobytes())
        digest.update(_keys(np.asarray(head.x), np.asarray(head.y), np.asarray(head.z)).tobytes())
        self.digest = digest.hexdigest()
        self.header = (self.n, *np.round(ext * _MM).astype(np.int64).tolist())
        self.first = _keys(np.asarray(head.x), np.asarray(head.y), np.asarray(head.z))
        self.xy = np.c_[np.asarray(head.x, float), np.asarray(head.y, float)]


def _sample(path: Path) -> _Tile:
    """The tile's sample, read once per file version (size, modification time)."""
    try:
        st = os.stat(path)
    except OSError:
        return _Tile(path)  # an empty sample: the tile's reader reports it
    return _cached_sample(str(path), st.st_size, st.st_mtime_ns)


def _order_free(path: Path) -> tuple[int, int, int] | None:
    """A digest of all the tile's points that does not depend on their order (the count
    and two wrapping sums of per-point hashes), read once per file version."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return _cached_order_free(str(path), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=256)
def _cached_order_free(path: str, size: int, mtime: int  # noqa: ARG001 - cache keys
                       ) -> tuple[int, int, int] | None:
    n, s1, s2 = 0, np.uint64(0), np.uint64(0)
    try:
        for h in file_point_hashes(path):
            with np.errstate(over="ignore"):
                s1 = s1 + h.sum(dtype=np.uint64)
                s2 = s2 + mix(h ^ MIX[0]).sum(dtype=np.uint64)
            n += h.size
    except Exception:  # noqa: BLE001 - an unreadable tile is reported by its reader
        return None
    return n, int(s1), int(s2)


def _same_content(a: Path, b: Path) -> bool:
    """Whether two tiles hold the same points, in whatever order (full reads of both)."""
    da = _order_free(a)
    return da is not None and da == _order_free(b)


@functools.lru_cache(maxsize=4096)
def _cached_sample(path: str, size: int, mtime: int) -> _Tile:  # noqa: ARG001 - cache keys
    return _Tile(Path(path))


def duplicate_tiles(sources: Sequence[Any]) -> tuple[list[Any], list[tuple[Any, Any, str]]]:
    """``sources`` without the tiles whose points an earlier tile already holds.

    Parameters
    ----------
    sources : sequence of paths (or URLs, COPC/EPT sources: kept as they are)

    Returns
    -------
    kept : list
        The sources in their order, each set of points once.
    dropped : list of (source, same_as, why)
        Each tile left out, the source kept instead and why ("same file", "same points",
        "reordered", "part of", "in cloud": all its points are a kept COPC/EPT's, see
        :mod:`~canopyblocks.readers.cloud_duplicates`); a
        :class:`~canopyblocks.errors.CanopyBlocksWarning` names each.

    Raises
    ------
    InputError
        A tile sharing some, not all, of its points with a COPC/EPT source given too.
    """
    kept: list[Any] = []
    dropped: list[tuple[Any, Any, str]] = []
    seen_files: dict[tuple[int, int], Any] = {}
    seen_digest: dict[str, Any] = {}
    seen_header: dict[tuple[int, ...], list[tuple[Path, Any]]] = {}
    tiles: list[_Tile] = []
    for src in sources:  # a loop over tiles (a few reads each), not over points
        p = _local(src)
        if p is None:
            kept.append(src)
            continue
        st = os.stat(p)
        ident = (st.st_dev, st.st_ino)
        if ident in seen_files:
            dropped.append((src, seen_files[ident], "same file"))
            continue
        t = _sample(p)
        if t.digest is not None and t.digest in seen_digest:
            dropped.append((src, seen_digest[t.digest], "same points"))
            continue
        twin = next((s for q, s in seen_header.get(t.header or (), []) if _same_content(p, q)),
                    None)  # the same header, other first points: the same points reordered?
        if twin is not None:
            dropped.append((src, twin, "reordered"))
            continue
        seen_files[ident] = src
        if t.digest is not None:
            seen_digest[t.digest] = src
        if t.header is not None:
            seen_header.setdefault(t.header, []).append((p, src))
        tiles.append(t)
        kept.append(src)
    for t, big in _crops(tiles):
        kept = [k for k in kept if k is not t.path and str(k) != str(t.path)]
        dropped.append((t.path, big.path, "part of"))
    from .cloud_duplicates import tiles_in_clouds

    for src, cloud in tiles_in_clouds(kept, tiles):
        kept = [k for k in kept if k is not src and str(k) != str(src)]
        dropped.append((src, cloud, "in cloud"))
    for src, same, why in dropped:
        warnings.warn(_message(src, same, why), CanopyBlocksWarning, stacklevel=2)
    return kept, dropped


def _message(src: Any, same: Any, why: str) -> str:
    if why == "same file":
        return f"{src} is given twice (the same file as {same}): read once"
    if why == "same points":
        return (f"{src} holds the same points as {same} (the same count, extent and "
                f"coordinates): a copy, counted once, as {same}")
    if why == "reordered":
        return (f"{src} holds the same points as {same} in another order (the same count, "
                f"extent and coordinates): a copy, counted once, as {same}")
    if why == "in cloud":
        return (f"{src}: every one of its points is a point of {same}, given too: the tile is "
                f"left out so that no point is counted twice (give the tiles or {same}, not "
                "both)")
    return (f"{src} holds a part of the points of {same} (its extent lies within that "
            f"tile's and the {SAMPLE} points sampled from it are all points of that tile): a "
            f"crop of it, left out so that no point is counted twice")


def _crops(tiles: list[_Tile]) -> list[tuple[_Tile, _Tile]]:
    """(crop, tile) pairs: a tile with fewer points, nested extent, sample all in the tile."""
    good = [t for t in tiles if t.box is not None and t.first.size]
    if len(good) < 2:
        return []
    boxes = np.asarray([t.box for t in good], dtype=np.float64)
    out: list[tuple[_Tile, _Tile]] = []
    gone: set[int] = set()
    for i, t in enumerate(good):  # a loop over tiles, vectorised over the other boxes
        inside = ((boxes[:, 0] <= boxes[i, 0] + 1e-3) & (boxes[:, 1] <= boxes[i, 1] + 1e-3)
                  & (boxes[:, 2] >= boxes[i, 2] - 1e-3) & (boxes[:, 3] >= boxes[i, 3] - 1e-3))
        inside[i] = False
        for j in np.flatnonzero(inside):
            big = good[j]
            if j in gone or big.n <= t.n:
                continue
            if _all_within(t.first, big.path):
                out.append((t, big))
                gone.add(i)
                break
    return out


def _all_within(sample: np.ndarray, path: Path) -> bool:
    """Whether every sampled point key is a point of the tile at ``path`` (one pass)."""
    from .las_crs import _laspy

    todo = np.unique(sample)
    try:
        with _laspy().open(path) as reader:
            for chunk in reader.chunk_iterator(2_000_000):
                k = _keys(np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z))
                todo = todo[~np.isin(todo, k)]
                if todo.size == 0:
                    return True
    except Exception:  # noqa: BLE001 - an unreadable tile is reported by its reader
        return False
    return todo.size == 0


def check_first_points(path: str | os.PathLike[str], header: Box, tolerance: float) -> None:
    """Refuse a tile whose first points lie outside its header's extent.

    Raises
    ------
    FileFormatError
        Naming the tile, the stated extent and where its first points lie.
    """
    xy = _sample(Path(path)).xy
    if xy.size == 0:
        return
    x, y = xy[:, 0], xy[:, 1]
    out = ((x < header[0] - tolerance) | (x > header[2] + tolerance)
           | (y < header[1] - tolerance) | (y > header[3] + tolerance))
    if not out.any():
        return
    h = header
    raise FileFormatError(
        f"{path}: its header says the points lie in ({h[0]:.2f}, {h[1]:.2f}, {h[2]:.2f}, "
        f"{h[3]:.2f}) but {int(out.sum())} of its first {x.size} points lie outside, in "
        f"({x.min():.2f}, {y.min():.2f}, {x.max():.2f}, {y.max():.2f}): the tile would be "
        "skipped or placed by a wrong extent; rewrite the file with a LAS tool (e.g. las2las "
        "or PDAL) after checking where it should be")


def check_tile_headers(sources: Sequence[Any], tolerance: float = 1.0) -> None:
    """:func:`check_first_points` for every local LAS/LAZ tile of a survey, against its own
    header's extent (the sample :func:`duplicate_tiles` read, so no tile is opened twice):
    every door that reads a survey refuses a tile its header misplaces, not only ``rasters``.
    URLs and COPC/EPT sources are left to their readers."""
    for src in sources:  # a loop over tiles: their cached samples
        p = _local(src)
        if p is None:
            continue
        t = _sample(p)
        if t.box is not None and t.n > 0 and plausible_box(t.box):  # else fixed where read
            check_first_points(p, t.box, tolerance)



def check_survey_tiles(tiles: Sequence[tuple[Any, Box]], tolerance: float) -> None:
    """The checks of a survey's LAS/LAZ tiles before any is read in full: each tile's first
    points within its header extent (:func:`check_first_points`, ``tolerance`` metres) and
    one vertical datum for all (:func:`check_vertical_datums`)."""
    for path, box in tiles:  # a loop over tiles: one small read each
        check_first_points(path, box, tolerance)
    paths = [p for p, _ in tiles]
    check_vertical_datums(paths, vertical_names(paths))


def check_tile_datums(paths: Sequence[Any]) -> None:
    """Refuse local LAS/LAZ tiles stating different vertical datums (URLs and COPC/EPT
    sources are left to their readers); for ``run``'s and ``batch``'s tile lists."""
    local = [p for p in paths if _local(p) is not None]
    check_vertical_datums(local, vertical_names(local), warn=False)


def vertical_names(paths: Sequence[Any]) -> list[str]:
    """Each tile's stated vertical datum for a message (``"EPSG:5713 (CGVD28 height)"``;
    "unknown" when it states none)."""
    from .las_crs import las_file_crs

    stated = [las_file_crs(p) for p in paths]
    return [s.vertical_name if s.vertical is None or s.vertical_name == s.vertical.name
            else f"{s.vertical_name} ({s.vertical.name})" for s in stated]


def check_vertical_datums(paths: Sequence[Any], names: Sequence[str], *,
                          warn: bool = True) -> None:
    """Refuse tiles that state different vertical datums (``names``: each tile's,
    "unknown" when it states none); warn when some state one and others none: those are
    taken to be in the stated datum, which the survey's rasters declare whatever the tiles'
    order (:func:`~canopyblocks.readers.survey.survey_crs`).

    Raises
    ------
    CRSError
        Naming a tile of each datum.
    """
    first: dict[str, Any] = {}
    for p, n in zip(paths, names):
        first.setdefault(n or "unknown", p)
    known = {n: p for n, p in first.items() if n != "unknown"}
    if len(known) > 1:
        (a, pa), (b, pb) = list(known.items())[:2]
        raise CRSError(
            f"tiles state different vertical datums: {pa} heights in {a}, {pb} in {b}; their "
            "heights cannot be mixed in one DTM: convert the tiles to one vertical datum "
            "(e.g. PDAL filters.reprojection with a compound CRS) or give only the tiles of "
            "one datum")
    if warn and known and "unknown" in first:
        (a, pa), = known.items()
        none = [str(p) for p, n in zip(paths, names) if (n or "unknown") == "unknown"]
        which = none[0] if len(none) == 1 else f"{none[0]} and {len(none) - 1} more tile(s)"
        warnings.warn(
            f"{which} states no vertical datum, {pa} states {a}: its heights are taken to be "
            f"in {a} too (the rasters declare it); if they are in another datum, convert the "
            "tile to it first (a tile in another datum would shift the DTM)",
            CanopyBlocksWarning, stacklevel=3)


def warn_groundless(path: Any, held: str, consequence: str, fix: str) -> None:
    """The warning for a tile holding points but no ground point (class 2) among tiles that
    have ground (``held``: e.g. "823,945 points"): what it costs and what to do."""
    warnings.warn(
        f"tile {path} holds {held} but no ground point (ASPRS class 2) while the other tiles "
        f"have ground: {consequence}; {fix}", CanopyBlocksWarning, stacklevel=3)


def check_ground_read(pts: Any, where: str, ground_class: int = 2) -> None:
    """Check the ground of a survey's points read ``where`` (e.g. "under the footprints"):
    refuse when none is ground; warn, naming it, for each tile read with points there but
    no ground point while others have (its footprints get no ground reference).

    ``pts``: :class:`~canopyblocks.readers.las.LasPoints` (per tile only when its ``row``
    is known, i.e. LAS/LAZ tiles alone).

    Raises
    ------
    NoUsableDataError
        No point read is ground.
    """
    if len(pts) == 0:
        return
    ground = np.asarray(pts.classification) == ground_class
    names = ", ".join(map(str, pts.sources[:4])) + (
        f" and {len(pts.sources) - 4} more" if len(pts.sources) > 4 else "")
    if not ground.any():
        raise NoUsableDataError(
            f"no point of {names} {where} is classed ground (ASPRS class {ground_class}): the "
            "tiles are unclassified there; classify their ground (e.g. PDAL filters.smrf) and "
            "validate again")
    if pts.row is None or len(pts.sources) < 2:
        return
    edges = np.cumsum([_sample(Path(p)).n for p in pts.sources])
    tile = np.searchsorted(edges, np.asarray(pts.row), side="right")
    n_read = np.bincount(tile, minlength=edges.size)
    n_ground = np.bincount(tile[ground], minlength=edges.size)
    for i in np.flatnonzero((n_read > 0) & (n_ground == 0)):  # a loop over groundless tiles
        warn_groundless(pts.sources[i], f"{int(n_read[i]):,} points {where}",
                        "the blocks or footprints over it have no ground reference (left out "
                        "as 'reference nodata')", "classify its ground (e.g. PDAL filters.smrf)")
