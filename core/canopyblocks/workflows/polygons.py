"""The ``--polygon`` of the front doors: WKT text, a file holding WKT, or a vector file in
any CRS, checked to be a valid polygon and brought to the CRS of the work.

``rasters.read_polygon`` and ``blocks_granules.read_polygon`` read their option through
:func:`polygon_geometry`; :func:`require_valid` is the one validity check of both.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any

from ..errors import CanopyBlocksWarning, InputError

__all__ = ["polygon_geometry", "require_valid", "MAX_WKT_FILE"]

#: A polygon file this small is looked at for WKT text before it is read as a vector file.
MAX_WKT_FILE = 1 << 24
_WKT_WORDS = ("POLYGON", "MULTIPOLYGON")


def require_valid(geom: Any, name: str) -> Any:
    """``geom`` when it is a valid, non-empty polygon; else the project's refusal naming
    ``name`` and why (e.g. a self-intersecting ring: a bow tie has no one inside)."""
    import shapely
    from shapely.validation import explain_validity

    if geom is None or geom.is_empty or geom.geom_type not in ("Polygon", "MultiPolygon"):
        raise InputError(f"--polygon {name}: not a polygon ({getattr(geom, 'geom_type', geom)}"
                         "); give a polygon or multipolygon")
    if not shapely.is_valid(geom):
        raise InputError(f"--polygon {name}: the polygon is not valid ({explain_validity(geom)}"
                         "): which side is inside cannot be told; correct it (e.g. QGIS 'Fix "
                         "geometries', or split a bow tie into two polygons)")
    return geom


def _wkt(text: str, name: str) -> Any:
    import shapely

    try:
        geom = shapely.from_wkt(text)
    except shapely.errors.GEOSException as exc:
        raise InputError(f"--polygon {name}: not valid WKT ({exc}); give e.g. "
                         "'POLYGON ((x0 y0, x1 y1, x2 y2, x0 y0))'") from None
    return require_valid(geom, name)


def _wkt_in_file(p: Path) -> str | None:
    """The file's text when it holds one WKT polygon (not a vector format), else None."""
    try:
        if p.stat().st_size > MAX_WKT_FILE:
            return None
        text = p.read_bytes().decode("utf-8").strip()
    except (OSError, UnicodeDecodeError):
        return None
    return text if text.upper().startswith(_WKT_WORDS) else None


def polygon_geometry(value: str | os.PathLike[str], *, crs: Any = None) -> tuple[Any, Any]:
    """The polygon of ``--polygon``: (valid shapely geometry, the CRS it is in or None).

    WKT text or a file holding WKT (in ``crs``, the work's, since WKT states none); a
    vector file (the union of its polygons) in its own CRS, reprojected to ``crs`` when
    both are known and differ, with a warning naming both.

    Raises
    ------
    InputError
        Text that is neither WKT nor an existing file, an unreadable file, a file without
        polygons, an invalid polygon (e.g. self-intersecting).
    """
    text = str(value).strip()
    if text.upper().startswith(_WKT_WORDS):
        return _wkt(text, "(WKT text)"), crs
    p = Path(text)
    if not p.is_file():
        raise InputError(f"--polygon {text[:60]!r} is neither a WKT polygon nor an existing "
                         "vector file (GeoPackage, GeoJSON, shapefile)")
    inline = _wkt_in_file(p)
    if inline is not None:
        return _wkt(inline, str(p)), crs
    return _vector_file(p, crs)


def _vector_file(p: Path, crs: Any) -> tuple[Any, Any]:
    import geopandas as gpd
    import shapely

    try:
        frame = gpd.read_file(p)
    except Exception as exc:  # noqa: BLE001 - pyogrio/fiona raise several types
        raise InputError(f"--polygon {p}: cannot read it as a vector file (GeoPackage, "
                         f"GeoJSON, shapefile) or WKT ({str(exc).splitlines()[0][:120]})"
                         ) from None
    polys = frame[frame.geometry.notna() & frame.geometry.geom_type.isin(
        ["Polygon", "MultiPolygon"])]
    if not len(polys):
        raise InputError(f"--polygon {p}: it holds no polygon; give a file of polygons")
    for g in polys.geometry:
        require_valid(g, str(p))
    if polys.crs is not None and crs is not None:
        from ..geo import as_crs

        target = as_crs(crs, "--polygon target CRS")
        if not target.equals(polys.crs):
            warnings.warn(f"--polygon {p}: in {polys.crs.name}, reprojected to the tiles' "
                          f"{target.name}", CanopyBlocksWarning, stacklevel=3)
            polys = polys.to_crs(target)
    geom = shapely.union_all(list(polys.geometry))
    return require_valid(geom, str(p)), polys.crs if crs is None else crs
