"""Corpus cases of surveys whose tiles are not what their headers or names say, made from
the Topography tile cut in two halves (west, east; adjacent tiles): the same points given
twice (a renamed copy with an upper-case suffix, the same path twice, a symlink, a crop of
a tile, a copy with its points in another order, a COPC of the whole tile given with its
halves), a tile whose header extent is 5 km off its points, one whose header's max x is 2,000 km
too far (every point inside; named, not the grid's size), a tile without ground points
among classified ones, tiles stating two vertical datums (CGVD28 and CGVD2013), a tile
stating none beside one stating CGVD28 (CGVD28 declared, whatever the order); ``validate``
against the footprint reference with a tile without ground (named), and with it alone
(refused for its ground, not the track's coverage); a tile in US survey feet (refused
first, with no warning of a UTM working CRS before).  (COPC
files and EPT datasets whose hierarchy lies are in ``copc_corpus``.)

The accepted surveys must give the rasters of the whole tile, cell for cell (the halves
hold exactly its points), with a warning naming the cause; the tile without ground must
leave its cells without DTM.  Registered in :func:`badinputs.make_corpus.all_cases`; the
runner ``survey`` joins the corpus test's runners through :data:`RUNNERS`.
"""

from __future__ import annotations

import os
import shutil
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["survey_cases", "RUNNERS", "move_header", "grow_header", "crop_of", "in_feet"]


DUPLICATES = ("copy", "twice", "symlink", "crop", "shuffled", "copc-of-tiles")
"""The survey cases that give the same points twice (counted once, with a warning)."""


def move_header(path: Path, dx: float, dy: float) -> None:
    """Shift a LAS/LAZ header's stated extent (max/min x, y at bytes 179-211), not its points."""
    raw = bytearray(path.read_bytes())
    mx, mnx, my, mny = struct.unpack_from("<4d", raw, 179)
    struct.pack_into("<4d", raw, 179, mx + dx, mnx + dx, my + dy, mny + dy)
    path.write_bytes(bytes(raw))


def grow_header(path: Path, dx: float) -> None:
    """Raise a LAS/LAZ header's stated max x (byte 179) by ``dx``: every point still inside."""
    raw = bytearray(path.read_bytes())
    struct.pack_into("<d", raw, 179, struct.unpack_from("<d", raw, 179)[0] + dx)
    path.write_bytes(bytes(raw))


def crop_of(src: Path, out: Path) -> Path:
    """The western half of a tile's points (a subset, in the file's order)."""
    import laspy

    las = laspy.read(src)
    x = np.asarray(las.x)
    _write(las, x < np.median(x), out)
    return out


def _write(las: Any, keep: np.ndarray, out: Path) -> None:
    import laspy

    part = laspy.LasData(las.header)
    part.points = las.points[keep].copy()
    part.update_header()
    part.write(str(out))


def _shuffled(src: Path, out: Path) -> Path:
    """A copy of a tile with its points in another order (the same header)."""
    import laspy

    las = laspy.read(src)
    copy = laspy.LasData(las.header)
    copy.points = las.points[np.random.default_rng(3).permutation(len(las.points))]
    copy.write(str(out))
    return out


def _halves(base: Any, folder: Path, vertical: tuple[int | None, int | None] | None = None
            ) -> tuple[Path, Path]:
    """The Topography tile's west and east halves (optionally with vertical datums; None:
    the horizontal CRS alone)."""
    import laspy
    import pyproj

    las = laspy.read(base.topo)
    x = np.asarray(las.x)
    cut = float(np.floor(np.median(x)))
    out = []
    for i, (name, keep) in enumerate((("west", x < cut), ("east", x >= cut))):
        p = folder / f"{name}.laz"
        if vertical is None:
            _write(las, keep, p)
        else:
            one = laspy.convert(las, file_version="1.4", point_format_id=6)
            one.header.vlrs.clear()
            v = vertical[i]
            one.header.add_crs(pyproj.CRS.from_user_input(
                "EPSG:2949" if v is None else f"EPSG:2949+{v}"))
            _write(one, keep, p)
        out.append(p)
    return out[0], out[1]


