"""Corridor polygons along the track, one per block (DESIGN 2.2).

A block's corridor is the piece of the track line between the block's ``s_start`` and
``s_end``, buffered by ``width / 2`` on each side with flat ends.  The track line is
either given (a LineString whose arc length is ``s``, offset by ``line_s0``) or built
from the block centres themselves: per ``(track, length)``, the centres ordered by
``s_mid = (s_start + s_end) / 2`` form a polyline. A block centre is the mean position
of its photons, which lies at the photons' mean along-track distance, not at ``s_mid``
(photons bunched at one end of a block move it by up to half a block). So each node is
parametrised by its true along-track position: the arc length along the polyline, plus
one constant per track fitted so that the nodes' ``s`` match ``s_mid`` on average. A
bunched block then no longer drags its corridor (nor its neighbours'), and corridors are
as long as their blocks. Positions at any ``s`` are interpolated linearly between nodes
and extrapolated linearly beyond the first/last node.

Geometry facts (tested):

* straight track: each polygon is a ``width`` x ``length`` rectangle, area exactly
  ``width * length``, ends perpendicular to the track;
* adjacent blocks share their end edge without overlap.  With the polyline through
  the block centres, a block edge always falls on the segment between two
  consecutive centres, so both neighbours cut it perpendicular to that same
  segment: the shared edge is exact even on curved tracks (up to float round-off);
* on a curved track the polygon bends at its own centre (mitre join), so its area
  differs from ``width * length`` by a term of order ``width**2 * turn angle``;
  on the inside of very sharp bends (radius < width / 2) the buffer folds and
  neighbouring polygons may overlap slightly.  With a given ``track_line`` whose
  vertices fall inside blocks, the same holds; its pieces are clamped at the
  line's ends (no extrapolation).
"""

from __future__ import annotations

import logging

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely
from shapely.geometry import LineString
from shapely.ops import substring

from ..errors import CRSError, InputError
from .sensor_width import corridor_width

__all__ = ["block_corridors", "track_polyline", "positions_at", "CORRIDOR_ID_COLUMNS"]

log = logging.getLogger(__name__)

#: Columns copied from the block table onto each corridor polygon.
CORRIDOR_ID_COLUMNS: tuple[str, ...] = ("track", "length", "block", "s_start", "s_end")


def _require_columns(blocks: pd.DataFrame, cols: tuple[str, ...], what: str) -> None:
    missing = [c for c in cols if c not in blocks.columns]
    if missing:
        raise InputError(
            f"{what} lacks column(s) {', '.join(missing)}; pass a block table from "
            "compute_blocks / read_blocks"
        )


