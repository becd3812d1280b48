"""What the co-registration aligns, and how a found offset is applied.

Targets are heights at map positions: ground (compared with the DTM) and canopy top
(compared with the DSM), grouped into blocks for the bootstrap. They come from photons
(the ground- and top-window photons of 10 m blocks: the photons themselves, not a block
statistic, so no estimator bias enters the vertical offset), from a block table (block
centres, ``ground`` and ``top`` of ``ok`` blocks), or from a footprint table (``ground``
and ``top`` of ``ok`` footprints).

:func:`apply_offset` shifts a :class:`~canopyblocks.photons.PhotonTrack`, a block table or
a footprint table by a :class:`~canopyblocks.validation.coregistration.CoregOffset`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import pyproj

from ..errors import InputError, NoUsableDataError
from ..geo import as_crs, from_metric
from ..photons import PhotonTrack

if TYPE_CHECKING:
    from .coregistration_offset import CoregOffset

__all__ = ["KIND_GROUND", "KIND_TOP", "CoregTargets", "targets_from_photons",
           "targets_from_table", "apply_offset"]

log = logging.getLogger(__name__)

KIND_GROUND = 0
KIND_TOP = 1
_GROUP_STRIDE = 10_000_000


@dataclass(frozen=True)
class CoregTargets:
    """Heights at positions, to be aligned with reference rasters.

    Attributes
    ----------
    x, y : ndarray float64
        Positions (m) in ``crs`` (the rasters' horizontal CRS).
    z : ndarray float64
        Heights (m) in the rasters' vertical datum.
    s : ndarray float64
        Along-track distance (m), to orient the track.
    kind : ndarray int8
        ``KIND_GROUND`` (0) or ``KIND_TOP`` (1).
    track : ndarray of str
        Track (beam) name of each target.
    group : ndarray int64
        Bootstrap unit (block), unique across tracks.
    crs : pyproj.CRS
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    s: np.ndarray
    kind: np.ndarray
    track: np.ndarray
    group: np.ndarray
    crs: pyproj.CRS

    def __post_init__(self) -> None:
        n = len(self.x)
        for name in ("y", "z", "s", "kind", "track", "group"):
            if len(getattr(self, name)) != n:
                raise InputError(f"CoregTargets.{name} has {len(getattr(self, name))} values, "
                                 f"x has {n}")

    def __len__(self) -> int:
        return len(self.x)

    def subset(self, mask: np.ndarray) -> CoregTargets:
        """The targets selected by a boolean mask."""
        return CoregTargets(self.x[mask], self.y[mask], self.z[mask], self.s[mask],
                            self.kind[mask], self.track[mask], self.group[mask], self.crs)

    @staticmethod
    def concat(parts: list[CoregTargets]) -> CoregTargets:
        """Targets of several tracks in one set (same CRS)."""
        if not parts:
            raise NoUsableDataError("no targets to co-register")
        cols = {f: np.concatenate([getattr(p, f) for p in parts])
                for f in ("x", "y", "z", "s", "kind", "track", "group")}
        return CoregTargets(**cols, crs=parts[0].crs)


def _to_crs(x: np.ndarray, y: np.ndarray, src: pyproj.CRS, dst: pyproj.CRS
            ) -> tuple[np.ndarray, np.ndarray]:
    if src == dst:
        return x, y
    tr = pyproj.Transformer.from_crs(src, dst, always_xy=True)
    xx, yy = tr.transform(x, y)
    return np.asarray(xx, float), np.asarray(yy, float)


def _horizontal(crs: pyproj.CRS) -> pyproj.CRS:
    return crs.sub_crs_list[0] if crs.is_compound else crs


def targets_from_photons(track: PhotonTrack, crs: Any, *, length: float = 10.0,
                         heights: np.ndarray | None = None, min_signal_conf: int | None = None,
                         track_index: int = 0) -> CoregTargets:
    """Ground- and top-window photons of ``length`` m blocks (DESIGN 1) as targets.

    Parameters
    ----------
    track : PhotonTrack
    crs : CRS-like
        The rasters' CRS; positions are transformed into its horizontal part.
    length : float
        Block length (m) of the windows that pick ground and top photons.
    heights : ndarray, optional
        Photon heights already converted to the rasters' vertical datum (default
        ``track.h``).
    min_signal_conf : int, optional
        ATL03 confidence threshold applied before the block windows.
    track_index : int
        Makes the bootstrap groups unique across tracks.
    """
    from ..blocks import BlockParams, compute_blocks
    from ..schema import LABEL_CANOPY, LABEL_GROUND

    h = track.h if heights is None else np.asarray(heights, float)
    params = BlockParams(lengths=(float(length),), min_signal_conf=min_signal_conf)
    _, labels = compute_blocks(track, params, labels=True)
    lab = labels[float(length)]
    pick = (lab == LABEL_GROUND) | (lab == LABEL_CANOPY)
    if not pick.any():
        raise NoUsableDataError(f"track {track.track}: no photon in a ground or top window; "
                                "nothing to co-register")
    x, y = _to_crs(track.x[pick], track.y[pick], track.crs, _horizontal(as_crs(crs)))
    s = track.s[pick]
    s0 = float(np.nanmin(track.s))
    block = np.floor((s - s0) / length).astype(np.int64)
    kind = np.where(lab[pick] == LABEL_GROUND, KIND_GROUND, KIND_TOP).astype(np.int8)
    return CoregTargets(x, y, h[pick].astype(float), s, kind,
                        np.full(int(pick.sum()), track.track, dtype=object),
                        block + track_index * _GROUP_STRIDE, _horizontal(as_crs(crs)))


def targets_from_table(table: pd.DataFrame, table_crs: Any, crs: Any, *,
                       track_column: str | None = None, heights: pd.DataFrame | None = None
                       ) -> CoregTargets:
    """Block or footprint table rows flagged ``ok`` as targets (ground and top).

    Parameters
    ----------
    table : DataFrame
        A block table (``track``, ``s_start``/``s_end``, ``x``, ``y``, ``ground``, ``top``)
        or a footprint table (``beam``, ``time``, geometry or ``lon``/``lat``, ``ground``,
        ``top``).
    table_crs : CRS-like
        CRS of the table's ``x``/``y`` (or geometry).
    crs : CRS-like
        The rasters' CRS.
    heights : DataFrame, optional
        ``ground``/``top`` already converted to the rasters' vertical datum.
    """
    t = table
    tcol = track_column or ("track" if "track" in t.columns else "beam")
    if tcol not in t.columns:
        raise InputError("the table has neither a 'track' nor a 'beam' column")
    for c in ("ground", "top"):
        if c not in t.columns:
            raise InputError(f"the table has no '{c}' column; give a block or footprint table")
    ok = ((t["flag"] == "ok").to_numpy(dtype=bool, copy=True) if "flag" in t.columns
          else np.ones(len(t), bool))
    if "length" in t.columns and t["length"].nunique() > 1:
        shortest = float(t["length"].min())
        ok &= (t["length"] == shortest).to_numpy()
        log.info("co-registering the %.0f m blocks (the shortest length in the table)",
                 shortest)
    if not ok.any():
        raise NoUsableDataError("no row flagged 'ok' to co-register")
    sub = t[ok]
    hsrc = heights[ok] if heights is not None else sub
    if "x" in sub.columns and "y" in sub.columns:
        x0, y0 = sub["x"].to_numpy(float), sub["y"].to_numpy(float)
    elif hasattr(sub, "geometry"):
        x0, y0 = sub.geometry.x.to_numpy(float), sub.geometry.y.to_numpy(float)
    else:
        raise InputError("the table has no x/y columns nor point geometry")
    x, y = _to_crs(x0, y0, _horizontal(as_crs(table_crs)), _horizontal(as_crs(crs)))
    if "s_start" in sub.columns:
        s = 0.5 * (sub["s_start"].to_numpy(float) + sub["s_end"].to_numpy(float))
    elif "time" in sub.columns:
        s = sub["time"].to_numpy(float)
    else:
        s = np.arange(len(sub), dtype=float)
    names = sub[tcol].astype(str).to_numpy(dtype=object)
    codes = pd.factorize(names)[0].astype(np.int64)
    group = codes * _GROUP_STRIDE + np.arange(len(sub))
    n = len(sub)
    return CoregTargets(
        np.concatenate([x, x]), np.concatenate([y, y]),
        np.concatenate([hsrc["ground"].to_numpy(float), hsrc["top"].to_numpy(float)]),
        np.concatenate([s, s]),
        np.concatenate([np.full(n, KIND_GROUND, np.int8), np.full(n, KIND_TOP, np.int8)]),
        np.concatenate([names, names]), np.concatenate([group, group]),
        _horizontal(as_crs(crs)))


def _shift_xy(x: np.ndarray, y: np.ndarray, crs: pyproj.CRS, off: CoregOffset
              ) -> tuple[np.ndarray, np.ndarray]:
    """Positions in ``crs`` moved by the offset's east/north (defined in its own CRS)."""
    ocrs = pyproj.CRS.from_wkt(off.crs_wkt)
    xo, yo = _to_crs(np.asarray(x, float), np.asarray(y, float), _horizontal(crs), ocrs)
    return _to_crs(xo + off.east, yo + off.north, ocrs, _horizontal(crs))


def apply_offset(obj: Any, offset: CoregOffset, *, crs: Any = None,
                 force: bool = False) -> Any:
    """A copy of a photon track, block table or footprint table shifted by ``offset``.

    Positions move by ``east``/``north`` (in the offset's CRS), along-track distances by
    ``along_track``, absolute heights (photon ``h``; table ``top``, ``ground``, ``z90``)
    by ``vertical``; lon/lat are recomputed. Relative heights (hmax, h90, rh) stay.

    Parameters
    ----------
    obj : PhotonTrack or (Geo)DataFrame
    offset : CoregOffset
    crs : CRS-like, optional
        CRS of a plain DataFrame's ``x``/``y`` (a GeoDataFrame carries its own).
    force : bool
        Apply an undetermined offset too (by default it is refused: it is not
        significant on held-out stretches of the track, or not constrained).

    Raises
    ------
    InputError
        The offset is undetermined (and ``force`` is False).
    """
    from ..arguments import check_instance
    from .coregistration_offset import CoregOffset as _CoregOffset
    check_instance(offset, _CoregOffset, "apply_offset: offset", "a CoregOffset (an item of CoregResult.offsets from coregister)")
    if not offset.determined and not force:
        raise InputError(f"apply_offset: the offset of {offset.name} is undetermined "
                         f"({offset.reason}); it is not applied (force=True applies it "
                         "anyway)")
    if isinstance(obj, PhotonTrack):
        x, y = _shift_xy(obj.x, obj.y, obj.crs, offset)
        lon, lat = from_metric(x, y, obj.crs)
        return replace(obj, x=x, y=y, lon=np.asarray(lon), lat=np.asarray(lat),
                       h=obj.h + offset.vertical, s=obj.s + offset.along_track)
    if not isinstance(obj, pd.DataFrame):
        raise InputError(f"apply_offset takes a PhotonTrack, a block table or a footprint "
                         f"table; got {type(obj).__name__}")
    out = obj.copy()
    tcrs = getattr(obj, "crs", None) or crs
    if tcrs is None:
        raise InputError("the table carries no CRS; pass crs=...")
    tcrs = as_crs(tcrs)
    has_geom = hasattr(out, "geometry") and "geometry" in out.columns
    if "x" in out.columns and "y" in out.columns:
        x0, y0 = out["x"].to_numpy(float), out["y"].to_numpy(float)
    elif has_geom:
        x0, y0 = out.geometry.x.to_numpy(float), out.geometry.y.to_numpy(float)
    else:
        raise InputError("the table has no x/y columns nor point geometry")
    x, y = _shift_xy(x0, y0, tcrs, offset)
    if "x" in out.columns:
        out["x"], out["y"] = x, y
    lon, lat = from_metric(x, y, _horizontal(tcrs))
    if "lon" in out.columns:
        out["lon"], out["lat"] = np.asarray(lon), np.asarray(lat)
    for c in ("top", "ground", "z90"):
        if c in out.columns:
            out[c] = out[c].to_numpy(float) + offset.vertical
    for c in ("s_start", "s_end"):
        if c in out.columns:
            out[c] = out[c].to_numpy(float) + offset.along_track
    if has_geom:
        import geopandas as gpd

        z = out["ground"].to_numpy(float) if (
            "ground" in out.columns and out.geometry.has_z.any()) else None
        geom = gpd.points_from_xy(x, y, z, crs=tcrs)
        out = out.set_geometry(geom)
    return out