def _survey(kind: str) -> Callable[[Path, Any], dict[str, Any]]:
    def make(folder: Path, base: Any) -> dict[str, Any]:
        west, east = _halves(base, folder, {"datums": (5713, 6647), "datum-unstated": (
            5713, None)}.get(kind))
        tiles: list[Path] = [west, east]
        damaged = west
        if kind == "copy":
            damaged = Path(shutil.copy(west, folder / "tile1.LAZ"))
        elif kind == "twice":
            damaged = west
        elif kind == "symlink":
            damaged = folder / "link.laz"
            os.symlink(west, damaged)
        elif kind == "crop":
            damaged = crop_of(west, folder / "crop.laz")
        elif kind == "shuffled":
            damaged = _shuffled(west, folder / "shuffled.laz")
        elif kind == "copc-of-tiles":
            from .copc_corpus import _made

            damaged = Path(shutil.copy(_made(base)[0], folder / "whole.copc.laz"))
        elif kind == "header-moved":
            move_header(east, 5000.0, 0.0)
            damaged, tiles = east, [west, east]
        elif kind == "header-grown":  # 2,000 km wider: the whole-survey grid too large
            grow_header(east, 2.0e6)
            damaged, tiles = east, [west, east]
        elif kind in ("no-ground", "validate-no-ground", "validate-no-ground-alone"):
            import laspy

            las = laspy.read(east)
            c = np.asarray(las.classification)
            c[c == 2] = 1
            las.classification = c
            las.write(str(east))
            damaged = east
        elif kind == "datums":
            damaged = east
        elif kind == "feet":  # the east half stating US survey feet, x/y in feet
            damaged = in_feet(east, folder / "feet.laz")
            tiles = [damaged]
        elif kind == "datum-unstated":  # the tile stating no datum first: it used to decide
            damaged, tiles = east, [east, west]
        if kind in DUPLICATES:
            tiles = [west, east, damaged]
        elif kind == "validate-no-ground-alone":
            tiles = [east]
        return {"path": damaged, "tiles": tiles, "kind": kind, "truth": base.topo,
                "west": west}
    return make


def in_feet(src: Path, out: Path) -> Path:
    """A copy of a tile stating US survey feet (EPSG:2286), its x/y converted to feet."""
    import laspy
    import pyproj

    las = laspy.convert(laspy.read(src), file_version="1.4", point_format_id=6)
    las.header.vlrs.clear()
    las.header.add_crs(pyproj.CRS.from_epsg(2286))
    x, y = np.asarray(las.x) / 0.3048006096, np.asarray(las.y) / 0.3048006096
    las.header.offsets = [float(x.min()), float(y.min()), las.header.offsets[2]]
    las.x, las.y = x, y
    las.write(str(out))
    return out


