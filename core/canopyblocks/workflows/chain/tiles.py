"""The airborne tiles of a chain run: their CRS and the name of their vertical datum."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def _vertical_name(crs: Any) -> str | None:
    """The vertical datum's name of a (compound) CRS, e.g. 'CGVD28 height'; None if none."""
    try:
        import pyproj

        c = pyproj.CRS.from_user_input(crs) if crs is not None else None
    except Exception:  # an unreadable CRS only loses the axis label's datum
        return None
    if c is None:
        return None
    for sub in (c.sub_crs_list if c.is_compound else [c]):
        if sub.is_vertical:
            return str(sub.name)
    return None


def _tiles_crs(tiles: Sequence[Any]) -> Any:
    """The tiles' full (compound) CRS as their header states it (WKT or GeoTIFF keys,
    read by the one LAS CRS reader; the first tile stating a vertical datum, whatever their
    order): the vertical datum of every raster made from them, also after reprojection;
    None when unstated."""
    from ...readers.survey import survey_crs
    from ...readers.tile_checks import check_tile_datums

    check_tile_datums(tiles)  # tiles in two vertical datums: refused
    return survey_crs(tiles).crs
