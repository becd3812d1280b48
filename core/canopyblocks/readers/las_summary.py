"""What a LAS/LAZ file's points say about themselves: extent, count, noise share.

The header's extent and count may lie (damaged or hand-edited files); the points do not.
One streaming pass over the integer coordinates (no float copies of the cloud) gives the
true extent, the number of points and how many are classed noise (ASPRS 7 and 18).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DependencyError, FileFormatError
from .cloud_checks import HeightTally
from .las_header import check_las_file, check_nothing_beyond_count, points_unreadable

__all__ = ["LasSummary", "las_summary", "NOISE_CLASSES"]

NOISE_CLASSES = (7, 18)
"""ASPRS low noise and high noise."""

_CHUNK = 2_000_000


@dataclass(frozen=True)
class LasSummary:
    """Extent and counts of one LAS/LAZ file, from its points.

    Attributes
    ----------
    path : Path
    bounds : (xmin, ymin, xmax, ymax)
        Metres in the file's CRS (NaN when the file holds no point).
    z_range : (zmin, zmax)
        Metres.
    n_points, n_noise, n_ground : int
        All points, points of classes 7/18, points of class 2.
    header_bounds : (xmin, ymin, xmax, ymax)
        What the header states.
    """

    path: Path
    bounds: tuple[float, float, float, float]
    z_range: tuple[float, float]
    n_points: int
    n_noise: int
    n_ground: int
    header_bounds: tuple[float, float, float, float]



def _laspy() -> Any:
    try:
        import laspy
    except ImportError:
        raise DependencyError("reading LAS/LAZ needs laspy (and lazrs for LAZ)") from None
    return laspy


def las_summary(path: str | os.PathLike[str]) -> LasSummary:
    """Read every point's integer coordinates and class once; see :class:`LasSummary`.

    Raises
    ------
    FileFormatError
        A damaged or truncated file (see :func:`~canopyblocks.readers.las_header.check_las_file`).
    NoUsableDataError
        Terrain outside the heights a survey on Earth can have
        (:class:`~canopyblocks.readers.cloud_checks.HeightTally`).
    """
    laspy = _laspy()
    p = Path(path)
    if not p.exists():
        raise FileFormatError(f"{p}: file does not exist")
    check_las_file(p)
    lo = np.full(3, np.iinfo(np.int64).max)
    hi = np.full(3, np.iinfo(np.int64).min)
    n = n_noise = n_ground = count = 0
    heights = HeightTally()
    try:
        with laspy.open(p) as reader:
            h = reader.header
            count = int(h.point_count)
            scale = np.asarray(h.scales, float)
            offset = np.asarray(h.offsets, float)
            hb = (float(h.mins[0]), float(h.mins[1]), float(h.maxs[0]), float(h.maxs[1]))
            for chunk in reader.chunk_iterator(_CHUNK):
                if len(chunk) == 0:
                    continue
                for k, name in enumerate("XYZ"):
                    a = np.asarray(chunk[name])
                    lo[k] = min(lo[k], int(a.min()))
                    hi[k] = max(hi[k], int(a.max()))
                c = np.asarray(chunk.classification)
                heights.add_scaled(np.asarray(chunk["Z"]), c, float(scale[2]), float(offset[2]))
                n += c.size
                n_noise += int(np.isin(c, NOISE_CLASSES).sum())
                n_ground += int(np.count_nonzero(c == 2))
            check_nothing_beyond_count(reader, p, n)
    except FileFormatError:
        raise
    except Exception as exc:  # laspy/lazrs raise several types on damaged data
        raise points_unreadable(p, exc, count) from None
    heights.check(str(p))
    if n == 0:
        nan = float("nan")
        return LasSummary(p, (nan, nan, nan, nan), (nan, nan), 0, 0, 0, hb)
    mn = lo * scale + offset
    mx = hi * scale + offset
    return LasSummary(p, (float(mn[0]), float(mn[1]), float(mx[0]), float(mx[1])),
                      (float(mn[2]), float(mx[2])), n, n_noise, n_ground, hb)
