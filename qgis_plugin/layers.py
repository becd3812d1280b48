"""GeoDataFrame <-> QGIS features: the one conversion every algorithm uses.

* :func:`frame_fields` maps pandas dtypes to QgsFields,
* :func:`write_frame` creates the sink of an output parameter and fills it,
* :func:`source_to_frame` reads a QgsProcessingFeatureSource into a GeoDataFrame,
* :func:`qgs_crs` / :func:`pyproj_crs` convert coordinate reference systems.

NaN becomes NULL; numpy scalars become Python values; geometries travel as WKB.
"""

from __future__ import annotations

from typing import Any

from qgis.core import (
    Qgis,
    QgsCoordinateReferenceSystem,
    QgsFeature,
    QgsFeatureRequest,
    QgsFeatureSink,
    QgsField,
    QgsFields,
    QgsGeometry,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeatureSource,
    QgsProcessingFeedback,
    QgsWkbTypes,
)

__all__ = [
    "frame_fields",
    "frame_wkb_type",
    "write_frame",
    "source_to_frame",
    "qgs_crs",
    "pyproj_crs",
]

# QgsField takes QMetaType.Type from QGIS 3.38 (QVariant.Type before, deprecated after)
_NEW_FIELD_TYPES = Qgis.QGIS_VERSION_INT >= 33800


def _field_type(kind: str) -> Any:
    """The QGIS field type for a numpy dtype kind ('i', 'u', 'f', 'b', 'M', other -> string)."""
    if _NEW_FIELD_TYPES:
        from qgis.PyQt.QtCore import QMetaType

        table = {"i": QMetaType.Type.LongLong, "u": QMetaType.Type.LongLong,
                 "f": QMetaType.Type.Double, "b": QMetaType.Type.Bool,
                 "M": QMetaType.Type.QDateTime}
        return table.get(kind, QMetaType.Type.QString)
    from qgis.PyQt.QtCore import QVariant

    table_old = {"i": QVariant.LongLong, "u": QVariant.LongLong, "f": QVariant.Double,
                 "b": QVariant.Bool, "M": QVariant.DateTime}
    return table_old.get(kind, QVariant.String)


def _columns(frame: Any) -> list[str]:
    geom = getattr(frame, "_geometry_column_name", None) if hasattr(frame, "geometry") else None
    return [str(c) for c in frame.columns if c != geom]


def frame_fields(frame: Any) -> QgsFields:
    """QgsFields for the non-geometry columns of a (Geo)DataFrame, in column order."""
    fields = QgsFields()
    for col in _columns(frame):
        kind = frame[col].dtype.kind
        if kind == "O" and len(frame) and frame[col].map(lambda v: isinstance(v, bool)).all():
            kind = "b"
        fields.append(QgsField(col, _field_type(kind)))
    return fields


def frame_wkb_type(frame: Any) -> Any:
    """The single WKB type of a GeoDataFrame's geometries (NoGeometry for a plain table)."""
    if not hasattr(frame, "geometry") or getattr(frame, "_geometry_column_name", None) is None:
        return QgsWkbTypes.NoGeometry
    types = {t for t in frame.geometry.geom_type.dropna().unique()}
    if not types:
        return QgsWkbTypes.Point
    multi = {"MultiPolygon", "MultiLineString", "MultiPoint"}
    if types & multi or len(types) > 1:
        base = sorted(types)[0].replace("Multi", "")
        name = "Multi" + base
    else:
        name = types.pop()
    has_z = bool(frame.geometry.has_z.any())
    wkb = {"Point": QgsWkbTypes.Point, "LineString": QgsWkbTypes.LineString,
           "Polygon": QgsWkbTypes.Polygon, "MultiPoint": QgsWkbTypes.MultiPoint,
           "MultiLineString": QgsWkbTypes.MultiLineString,
           "MultiPolygon": QgsWkbTypes.MultiPolygon}.get(name, QgsWkbTypes.Unknown)
    return QgsWkbTypes.addZ(wkb) if has_z else wkb


def qgs_crs(crs: Any) -> QgsCoordinateReferenceSystem:
    """A QgsCoordinateReferenceSystem from a pyproj CRS (authority code first, else WKT)."""
    if crs is None:
        return QgsCoordinateReferenceSystem()
    auth = crs.to_authority(min_confidence=90)
    if auth is not None:
        q = QgsCoordinateReferenceSystem(f"{auth[0]}:{auth[1]}")
        if q.isValid():
            return q
    return QgsCoordinateReferenceSystem.fromWkt(crs.to_wkt())


def pyproj_crs(crs: QgsCoordinateReferenceSystem) -> Any:
    """A pyproj CRS from a QgsCoordinateReferenceSystem (None when invalid)."""
    if not crs.isValid():
        return None
    import pyproj

    authid = crs.authid()
    if authid and not authid.upper().startswith("USER"):
        try:
            return pyproj.CRS.from_user_input(authid)
        except pyproj.exceptions.CRSError:
            pass
    return pyproj.CRS.from_wkt(crs.toWkt(QgsCoordinateReferenceSystem.WKT2_2019))