def run_survey_quiet(i: dict[str, Any], folder: Path) -> Any:
    """:func:`run_survey` that must refuse without a warning first (none contradicts it)."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return run_survey(i, folder)
        finally:
            assert [str(w.message) for w in caught] == [], "a warning before the refusal"


def run_survey(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks.workflows.rasters import make_survey_rasters

    return make_survey_rasters(i["tiles"], folder / "rasters", backend="serial")


def _band(path: Path) -> np.ndarray:
    import rasterio

    with rasterio.open(path) as src:
        a = src.read(1).astype(float)
        a[a == src.nodata] = np.nan
    return a


def check_survey(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    """Duplicates: the whole tile's rasters, cell for cell; no ground: no DTM beyond the
    classified half (more than 3 m east of it)."""
    from canopyblocks.reference.rasters import make_reference_rasters

    assert any(Path(i["path"]).name in w for w in ws), f"no warning names the tile: {ws}"
    if i["kind"] == "no-ground":
        import laspy

        dtm = _band(result.dtm)
        west = laspy.read(i["west"])
        with __import__("rasterio").open(result.dtm) as src:
            t = src.transform
        cx = t.c + (np.arange(dtm.shape[1]) + 0.5) * t.a
        east_of = cx > float(np.max(west.x)) + 3.0
        assert np.isnan(dtm[:, east_of]).all(), "DTM interpolated across the tile"
        assert result.stats["dtm_unsupported"] > 0
        return
    if i["kind"] == "datum-unstated":  # the datum the other tile states, whatever the order
        import pyproj

        for name in ("dtm", "dsm_max", "dsm_p90"):
            with __import__("rasterio").open(getattr(result, name)) as src:
                crs = pyproj.CRS.from_wkt(src.crs.to_wkt())
            assert crs.sub_crs_list[1].to_epsg() == 5713, (name, crs.name)
    whole = make_reference_rasters([i["truth"]], i["folder"] / "whole")
    for name in ("dtm", "dsm_max", "dsm_p90"):
        np.testing.assert_array_equal(_band(getattr(result, name)), _band(getattr(whole, name)),
                                      err_msg=name)


def _blocks_across(i: dict[str, Any]) -> Any:
    """25 m blocks along the tile's middle row, west half to east half, in its CRS."""
    import geopandas as gpd
    import laspy

    from canopyblocks.readers.survey import source_crs

    with laspy.open(i["truth"]) as r:
        lo, hi = r.header.mins, r.header.maxs
    bx = np.arange(float(lo[0]) + 20.0, float(hi[0]) - 20.0, 25.0)
    by = np.full(bx.size, (float(lo[1]) + float(hi[1])) / 2.0)
    return gpd.GeoDataFrame(
        {"track": "gt1l", "length": 25.0, "block": np.arange(bx.size), "s_start": bx - 12.5,
         "s_end": bx + 12.5, "x": bx, "y": by, "flag": "ok", "ground": 0.0, "top": 20.0,
         "z90": 18.0, "hmax": 20.0, "h90": 18.0},
        geometry=gpd.points_from_xy(bx, by), crs=source_crs(i["truth"]).horizontal)


def run_validate(i: dict[str, Any], folder: Path) -> Any:
    from canopyblocks.validation.footprints import validate_blocks_footprint

    blocks = _blocks_across(i)
    return blocks, validate_blocks_footprint(blocks, i["tiles"], offset=0.0).residuals


def check_validate(case: Any, i: dict[str, Any], result: Any, ws: list[str]) -> None:
    """The tile without ground named; its blocks (beyond the footprint's reach) without a
    ground reference, the others with one."""
    import laspy

    assert any(Path(i["path"]).name in w and "no ground point" in w for w in ws), ws
    blocks, res = result
    cut = float(np.max(laspy.read(i["west"]).x))
    x, g = blocks["x"].to_numpy(float), res["ref_ground"].to_numpy(float)
    assert np.isnan(g[x > cut + 20.0]).all() and (x > cut + 20.0).any()
    assert np.isfinite(g[x < cut - 20.0]).any()


RUNNERS: dict[str, tuple[Callable[..., Any], Callable[..., None]]] = {
    "survey": (run_survey, check_survey), "survey-validate": (run_validate, check_validate),
    "survey-quiet": (run_survey_quiet, check_survey)}


def survey_cases() -> list[Any]:
    from .make_corpus import Case

    same = ("same points", "same file", "part of the points", "is a point of")
    cases = [Case(f"survey-{k}", "survey", _survey(k), warn_words=same) for k in DUPLICATES]
    cases += [Case("survey-header-moved", "survey", _survey("header-moved"),
                   needles=("its header says",), must_refuse=True),
              Case("survey-header-grown", "survey", _survey("header-grown"),
                   needles=("its header says",), forbidden=("resolution", "cells"),
                   must_refuse=True),
              Case("survey-no-ground", "survey", _survey("no-ground"),
                   warn_words=("no ground point",)),
              Case("survey-validate-no-ground", "survey-validate",
                   _survey("validate-no-ground"), warn_words=("no ground point",)),
              Case("survey-validate-no-ground-alone", "survey-validate",
                   _survey("validate-no-ground-alone"), needles=("classed ground",),
                   forbidden=("covers the track",), must_refuse=True),
              Case("survey-feet", "survey-quiet", _survey("feet"),
                   needles=("feet are not supported",), forbidden=("UTM",), must_refuse=True),
              Case("survey-vertical-datums", "survey", _survey("datums"),
                   needles=("different vertical datums",), must_refuse=True),
              Case("survey-vertical-datum-unstated", "survey", _survey("datum-unstated"),
                   warn_words=("states no vertical datum",), must_accept=True)]
    return cases
