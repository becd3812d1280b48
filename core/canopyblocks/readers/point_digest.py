"""Point identities shared by the survey checks: a 64-bit hash per point (x, y, z to the
millimetre, whatever the file's scale and offset) and a LAS/LAZ reader cheap to open.

Used by :mod:`~canopyblocks.readers.tile_checks` (a copy of a tile with its points in
another order, by an order-free sum of these hashes) and
:mod:`~canopyblocks.readers.cloud_duplicates` (tiles beside a COPC/EPT holding their points).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

__all__ = ["MIX", "mix", "open_reader", "mm_keys", "point_hashes", "file_point_hashes"]

_MM = 1000.0  # coordinates compared to the millimetre


def open_reader(path: Any) -> Any:
    """A laspy reader with the single-threaded LAZ decompressor (the parallel one costs
    about 70 ms to start on a 4 MB tile; a sample needs a few points)."""
    from .las_crs import _laspy

    laspy = _laspy()
    try:
        backend = laspy.LazBackend.Lazrs
        return laspy.open(path, laz_backend=backend) if backend.is_available() \
            else laspy.open(path)
    except AttributeError:  # a laspy without LazBackend
        return laspy.open(path)


MIX = (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBF58476D1CE4E5B9),
       np.uint64(0x94D049BB133111EB))


def mix(v: np.ndarray) -> np.ndarray:
    """A 64-bit finaliser (splitmix64) of each value: a well spread hash per point."""
    v = v ^ (v >> np.uint64(30))
    v = v * MIX[1]
    v = v ^ (v >> np.uint64(27))
    v = v * MIX[2]
    return v ^ (v >> np.uint64(31))


def mm_keys(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(n, 3) int64: each point's x, y, z in whole millimetres."""
    return np.round(np.column_stack([x, y, z]) * _MM).astype(np.int64)


def point_hashes(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """One 64-bit hash per point of (x, y, z) to the millimetre (uint64)."""
    q = mm_keys(x, y, z).view(np.uint64)
    with np.errstate(over="ignore"):
        return mix(mix(mix(q[:, 0] + MIX[0]) ^ q[:, 1]) ^ q[:, 2])


def file_point_hashes(path: Any, chunk: int = 2_000_000) -> Iterator[np.ndarray]:
    """The point hashes of a whole LAS/LAZ file, ``chunk`` points at a time."""
    with open_reader(path) as reader:
        for part in reader.chunk_iterator(chunk):  # a loop over chunks
            yield point_hashes(np.asarray(part.x), np.asarray(part.y), np.asarray(part.z))
