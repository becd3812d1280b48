"""The one reader of a LAS/LAZ file's CRS: horizontal part, vertical part and units.

A LAS file states its CRS in one of two ways (ASPRS LAS 1.0-1.4):

* a WKT VLR (``LASF_Projection`` 2112; required for point formats 6-10, also written by
  liblas into older files), possibly a compound CRS with a vertical part;
* GeoTIFF keys (``LASF_Projection`` 34735, with 34736/34737 for doubles and strings):
  ``ProjectedCSTypeGeoKey`` (3072) or ``GeographicTypeGeoKey`` (2048) for the horizontal
  CRS, ``ProjLinearUnitsGeoKey`` (3076) for its unit, ``VerticalCSTypeGeoKey`` (4096) for
  the vertical CRS and ``VerticalUnitsGeoKey`` (4099) for the unit of the heights.

laspy's own ``parse_crs`` reads only the horizontal key of the GeoTIFF record, so a tile
whose keys say NAVD88 heights in US survey feet looked like metres to the laspy path and
like feet to PDAL.  :func:`las_file_crs` reads everything, in PDAL's order (LAS 1.4: the
WKT when it is there; older files: the GeoTIFF keys first, then a WKT VLR), and reads the
GeoTIFF keys of LAS 1.4 files too, which PDAL 2.2 ignores.  Every command and the QGIS
algorithms take a tile's CRS from here.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import pyproj

from ..errors import CRSError, DependencyError, FileFormatError

__all__ = ["LasCRS", "las_file_crs", "crs_from_records", "GEOKEY_PROJECTED", "GEOKEY_GEOGRAPHIC",
           "GEOKEY_LINEAR_UNITS", "GEOKEY_VERTICAL", "GEOKEY_VERTICAL_UNITS"]

log = logging.getLogger(__name__)

GEOKEY_GEOGRAPHIC = 2048
GEOKEY_PROJECTED = 3072
GEOKEY_LINEAR_UNITS = 3076
GEOKEY_VERTICAL = 4096
GEOKEY_VERTICAL_UNITS = 4099
_USER_DEFINED = 32767  # a GeoTIFF key's "user defined": the CRS is stated another way


@dataclass(frozen=True)
class LasCRS:
    """What a LAS/LAZ file says about its coordinates.

    Attributes
    ----------
    path : Path
    horizontal : pyproj.CRS or None
        The horizontal CRS of x/y; None when the file states none.
    vertical : pyproj.CRS or None
        The vertical CRS of z; None when the file states none (or an unknown one).
    vertical_name : str
        ``"EPSG:nnnn"`` of the vertical CRS, its name when it has no code (e.g. a
        user-defined datum named in the GeoTIFF citation), or ``"unknown"``.
    horizontal_unit, vertical_unit : (str, float) or None
        Unit name and metres per unit, as the file states them (GeoTIFF unit keys, or
        the CRS's axes); None when not stated.
    source : str
        ``"wkt"``, ``"geotiff keys"`` or ``"none"``.
    """

    path: Path
    horizontal: pyproj.CRS | None
    vertical: pyproj.CRS | None
    vertical_name: str
    horizontal_unit: tuple[str, float] | None
    vertical_unit: tuple[str, float] | None
    source: str

    @property
    def crs(self) -> pyproj.CRS | None:
        """The full CRS: compound when a vertical CRS is known, else the horizontal one."""
        if self.horizontal is None:
            return None
        if self.vertical is None:
            return self.horizontal
        h, v = self.horizontal.to_epsg(), self.vertical.to_epsg()
        if h and v:
            return pyproj.CRS(f"EPSG:{h}+{v}")
        return pyproj.CRS(pyproj.crs.CompoundCRS(
            name=f"{self.horizontal.name} + {self.vertical.name}",
            components=[self.horizontal, self.vertical]).to_wkt())

    def require_metres(self) -> None:
        """Refuse positions or heights the file states in feet (or another non-metre unit).

        Raises
        ------
        CRSError
            Naming the file, the unit found and where it was found.
        """
        for what, unit in (("positions (x, y)", self.horizontal_unit),
                           ("heights (z)", self.vertical_unit)):
            if unit is not None and abs(unit[1] - 1.0) > 1e-9 and "degree" not in unit[0]:
                raise CRSError(
                    f"{self.path}: its {self.source} say the {what} are in {unit[0]!r}; "
                    "positions and heights in feet are not supported: convert the tile to "
                    "metres (x, y and z) first, e.g. with PDAL filters.reprojection plus a Z "
                    "scale of 0.3048006")


def _laspy() -> Any:
    try:
        import laspy
    except ImportError:
        raise DependencyError(
            "reading LAS/LAZ needs laspy with a LAZ backend: pip install 'canopyblocks[las]'"
        ) from None
    return laspy


def las_file_crs(path: str | os.PathLike[str]) -> LasCRS:
    """Read the CRS records of a LAS/LAZ file (header and VLRs only, no points).

    Raises
    ------
    FileFormatError
        Missing or unreadable file.
    CRSError
        CRS records that cannot be understood (a WKT that PROJ rejects, GeoTIFF keys
        naming a code that does not exist, keys that contradict each other); the
        message names the file and the record.
    """
    p = Path(path)
    try:
        stat = p.stat()
    except FileNotFoundError:
        raise FileFormatError(f"{p}: no such file") from None
    except OSError as exc:
        raise FileFormatError(f"cannot read {p}: {exc.strerror or exc}") from None
    return _cached(str(p.absolute()), stat.st_size, stat.st_mtime_ns)


@lru_cache(maxsize=256)
def _cached(path: str, size: int, mtime: int) -> LasCRS:  # noqa: ARG001 - cache keys
    laspy = _laspy()
    p = Path(path)
    try:
        with laspy.open(p) as reader:
            header = reader.header
            vlrs = list(header.vlrs or []) + list(getattr(header, "evlrs", None) or [])
            version = (int(header.version.major), int(header.version.minor))
            wkt_bit = bool(getattr(header.global_encoding, "wkt", False))
    except FileNotFoundError:
        raise FileFormatError(f"{p}: no such file") from None
    except Exception as exc:  # noqa: BLE001 - laspy raises several types for corrupt headers
        raise FileFormatError(f"{p}: not a readable LAS/LAZ file ({exc})") from None
    return crs_from_records(p, vlrs, version, wkt_bit)


def crs_from_records(p: Path, vlrs: list[Any], version: tuple[int, int],
                     wkt_bit: bool) -> LasCRS:
    """The CRS a file states by its (E)VLRs (laspy records), LAS ``version`` and the header's
    WKT bit, read as :func:`las_file_crs` reads a file (COPC read by byte ranges uses it)."""
    wkt = _wkt_record(vlrs)
    keys = _geo_keys(vlrs)
    if wkt is not None and (version >= (1, 4) or wkt_bit or not keys):
        return _from_wkt(p, wkt)
    if keys:
        return _from_keys(p, keys, _geo_ascii(vlrs))
    return LasCRS(p, None, None, "unknown", None, None, "none")


def _wkt_record(vlrs: list[Any]) -> str | None:
    for vlr in vlrs:
        if getattr(vlr, "record_id", None) != 2112:
            continue
        text = getattr(vlr, "string", None)
        if text is None:
            raw = getattr(vlr, "record_data", b"") or b""
            text = bytes(raw).decode("utf-8", errors="replace")
        text = str(text).strip("\x00 \n")
        if text:
            return text
    return None


def _geo_keys(vlrs: list[Any]) -> dict[int, tuple[int, int, int]]:
    """``{key id: (tiff tag location, count, value)}`` of the GeoKeyDirectory record."""
    for vlr in vlrs:
        keys = getattr(vlr, "geo_keys", None)
        if getattr(vlr, "record_id", None) == 34735 and keys:
            return {int(k.id): (int(k.tiff_tag_location), int(k.count), int(k.value_offset))
                    for k in keys if int(k.id) > 0}
    return {}


def _geo_ascii(vlrs: list[Any]) -> str:
    for vlr in vlrs:
        if getattr(vlr, "record_id", None) == 34737:
            raw = getattr(vlr, "record_data", None)
            if raw:
                return bytes(raw).decode("ascii", errors="replace")
            return "|".join(str(s) for s in getattr(vlr, "strings", []) or []) + "|"
    return ""


def _from_wkt(p: Path, wkt: str) -> LasCRS:
    try:
        full = pyproj.CRS.from_wkt(wkt)
    except pyproj.exceptions.CRSError as exc:
        raise CRSError(f"{p}: its WKT CRS record cannot be read ({exc}); rewrite the file's "
                       "CRS (e.g. pdal translate with writers.las.a_srs)") from None
    horizontal: pyproj.CRS | None = full
    vertical: pyproj.CRS | None = None
    if full.is_compound:
        subs = full.sub_crs_list
        horizontal = next((s for s in subs if not s.is_vertical), subs[0])
        vertical = next((s for s in subs if s.is_vertical), None)
    elif full.is_vertical:
        horizontal, vertical = None, full
    return LasCRS(p, horizontal, _known_vertical(vertical), _vertical_name(vertical),
                  _axis_unit(horizontal), _axis_unit(vertical), "WKT CRS record")


def _known_vertical(v: pyproj.CRS | None) -> pyproj.CRS | None:
    """None for a vertical CRS that names no datum (``VERT_CS["unknown", ...]``)."""
    if v is None or (v.name.lower() in ("unknown", "") and not v.to_epsg()):
        return None
    return v


def _vertical_name(v: pyproj.CRS | None) -> str:
    if v is None or _known_vertical(v) is None:
        return "unknown"
    code = v.to_epsg()
    return f"EPSG:{code}" if code else v.name


def _axis_unit(crs: pyproj.CRS | None) -> tuple[str, float] | None:
    if crs is None or not crs.axis_info:
        return None
    a = crs.axis_info[0]
    return (a.unit_name, float(a.unit_conversion_factor))


def _unit(code: int) -> tuple[str, float] | None:
    from pyproj.database import get_units_map

    for name, u in get_units_map(auth_name="EPSG", category="linear").items():
        if u.code == str(code):
            return (name, float(u.conv_factor))
    return None


def _inline(keys: dict[int, tuple[int, int, int]], key: int) -> int | None:
    loc, _, value = keys.get(key, (-1, 0, 0))
    return value if loc == 0 else None


def _stated_unit(keys: dict[int, tuple[int, int, int]], key: int, p: Path, what: str,
                 kind: str) -> tuple[str, float] | None:
    """The unit (name, metres per unit) the GeoKey ``key`` states inline, or None (not
    stated, or user-defined); a code that is no unit is refused naming the file."""
    code = _inline(keys, key)
    if code is None or code == _USER_DEFINED:
        return None
    stated = _unit(code)
    if stated is None:
        raise CRSError(f"{p}: its {what} give the {kind} unit code {code}, which is not a "
                       "unit; rewrite the file's CRS")
    return stated


def _citation(keys: dict[int, tuple[int, int, int]], key: int, ascii_params: str) -> str:
    loc, count, offset = keys.get(key, (-1, 0, 0))
    if loc != 34737 or count <= 0:
        return ""
    return ascii_params[offset:offset + count].strip("|\x00 ")


def _from_keys(p: Path, keys: dict[int, tuple[int, int, int]], ascii_params: str) -> LasCRS:
    what = "GeoTIFF keys"
    horizontal = None
    for key in (GEOKEY_PROJECTED, GEOKEY_GEOGRAPHIC):
        code = _inline(keys, key)
        if code is not None and 1024 <= code < _USER_DEFINED:
            try:
                horizontal = pyproj.CRS.from_epsg(code)
            except pyproj.exceptions.CRSError:
                raise CRSError(f"{p}: its {what} name the horizontal CRS EPSG:{code}, which "
                               "does not exist; rewrite the file's CRS (e.g. pdal translate "
                               "with writers.las.a_srs)") from None
            break
    h_unit = _axis_unit(horizontal)
    stated = _stated_unit(keys, GEOKEY_LINEAR_UNITS, p, what, "linear")
    if stated is not None:
        if h_unit is not None and horizontal is not None and horizontal.is_projected \
                and abs(stated[1] - h_unit[1]) > 1e-9:
            raise CRSError(f"{p}: its {what} say the positions are in {stated[0]!r} but "
                           f"{horizontal.name} is in {h_unit[0]!r}: they contradict each "
                           "other; rewrite the file's CRS")
        if horizontal is None or horizontal.is_projected:
            h_unit = stated
    vertical = None
    v_name = "unknown"
    code = _inline(keys, GEOKEY_VERTICAL)
    if code is not None and 1024 <= code < _USER_DEFINED:
        try:
            cand = pyproj.CRS.from_epsg(code)
        except pyproj.exceptions.CRSError:
            cand = None
        if cand is not None and cand.is_vertical:
            vertical, v_name = cand, f"EPSG:{code}"
        elif cand is not None and len(cand.axis_info) == 3:  # a 3-D CRS: ellipsoidal heights
            vertical, v_name = cand, f"EPSG:{code}"
        else:
            log.warning("%s: VerticalCSTypeGeoKey %d is not a vertical CRS; vertical datum "
                        "unknown", p, code)
    elif code == _USER_DEFINED:
        v_name = _citation(keys, GEOKEY_VERTICAL + 1, ascii_params) or "unknown"
    v_unit = _axis_unit(vertical)
    stated = _stated_unit(keys, GEOKEY_VERTICAL_UNITS, p, what, "vertical")
    if stated is not None:
        if v_unit is not None and abs(stated[1] - v_unit[1]) > 1e-9:
            raise CRSError(f"{p}: its {what} say the heights are in {stated[0]!r} but "
                           f"{vertical.name if vertical else 'its vertical CRS'} is in "
                           f"{v_unit[0]!r}: they contradict each other; rewrite the file's "
                           "CRS")
        v_unit = stated
    return LasCRS(p, horizontal, vertical, v_name, h_unit, v_unit, what)
