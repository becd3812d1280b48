"""The survey argument of every command, and the CRS a run works in over it.

:func:`~canopyblocks.workflows.rasters.survey_tiles` is the one resolver of ``run``,
``validate --points``, ``batch --tiles``, ``calibrate --points``, ``rasters`` and the QGIS
algorithms: files, folders, glob patterns, a ``.vpc``, a COPC
file or an EPT dataset, local or by URL (:mod:`canopyblocks.readers.survey`).
:func:`working_crs` is the CRS a run over a survey computes in: the survey's own when its
metre is a ground metre, else the UTM zone of the survey's centre (a survey in Web
Mercator, EPSG:3857, as USGS 3DEP's EPT is, is reprojected, never used as metres).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["working_crs", "survey_centre"]


def survey_centre(tiles: Sequence[Any]) -> tuple[float, float]:
    """Longitude and latitude (degrees) of the centre of the first source's extent."""
    import pyproj

    from ..errors import CRSError
    from ..readers.survey import source_extent

    b, crs = source_extent(tiles[0])
    if crs is None:
        raise CRSError(f"{tiles[0]}: the source states no CRS; give its CRS")
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(
        0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3]))
    return float(lon), float(lat)


def working_crs(tiles: Sequence[Any]) -> Any:
    """The horizontal CRS a run over the survey computes in: the survey's own when its
    metre is a ground metre (:func:`~canopyblocks.geo.ground_metres`), else the UTM
    zone of the survey's centre; None when the survey states no CRS.  A survey in feet is
    refused here, before any word of a working CRS (its feet are not converted)."""
    from ..geo import ground_metres, utm_crs_for
    from ..readers.survey import source_crs

    stated = source_crs(tiles[0])
    stated.require_metres()  # CRSError: positions or heights in feet
    crs = stated.horizontal
    if crs is None or ground_metres(crs):
        return crs
    lon, lat = survey_centre(tiles)
    return utm_crs_for(lon, lat)
