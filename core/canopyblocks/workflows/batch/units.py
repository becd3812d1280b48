"""Units of work for many granules (DESIGN 6): tile index and track-tile intersection.

A unit is one (granule, beam, tiles it crosses). The tile index holds each LAS/LAZ
tile's header extent (no points read); a beam's track line comes from its geolocation
segments (ATL03 ``geolocation/reference_photon_lat|lon``), cheap to read.
"""

from __future__ import annotations

import hashlib
import logging
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj
import shapely

from ...errors import CanopyBlocksError, CanopyBlocksWarning, CRSError, FileFormatError, InputError

__all__ = ["Tile", "Unit", "tile_index", "track_line", "find_units", "list_inputs",
           "photon_identity", "drop_duplicate_granules"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Tile:
    """One airborne tile: its path, header extent (m, in ``crs``) and CRS (WKT)."""

    path: str
    bounds: tuple[float, float, float, float]
    crs_wkt: str

    @property
    def name(self) -> str:
        """File stem plus a short hash of the full path (unique within a batch)."""
        h = hashlib.sha1(os.path.abspath(self.path).encode()).hexdigest()[:8]
        return f"{Path(self.path).stem}-{h}"


@dataclass(frozen=True)
class Unit:
    """One (granule, beam, tiles) piece of work."""

    granule: str
    beam: str
    tiles: tuple[Tile, ...]

    @property
    def key(self) -> str:
        """Stable id: granule file name and beam."""
        return f"{Path(self.granule).name}:{self.beam}"

    @property
    def partition(self) -> str:
        """Relative folder of its outputs: ``<granule stem>/<beam>`` (plain names, not
        hive-style ``key=value``, so a reader does not invent a conflicting column)."""
        return f"{Path(self.granule).stem}/{self.beam}"


def list_inputs(items: Sequence[str | os.PathLike[str]], suffixes: tuple[str, ...]
                ) -> list[str]:
    """Files given directly, or found (sorted) in given folders, with one of ``suffixes``;
    also granule URLs, ``s3://`` prefixes (every object under it with one of ``suffixes``)
    and text files (``.txt``/``.lst``) listing paths or URLs, one a line (``#`` comments)."""
    from ...readers.remote import is_url, list_granules

    out: list[str] = []
    for it in items:
        if is_url(it):  # an s3:// prefix (listed) or a granule's URL
            url = str(it).strip()
            listed = url.startswith("s3://") and not url.lower().endswith(suffixes)
            out.extend(list_granules(url, suffixes) if listed else [url])
            continue
        p = Path(it)
        if p.is_file() and p.suffix.lower() in (".txt", ".lst"):  # a list of granules
            lines = [ln.strip() for ln in p.read_text(encoding="utf-8").splitlines()]
            out.extend(list_inputs([ln for ln in lines if ln and not ln.startswith("#")],
                                   suffixes))
            continue
        if p.is_dir():
            out.extend(str(q) for q in sorted(p.iterdir()) if q.suffix.lower() in suffixes)
        elif p.exists():
            out.append(str(p))
        else:
            raise FileFormatError(f"{p}: no such file or folder")
    if not out:
        raise InputError(f"no input files with suffix {', '.join(suffixes)} in "
                         f"{', '.join(map(str, items))}")
    return sorted(dict.fromkeys(out))


_ENDS = 256  # photons read at each end of each beam for a granule's identity


def photon_identity(path: str) -> str | None:
    """A digest of the photons a granule holds, whatever its name or place.

    Per beam (sorted): the photon count and the first and last ``_ENDS`` values of
    ``heights/delta_time`` and ``heights/h_ph`` (a few kB, cheap over ``s3://`` too).
    Two files with the same digest hold the same photons (a copy, a renamed copy, the
    same granule as a URL and a local path).

    Returns
    -------
    str or None
        Hex digest; None when the file cannot be read (its unit reports it).
    """
    from ...readers._h5 import open_h5

    h = hashlib.sha1()
    try:
        with open_h5(path, "ATL03") as f:
            for beam in sorted(k for k in f.keys("/") if k.startswith("gt")):
                for name in ("delta_time", "h_ph"):
                    d = f"{beam}/heights/{name}"
                    if not f.is_dataset(d) or len(f.shape(d)) != 1:
                        continue
                    n = f.shape(d)[0]
                    h.update(f"{d}:{n};".encode())
                    for sel in (np.s_[:min(n, _ENDS)], np.s_[max(n - _ENDS, 0):n]):
                        h.update(np.ascontiguousarray(f.read(d, sel, dtype=np.float64)).tobytes())
    except (CanopyBlocksError, OSError):
        return None
    return h.hexdigest()


def drop_duplicate_granules(paths: Sequence[str]) -> list[str]:
    """``paths`` without the granules whose photons an earlier one already holds, with a
    :class:`~canopyblocks.errors.CanopyBlocksWarning` naming each pair (the same photons
    never enter the merged tables twice)."""
    seen: dict[str, str] = {}
    out: list[str] = []
    for p in paths:
        key = photon_identity(p)
        if key is not None and key in seen:
            warnings.warn(f"{p} holds the same photons as {seen[key]} (same beams, same "
                          f"photon times and heights): counted once, as {seen[key]}",
                          CanopyBlocksWarning, stacklevel=2)
            continue
        if key is not None:
            seen[key] = p
        out.append(p)
    return out


def tile_index(paths: Sequence[str | os.PathLike[str]]) -> list[Tile]:
    """Header extents and CRSs of the tiles (tiles may be in several CRSs, e.g. UTM zones:
    each unit is validated on tiles of one CRS)."""
    from ...readers.survey import source_extent

    tiles = []
    for p in paths:
        bounds, crs = source_extent(p)
        if crs is None:
            raise CRSError(f"{p} states no CRS; batch needs tiles with a CRS in their header")
        tiles.append(Tile(str(p), tuple(float(v) for v in bounds),  # type: ignore[arg-type]
                          crs.to_wkt()))
    return tiles


def track_line(granule: str, beam: str) -> tuple[np.ndarray, np.ndarray]:
    """Longitude and latitude (degrees) of a beam's geolocation segments (ATL03)."""
    from ...readers._h5 import open_h5

    with open_h5(granule, product="ATL03") as f:
        lat = np.asarray(f.read(f"{beam}/geolocation/reference_photon_lat"), float)
        lon = np.asarray(f.read(f"{beam}/geolocation/reference_photon_lon"), float)
    ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
    return lon[ok], lat[ok]


def find_units(granules: Sequence[str], tiles: Sequence[Tile], *,
               beams: Sequence[str] = (), buffer: float = 10.0, reach: float = 0.0,
               problems: dict[str, str] | None = None,
               missed: dict[str, str] | None = None) -> list[Unit]:
    """Every (granule, beam) whose track line passes within ``buffer`` m of a tile, with
    every tile within ``max(buffer, reach)`` m of its track line (the tiles its corridor
    rasters read).

    Units are sorted by granule then beam, so a batch is deterministic. A granule that
    cannot be read is left out; with ``problems`` given, its error is recorded there
    (``{granule: message}``) instead of stopping the batch.  A granule none of whose
    beams passes a tile is left out too; with ``missed`` given, the reason is recorded
    there (how far its nearest beam passes from the nearest tile).
    """
    from ...errors import CanopyBlocksError
    from ...readers.atl03 import atl03_beams

    if not tiles:
        raise InputError("no airborne tiles given")
    groups: dict[str, list[Tile]] = {}
    for t in tiles:  # tiles of one CRS together (in the order first seen)
        groups.setdefault(t.crs_wkt, []).append(t)
    per_crs = []
    for wkt, group in groups.items():
        boxes = shapely.box(*np.array([t.bounds for t in group]).T)
        per_crs.append((group, boxes, shapely.union_all(boxes), pyproj.Transformer.from_crs(
            "EPSG:4326", pyproj.CRS.from_wkt(wkt), always_xy=True)))
    units = []
    for g in granules:
        try:
            names = list(beams) or [b.name for b in atl03_beams(g) if b.n_photons]
            lines = {beam: track_line(g, beam) for beam in names}
        except CanopyBlocksError as exc:
            if problems is None:
                raise
            problems[str(g)] = str(exc)  # the project's one line, naming the granule
            continue
        nearest = np.inf
        found = 0
        for beam, (lon, lat) in lines.items():
            if lon.size < 2:
                continue
            hits = []
            for group, boxes, everywhere, to_tiles in per_crs:
                x, y = to_tiles.transform(lon, lat)
                track = shapely.LineString(np.column_stack([x, y]))
                line = track.buffer(buffer)
                near = track.buffer(max(buffer, reach))
                hit = [t for t, box in zip(group, boxes) if near.intersects(box)] \
                    if any(line.intersects(box) for box in boxes) else []
                if hit:
                    hits.append(hit)
                else:
                    nearest = min(nearest, float(track.distance(everywhere)))
            if hits:  # one CRS a unit: the one with most tiles on the track
                best = max(hits, key=len)
                if len(hits) > 1:
                    log.warning("%s %s crosses tiles in %d CRSs; validated on the %d tile(s) "
                                "in %s, %d tile(s) in other CRSs left out", Path(g).name, beam,
                                len(hits), len(best),
                                pyproj.CRS.from_wkt(best[0].crs_wkt).name,
                                sum(len(h) for h in hits) - len(best))
                units.append(Unit(str(g), beam, tuple(best)))
                found += 1
        if not found and missed is not None:
            missed[str(g)] = (
                f"none of its {len(lines)} beam(s) ({', '.join(lines) or 'none'}) has a "
                "track with geolocation" if not np.isfinite(nearest) else
                f"none of its {len(lines)} beam(s) passes a tile: the nearest passes "
                f"{nearest / 1000.0:,.1f} km from the nearest of the {len(tiles)} tile(s)")
    return sorted(units, key=lambda u: (u.granule, u.beam))
