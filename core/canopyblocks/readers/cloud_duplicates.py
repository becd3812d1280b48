"""LAS/LAZ tiles given beside a COPC file or EPT dataset that already holds their points.

A COPC or EPT source is often made from a survey's tiles; given together (``run tiles/
survey.copc.laz``) every point would count twice.  Only a tile whose header extent
overlaps the cloud's is looked at (a survey of tiles alone, or a cloud alone, costs
nothing; tiles beside a cloud of other places cost one header read of the cloud): the
cloud's points where both lie are read (by bounds: the nodes there), and, if there are
any, the tile's points in full, and compared point by point (x, y, z to the millimetre,
whatever their order).  A tile all of whose points are the cloud's is left out, with a
warning naming both; a tile sharing only some of its points with the cloud cannot be
counted exactly and is refused, naming both sources.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, NoUsableDataError

__all__ = ["tiles_in_clouds"]

Box = tuple[float, float, float, float]
_PAD = 1e-3  # metres around a box read from a cloud (points on its edge included)


def _cloud_box(src: Any) -> Box | None:
    from .survey import source_kind

    if source_kind(src) == "copc":
        from .copc import copc_extent as extent
    else:
        from .ept import ept_extent as extent
    b = extent(src).bounds
    return (float(b[0]), float(b[1]), float(b[2]), float(b[3]))


def _cloud_hashes(src: Any, box: Box) -> np.ndarray:
    """The point hashes of a cloud's points inside ``box`` (padded), sorted."""
    from .point_digest import point_hashes
    from .survey import source_kind

    if source_kind(src) == "copc":
        from .copc import read_copc as read
    else:
        from .ept import read_ept as read
    pad = (box[0] - _PAD, box[1] - _PAD, box[2] + _PAD, box[3] + _PAD)
    try:
        pts = read(src, bounds=pad)
    except NoUsableDataError:
        return np.empty(0, np.uint64)
    return np.sort(point_hashes(pts.x, pts.y, pts.z))


def _tile_hashes(path: Path) -> np.ndarray:
    """Every point hash of a tile (read in full: only for a tile found in a cloud)."""
    from .point_digest import file_point_hashes

    parts = list(file_point_hashes(path))
    return np.concatenate(parts) if parts else np.empty(0, np.uint64)


def _found(h: np.ndarray, sorted_cloud: np.ndarray) -> np.ndarray:
    """Which of the hashes ``h`` are among ``sorted_cloud`` (vectorised search)."""
    if sorted_cloud.size == 0:
        return np.zeros(h.size, bool)
    i = np.minimum(np.searchsorted(sorted_cloud, h), sorted_cloud.size - 1)
    return sorted_cloud[i] == h


def _overlap(a: Box, b: Box) -> Box | None:
    """The box two boxes share (None when they only touch or are apart)."""
    box = (max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3]))
    return box if box[0] < box[2] and box[1] < box[3] else None


def tiles_in_clouds(kept: Sequence[Any], tiles: Sequence[Any]) -> list[tuple[Any, Any]]:
    """(tile, cloud) pairs: the kept local tiles (``tiles``: their
    :class:`~canopyblocks.readers.tile_checks._Tile` samples) all of whose points a kept
    COPC/EPT source holds; to be left out.

    Raises
    ------
    InputError
        A tile that shares some, not all, of its points with a cloud, naming both.
    """
    from .survey import source_kind

    clouds = [s for s in kept if source_kind(s) in ("copc", "ept")]
    names = {str(k) for k in kept}
    mine = [t for t in tiles if str(t.path) in names and t.box is not None and t.n > 0]
    if not clouds or not mine:
        return []
    out: list[tuple[Any, Any]] = []
    for cloud in clouds:  # a loop over sources, each test vectorised over points
        cbox = _cloud_box(cloud)
        for t in mine:
            both = None if cbox is None else _overlap(t.box, cbox)
            if both is None or any(t is d for d, _ in out):
                continue
            there = _cloud_hashes(cloud, both)
            if there.size == 0:  # the cloud has no point where the tile lies
                continue
            whole = _tile_hashes(t.path)
            shared = int(_found(whole, there).sum())
            if shared == 0:
                continue
            if shared == whole.size:
                out.append((t, cloud))
                continue
            raise InputError(
                f"{t.path} and {cloud} share points ({shared:,} of the tile's {whole.size:,} "
                f"points are points of {cloud}), but not all of them, so no point could be "
                f"counted exactly once: give the tiles or {cloud}, not both")
    return [(next(k for k in kept if str(k) == str(t.path)), c) for t, c in out]