def track_polyline(blocks: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """The polyline through the block centres of ONE track and block length.

    Parameters
    ----------
    blocks : DataFrame
        Rows of one ``(track, length)``, columns ``s_start``, ``s_end``, ``x``, ``y``
        (metres, metric CRS).  Rows with non-finite centres are ignored.

    Returns
    -------
    s : ndarray (n,)
        Strictly increasing node parameters, metres: the arc length along the polyline
        through the centres (in ``s_mid`` order) plus the constant that makes their mean
        equal the mean ``s_mid`` (see the module notes).
    xy : ndarray (n, 2)
        Node positions, metres.

    Raises
    ------
    InputError
        Fewer than two distinct finite block centres (no direction to follow).
    """
    s = 0.5 * (blocks["s_start"].to_numpy(float) + blocks["s_end"].to_numpy(float))
    x = blocks["x"].to_numpy(float)
    y = blocks["y"].to_numpy(float)
    ok = np.isfinite(s) & np.isfinite(x) & np.isfinite(y)
    s, x, y = s[ok], x[ok], y[ok]
    s_u, first = np.unique(s, return_index=True)
    if s_u.size < 2:
        raise InputError(
            f"cannot draw corridors: {s_u.size} usable block centre(s) in this track/length; "
            "at least 2 are needed to follow the track, or pass track_line="
        )
    xy = np.column_stack([x[first], y[first]])
    chord = np.hypot(*np.diff(xy, axis=0).T)
    keep = np.concatenate([[True], chord > 0])  # two blocks with one centre: keep the first
    xy, s_u = xy[keep], s_u[keep]
    if s_u.size < 2:
        raise InputError(
            "cannot draw corridors: all usable block centres of this track/length coincide; "
            "at least 2 distinct ones are needed to follow the track, or pass track_line="
        )
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    return arc + float(np.mean(s_u - arc)), xy


def positions_at(s_nodes: np.ndarray, xy_nodes: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Positions (metres) at along-track ``s`` on the polyline ``(s_nodes, xy_nodes)``.

    Linear interpolation between nodes, linear extrapolation beyond the ends.
    """
    s = np.asarray(s, dtype=float)
    seg = np.clip(np.searchsorted(s_nodes, s, side="right") - 1, 0, s_nodes.size - 2)
    s0, s1 = s_nodes[seg], s_nodes[seg + 1]
    t = (s - s0) / (s1 - s0)
    p0, p1 = xy_nodes[seg], xy_nodes[seg + 1]
    return p0 + (p1 - p0) * t[..., None]


def _pieces_from_nodes(s_nodes: np.ndarray, xy_nodes: np.ndarray, s_start: np.ndarray,
                       s_end: np.ndarray) -> list[LineString]:
    a = positions_at(s_nodes, xy_nodes, s_start)
    b = positions_at(s_nodes, xy_nodes, s_end)
    lo = np.searchsorted(s_nodes, s_start, side="right")  # first node strictly inside
    hi = np.searchsorted(s_nodes, s_end, side="left")     # one past the last inside
    lines = []
    for i in range(s_start.size):  # loop over blocks: each piece has its own vertex count
        inner = xy_nodes[lo[i]:hi[i]]
        lines.append(LineString(np.vstack([a[i:i + 1], inner, b[i:i + 1]])))
    return lines


def _pieces_from_line(line: LineString, line_s0: float, s_start: np.ndarray,
                      s_end: np.ndarray) -> list[LineString]:
    out = []
    for a, b in zip(s_start - line_s0, s_end - line_s0):
        piece = substring(line, float(a), float(b))
        if not isinstance(piece, LineString) or piece.length == 0:
            raise InputError(
                f"track_line (length {line.length:.1f} m, s0 {line_s0:g} m) does not reach "
                f"the block s {a + line_s0:.1f}..{b + line_s0:.1f} m; give a line covering "
                "the whole track"
            )
        out.append(piece)
    return out


def block_corridors(blocks: pd.DataFrame, *, width: float | None = None,
                    track_line: LineString | None = None,
                    line_s0: float = 0.0) -> gpd.GeoDataFrame:
    """One corridor polygon per block, cut at the block edges.

    Parameters
    ----------
    blocks : GeoDataFrame
        Block table (``canopyblocks.schema.BLOCK_COLUMNS``), centres ``x``/``y`` in the
        track's metric CRS (the GeoDataFrame's CRS).
    width : float, optional
        Full corridor width, metres; default the footprint of the blocks' sensor
        (:func:`~canopyblocks.reference.sensor_width.corridor_width`: ICESat-2 13 m, MABEL
        2 m, known from the ``track`` ids); tracks of no known sensor need it.
    track_line : LineString, optional
        The track line in the blocks' CRS.  Its arc length plus ``line_s0`` is ``s``.
        Default: the polyline through the block centres (see module notes).
    line_s0 : float
        ``s`` at the first vertex of ``track_line``, metres.

    Returns
    -------
    GeoDataFrame
        Columns ``track, length, block, s_start, s_end`` and polygon ``geometry`` in the
        blocks' CRS; same index and order as ``blocks``.

    Raises
    ------
    InputError
        Bad width, missing columns, fewer than 2 block centres per track and length
        without ``track_line``, or ``track_line`` not reaching a block.
    """
    from ..arguments import check_frame
    check_frame(blocks, "block_corridors: blocks", "a block table (DataFrame)")
    _require_columns(blocks, CORRIDOR_ID_COLUMNS, "the block table")
    if width is not None:
        width = float(width)
    width = corridor_width(width, pd.unique(blocks["track"].astype(str)),
                           source="the block table")
    crs = getattr(blocks, "crs", None)
    if crs is not None and not crs.is_projected:
        raise CRSError(
            f"the block table's CRS {crs.to_string()} is not projected; corridors need the "
            "track's metric CRS"
        )
    s_start = blocks["s_start"].to_numpy(float)
    s_end = blocks["s_end"].to_numpy(float)
    bad = ~(np.isfinite(s_start) & np.isfinite(s_end) & (s_end > s_start))
    if bad.any():
        raise InputError(
            f"{int(bad.sum())} block(s) have no valid s range (s_end must exceed s_start); "
            "check the block table"
        )
    lines: list[LineString | None] = [None] * len(blocks)
    if track_line is not None:
        if not isinstance(track_line, LineString) or track_line.is_empty:
            raise InputError("track_line must be a non-empty shapely LineString")
        for k, ln in enumerate(_pieces_from_line(track_line, float(line_s0), s_start, s_end)):
            lines[k] = ln
    else:
        _require_columns(blocks, ("x", "y"), "the block table")
        pos = np.arange(len(blocks))
        keys = blocks[["track", "length"]].reset_index(drop=True)
        for _, idx in keys.groupby(["track", "length"], sort=False).groups.items():
            rows = pos[np.asarray(idx)]
            s_nodes, xy_nodes = track_polyline(blocks.iloc[rows])
            pieces = _pieces_from_nodes(s_nodes, xy_nodes, s_start[rows], s_end[rows])
            for r, ln in zip(rows, pieces):
                lines[r] = ln
    polys = shapely.buffer(np.array(lines, dtype=object), width / 2.0,
                           cap_style="flat", join_style="mitre")
    out = gpd.GeoDataFrame(
        pd.DataFrame({c: blocks[c].to_numpy() for c in CORRIDOR_ID_COLUMNS}, index=blocks.index),
        geometry=polys, crs=crs,
    )
    return out