def _python_values(frame: Any, columns: list[str]) -> list[list[Any]]:
    """Column-wise conversion to Python values with NaN/NaT -> None."""
    import pandas as pd

    out = []
    for col in columns:
        s = frame[col]
        if s.dtype.kind == "M":  # QDateTime in UTC: PyQGIS does not convert a datetime
            from qgis.PyQt.QtCore import QDateTime, Qt

            ms = s.to_numpy("datetime64[ms]").astype("int64")
            vals = [None if pd.isna(v) else QDateTime.fromMSecsSinceEpoch(int(m), Qt.UTC)
                    for v, m in zip(s, ms)]
        else:
            vals = s.astype(object).where(s.notna(), None).tolist()
        out.append(vals)
    return out


def write_frame(
    alg: Any,
    parameters: dict[str, Any],
    name: str,
    context: QgsProcessingContext,
    frame: Any,
    feedback: QgsProcessingFeedback | None = None,
    *,
    crs: QgsCoordinateReferenceSystem | None = None,
) -> str | None:
    """Create the sink of output parameter ``name`` and write ``frame`` into it.

    Parameters
    ----------
    alg : QgsProcessingAlgorithm
        The running algorithm (its ``parameterAsSink`` is used).
    frame : GeoDataFrame or DataFrame
        Rows become features; a GeoDataFrame's geometry (in ``frame.crs``) is kept.
    crs : QgsCoordinateReferenceSystem, optional
        Override the layer CRS (default: ``frame.crs``).

    Returns
    -------
    str or None
        The sink's destination id (None when the optional output was not requested).
    """
    import shapely

    fields = frame_fields(frame)
    wkb_type = frame_wkb_type(frame)
    if crs is None:
        crs = qgs_crs(getattr(frame, "crs", None)) if wkb_type != QgsWkbTypes.NoGeometry \
            else QgsCoordinateReferenceSystem()
    sink, dest = alg.parameterAsSink(parameters, name, context, fields, wkb_type, crs)
    if sink is None:
        if parameters.get(name) is None:
            return None
        raise QgsProcessingException(alg.invalidSinkError(parameters, name))
    columns = _columns(frame)
    values = _python_values(frame, columns)
    if wkb_type != QgsWkbTypes.NoGeometry:
        wkbs = shapely.to_wkb(frame.geometry.values.to_numpy() if hasattr(
            frame.geometry.values, "to_numpy") else frame.geometry.values)
    else:
        wkbs = None
    n = len(frame)
    batch: list[QgsFeature] = []
    for i in range(n):  # one QgsFeature per row: the sink API has no bulk form
        f = QgsFeature(fields)
        f.setAttributes([v[i] for v in values])
        if wkbs is not None and wkbs[i] is not None:
            g = QgsGeometry()
            g.fromWkb(wkbs[i])
            f.setGeometry(g)
        batch.append(f)
        if len(batch) >= 5000:
            if not sink.addFeatures(batch, QgsFeatureSink.FastInsert):
                raise QgsProcessingException(alg.writeFeatureError(sink, parameters, name))
            batch = []
            if feedback is not None and feedback.isCanceled():
                break
    if batch and not sink.addFeatures(batch, QgsFeatureSink.FastInsert):
        raise QgsProcessingException(alg.writeFeatureError(sink, parameters, name))
    if hasattr(sink, "finalize"):
        sink.finalize()
    return dest


def source_to_frame(
    source: QgsProcessingFeatureSource,
    feedback: QgsProcessingFeedback | None = None,
) -> Any:
    """Read a feature source into a GeoDataFrame (CRS from the source; NULL -> NaN/None)."""
    import geopandas as gpd
    import numpy as np
    import pandas as pd
    import shapely

    names = [f.name() for f in source.fields()]
    rows: list[list[Any]] = []
    wkbs: list[bytes | None] = []
    for feat in source.getFeatures(QgsFeatureRequest()):
        if feedback is not None and feedback.isCanceled():
            break
        rows.append([None if _is_null(v) else v for v in feat.attributes()])
        g = feat.geometry()
        wkbs.append(None if g is None or g.isNull() else bytes(g.asWkb()))
    df = pd.DataFrame(rows, columns=names)
    for f in source.fields():
        if f.isNumeric():
            df[f.name()] = pd.to_numeric(df[f.name()], errors="coerce")
    geoms = shapely.from_wkb(np.array(wkbs, dtype=object)) if wkbs else []
    return gpd.GeoDataFrame(df, geometry=gpd.GeoSeries(geoms, index=df.index),
                            crs=pyproj_crs(source.sourceCrs()))


def _is_null(value: Any) -> bool:
    if value is None:
        return True
    try:
        from qgis.PyQt.QtCore import QVariant

        return isinstance(value, QVariant) and value.isNull()
    except ImportError:  # pragma: no cover
        return False
