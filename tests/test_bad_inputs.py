"""A demanding user's bad-input sweep over every command (run as a subprocess).

Each case builds a broken input from the real samples (truncated LAZ/HDF5, no CRS, US
feet, tiles off the track, block tables without CRS or layer, rasters on other grids,
without CRS, not covering the blocks, all nodata, photon tables with NaN/no rows/missing
columns, bad numbers, unusable output paths) and asserts: exit status 2, exactly one
``canopyblocks: error:`` line naming the file or value, no traceback, and no output or
``*.part*`` file left behind.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import h5py
import laspy
import numpy as np
import pandas as pd
import pyproj
import pytest
import rasterio

ATL03 = "icesat2/vegr_atl03_clip.h5"
TOPO = "als/lidR_Topography.laz"  # EPSG:2949, 286 x 286 m, classes 1, 2, 9
CONIFER = "als/lidR_MixedConifer.laz"  # EPSG:26912, 90 x 90 m


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "canopyblocks", "-q", *args],
                          capture_output=True, text=True, timeout=600, cwd=cwd)


def files_under(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def assert_bad_input(r: subprocess.CompletedProcess[str], *needles: str) -> str:
    """Exit 2, one ``canopyblocks: error:`` line (warnings may precede it), no traceback."""
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("canopyblocks: error:")]
    assert len(errors) == 1, r.stderr
    assert lines[-1] == errors[0], r.stderr  # the error is the last word
    assert all(ln.startswith("canopyblocks: ") for ln in lines), r.stderr
    for n in needles:
        assert n.lower() in errors[0].lower(), (n, errors[0])
    return errors[0]


# --- inputs derived from the real samples -------------------------------------------------


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, sample) -> dict[str, Path]:
    """Broken (and a few good) inputs, built once; never modified by the tests."""
    d = tmp_path_factory.mktemp("inputs")
    p: dict[str, Path] = {}
    atl03 = sample(ATL03)
    p["atl03"] = atl03
    p["topo"] = sample(TOPO)
    p["conifer"] = sample(CONIFER)
    raw = sample(TOPO).read_bytes()
    (d / "truncated.laz").write_bytes(raw[: len(raw) // 2])
    (d / "header_only.laz").write_bytes(raw[:200])
    (d / "not_las.laz").write_text("this is not a point cloud\n")
    las = laspy.read(sample(TOPO))
    src_crs = las.header.parse_crs()
    x0, y0 = float(las.x.min()), float(las.y.min())

    def write_las(path: Path, x, y, z, cls, crs: pyproj.CRS | None) -> None:
        h = laspy.LasHeader(point_format=3, version="1.4")
        h.offsets = [float(np.floor(np.min(x))) if len(x) else 0.0,
                     float(np.floor(np.min(y))) if len(y) else 0.0, 0.0]
        h.scales = [0.01, 0.01, 0.01]
        if crs is not None:
            h.add_crs(crs)
        out = laspy.LasData(h)
        out.x, out.y, out.z = x, y, z
        out.classification = cls
        out.write(path)

    xs, ys, zs = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
    cls = np.asarray(las.classification)
    write_las(d / "nocrs.laz", xs, ys, zs, cls, None)
    # the same survey shifted into New York, in US survey feet
    write_las(d / "feet.laz", xs - x0 + 980_000.0, ys - y0 + 200_000.0, zs, cls,
              pyproj.CRS.from_epsg(2263))
    write_las(d / "empty.laz", np.zeros(0), np.zeros(0), np.zeros(0),
              np.zeros(0, np.uint8), src_crs)
    # no class-2 point at all: no terrain
    write_las(d / "unclassified.laz", xs, ys, zs, np.ones_like(cls), src_crs)
    p.update({k: d / f"{k}.laz" for k in ("truncated", "header_only", "not_las", "nocrs",
                                            "feet", "empty", "unclassified")})

    # ATL03: truncated, a beam emptied of photons
    a = atl03.read_bytes()
    (d / "atl03_truncated.h5").write_bytes(a[: len(a) // 3])
    p["atl03_truncated"] = d / "atl03_truncated.h5"

    # photon tables
    rng = np.random.default_rng(5)
    n = 400
    s = np.sort(rng.uniform(0, 200, n))
    base = pd.DataFrame({"x": 500_000.0 + s, "y": np.full(n, 4_000_000.0),
                         "z": 100 + rng.uniform(0, 20, n)})
    nan = base.copy()
    nan["z"] = np.nan
    nan.to_csv(d / "photons_nan.csv", index=False)
    base.iloc[:0].to_csv(d / "photons_empty.csv", index=False)
    base.drop(columns="z").to_csv(d / "photons_noz.csv", index=False)
    (d / "photons_headeronly.csv").write_text("")
    base.to_csv(d / "photons_ok.csv", index=False)
    p.update({k: d / f"{k}.csv" for k in ("photons_ok", "photons_nan", "photons_empty", "photons_noz",
                                            "photons_headeronly")})

    # a good simulated chain over the Topography tile: blocks + rasters to break
    good = d / "good"
    r = run_cli("run", str(sample(TOPO)), "-o", str(good), "--realisations", "0",
                "--length", "25")
    assert r.returncode == 0, r.stderr
    p["blocks"] = good / "blocks.gpkg"
    p["sim_atl03"] = good / "photons_atl03.h5"
    for k in ("dtm", "dsm_max", "dsm_p90"):
        p[k] = good / "rasters" / f"{k}.tif"
    import geopandas as gpd

    blocks = gpd.read_file(p["blocks"], layer="blocks")
    pd.DataFrame(blocks.drop(columns="geometry")).to_csv(d / "blocks.csv", index=False)
    p["blocks_csv"] = d / "blocks.csv"
    blocks.to_file(d / "wrong_layer.gpkg", layer="something_else", driver="GPKG")
    p["wrong_layer"] = d / "wrong_layer.gpkg"
    # pyogrio, as canopyblocks writes: geopandas 0.14's default engine (fiona) warns on an
    # empty layer
    blocks.iloc[:0].to_file(d / "no_blocks.gpkg", layer="blocks", driver="GPKG",
                            engine="pyogrio")
    p["no_blocks"] = d / "no_blocks.gpkg"
    # the same blocks 50 km away: the rasters do not cover them
    far = blocks.copy()
    far["geometry"] = far.geometry.translate(50_000, 0)
    far["x"] = far["x"] + 50_000
    far.to_file(d / "far_blocks.gpkg", layer="blocks", driver="GPKG")
    p["far_blocks"] = d / "far_blocks.gpkg"

    with rasterio.open(p["dtm"]) as src:
        prof, data = src.profile, src.read(1)
    nodata = prof["nodata"]
    with rasterio.open(d / "dtm_nodata.tif", "w", **prof) as dst:
        dst.write(np.full_like(data, nodata), 1)
    prof_nocrs = dict(prof, crs=None)
    with rasterio.open(d / "dtm_nocrs.tif", "w", **prof_nocrs) as dst:
        dst.write(data, 1)
    t = prof["transform"]
    prof_shift = dict(prof, transform=rasterio.Affine(t.a, t.b, t.c + 1.0, t.d, t.e, t.f))
    with rasterio.open(d / "dtm_shifted.tif", "w", **prof_shift) as dst:
        dst.write(data, 1)
    with rasterio.open(d / "dtm_nan.tif", "w", **dict(prof, nodata=None)) as dst:
        dst.write(np.full_like(data, np.nan), 1)
    from rasterio.warp import calculate_default_transform, reproject

    for k in ("dtm", "dsm_max", "dsm_p90"):  # the rasters warped to longitude/latitude
        with rasterio.open(p[k]) as src, warnings.catch_warnings():
            warnings.simplefilter("ignore", PendingDeprecationWarning)  # rasterio uses `*`
            t, w, h = calculate_default_transform(src.crs, "EPSG:4326", src.width,
                                                  src.height, *src.bounds)
            with rasterio.open(d / f"{k}_geo.tif", "w", **dict(
                    src.profile, crs="EPSG:4326", transform=t, width=w, height=h)) as dst:
                reproject(rasterio.band(src, 1), rasterio.band(dst, 1),
                          src_nodata=src.nodata, dst_nodata=src.nodata)
        p[f"{k}_geo"] = d / f"{k}_geo.tif"
    b = p["dtm"].read_bytes()
    (d / "dtm_truncated.tif").write_bytes(b[: len(b) // 4])
    p.update({k: d / f"{k}.tif" for k in ("dtm_nodata", "dtm_nocrs", "dtm_shifted",
                                            "dtm_nan", "dtm_truncated")})
    return p


@pytest.fixture
def out(tmp_path) -> Path:
    """An empty folder for outputs; the test checks that it stays empty."""
    o = tmp_path / "out"
    o.mkdir()
    return o


def R(inputs: dict[str, Path], *names: str) -> list[str]:  # noqa: N802 - short helper
    # the rasters state the Topography tile's vertical datum (read from its GeoTIFF keys),
    # which the photons' ellipsoidal heights must be tied to: --offset 0 (a case that is
    # about the offset gives its own, which click takes as the last one given)
    return ["--dtm", str(inputs[names[0]]), "--dsm-max", str(inputs[names[1]]),
            "--dsm-p90", str(inputs[names[2]]), "--offset", "0"]


# (command line built from inputs and the output folder, substrings of the error line)
CASES = {
    # info
    "info-truncated-atl03": (lambda i, o: ["info", i["atl03_truncated"]], ["atl03_truncated"]),
    "info-laz": (lambda i, o: ["info", i["topo"]], ["lidR_Topography"]),
    # blocks: numbers
    **{f"blocks-length-{v}": (lambda i, o, v=v: ["blocks", i["atl03"], "--length", v, "-o",
                                                 o / "b.gpkg"], ["length"])
       for v in ("0", "-25", "nan", "inf")},
    "blocks-top-cutoff-0": (lambda i, o: ["blocks", i["atl03"], "--top-cutoff", "0", "-o",
                                          o / "b.gpkg"], ["cutoff"]),
    "blocks-ground-cutoff-nan": (lambda i, o: ["blocks", i["atl03"], "--ground-cutoff", "nan",
                                               "-o", o / "b.gpkg"], ["cutoff"]),
    "blocks-k-0": (lambda i, o: ["blocks", i["atl03"], "--k", "0", "-o", o / "b.gpkg"], ["k"]),
    "blocks-k-nan": (lambda i, o: ["blocks", i["atl03"], "--k", "nan", "-o", o / "b.gpkg"],
                     ["k"]),
    "blocks-min-photons-neg": (lambda i, o: ["blocks", i["atl03"], "--min-photons", "-1", "-o",
                                             o / "b.gpkg"], ["min_photons"]),
    "blocks-s0-nan": (lambda i, o: ["blocks", i["atl03"], "--s0", "nan", "-o", o / "b.gpkg"],
                      ["s0"]),
    "blocks-bbox-bad": (lambda i, o: ["blocks", i["atl03"], "--bbox", "1,2,3", "-o",
                                      o / "b.gpkg"], ["bbox"]),
    "blocks-bbox-miss": (lambda i, o: ["blocks", i["atl03"], "--bbox", "10,10,11,11", "-o",
                                       o / "b.gpkg"], ["vegr_atl03_clip"]),
    "blocks-crs-geographic": (lambda i, o: ["blocks", i["atl03"], "--crs", "EPSG:4326", "-o",
                                            o / "b.gpkg"], ["EPSG:4326"]),
    "blocks-crs-junk": (lambda i, o: ["blocks", i["atl03"], "--crs", "EPSG:999999", "-o",
                                      o / "b.gpkg"], ["999999"]),
    "blocks-channel-on-atl03": (lambda i, o: ["blocks", i["atl03"], "--channel", "x", "-o",
                                              o / "b.gpkg"], ["channel"]),
    # blocks: photon tables
    "blocks-table-nan": (lambda i, o: ["blocks", i["photons_nan"], "--crs", "EPSG:32612",
                                       "-o", o / "b.gpkg"], ["photons_nan"]),
    "blocks-table-empty": (lambda i, o: ["blocks", i["photons_empty"], "--crs", "EPSG:32612",
                                         "-o", o / "b.gpkg"], ["photons_empty"]),
    "blocks-table-headeronly": (lambda i, o: ["blocks", i["photons_headeronly"], "--crs",
                                              "EPSG:32612", "-o", o / "b.gpkg"],
                                ["photons_headeronly"]),
    "blocks-table-noz": (lambda i, o: ["blocks", i["photons_noz"], "--crs", "EPSG:32612",
                                       "-o", o / "b.gpkg"], ["photons_noz"]),
    "blocks-table-nocrs": (lambda i, o: ["blocks", i["photons_ok"], "-o", o / "b.gpkg"],
                           ["photons_ok", "crs"]),
    # blocks: output paths
    "blocks-out-is-dir": (lambda i, o: ["blocks", i["atl03"], "-o", o / "d.gpkg"], ["d.gpkg"]),
    "blocks-out-parent-is-file": (lambda i, o: ["blocks", i["atl03"], "-o", o / "f.txt" / "b.gpkg"],
                                  ["f.txt", "not a folder"]),
    "blocks-profile-parent-is-file": (lambda i, o: ["blocks", i["atl03"], "-o", o / "b.gpkg",
                                                    "--profile", o / "f.txt" / "p.png"],
                                      ["f.txt"]),
    "blocks-atl08-missing": (lambda i, o: ["blocks", i["atl03"], "--atl08", o / "none.h5",
                                           "-o", o / "b.gpkg"], ["none.h5"]),
    "blocks-profile-dir": (lambda i, o: ["blocks", i["atl03"], "--profile", o / "p.png",
                                         "-o", o / "b.gpkg"], ["p.png"]),
    # rasters
    "rasters-truncated": (lambda i, o: ["rasters", i["truncated"], "-o", o / "r"],
                          ["truncated.laz"]),
    "rasters-header-only": (lambda i, o: ["rasters", i["header_only"], "-o", o / "r"],
                            ["header_only.laz"]),
    "rasters-not-las": (lambda i, o: ["rasters", i["not_las"], "-o", o / "r"], ["not_las.laz"]),
    "rasters-missing": (lambda i, o: ["rasters", o / "nope.laz", "-o", o / "r"], ["nope.laz"]),
    "rasters-nocrs": (lambda i, o: ["rasters", i["nocrs"], "-o", o / "r"], ["nocrs.laz", "--crs"]),
    "rasters-feet": (lambda i, o: ["rasters", i["feet"], "-o", o / "r"], ["feet.laz", "foot"]),
    "rasters-empty": (lambda i, o: ["rasters", i["empty"], "-o", o / "r"], ["empty.laz"]),
    "rasters-unclassified": (lambda i, o: ["rasters", i["unclassified"], "-o", o / "r"],
                             ["smrf"]),
    "rasters-bounds-miss": (lambda i, o: ["rasters", i["topo"], "-o", o / "r", "--bounds", "0",
                                          "0", "100", "100"], ["bounds", "do not overlap"]),
    "rasters-bounds-inverted": (lambda i, o: ["rasters", i["topo"], "-o", o / "r", "--bounds",
                                              "100", "100", "0", "0"], ["bounds"]),
    **{f"rasters-resolution-{v}": (lambda i, o, v=v: ["rasters", i["topo"], "-o", o / "r",
                                                      "--resolution", v], ["resolution"])
       for v in ("0", "-2", "nan")},
    "rasters-crs-geographic": (lambda i, o: ["rasters", i["topo"], "-o", o / "r", "--crs",
                                             "EPSG:4326"], ["EPSG:4326"]),
    "rasters-mixed-crs": (lambda i, o: ["rasters", i["topo"], i["conifer"], "-o", o / "r"],
                          ["lidR_MixedConifer"]),
    "rasters-out-is-file": (lambda i, o: ["rasters", i["topo"], "-o", o / "f.txt"], ["f.txt"]),
    # validate
    "validate-csv-nocrs": (lambda i, o: ["validate", i["blocks_csv"], *R(i, "dtm", "dsm_max",
                                         "dsm_p90"), "-o", o / "v.gpkg"], ["blocks.csv", "--table-crs"]),
    "validate-wrong-layer": (lambda i, o: ["validate", i["wrong_layer"], *R(i, "dtm", "dsm_max",
                                           "dsm_p90"), "-o", o / "v.gpkg"],
                             ["wrong_layer.gpkg", "blocks"]),
    "validate-no-blocks": (lambda i, o: ["validate", i["no_blocks"], *R(i, "dtm", "dsm_max",
                                         "dsm_p90"), "-o", o / "v.gpkg"], ["no_blocks.gpkg"]),
    "validate-different-grids": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm_shifted", "dsm_max", "dsm_p90"), "-o", o / "v.gpkg"], ["grid", "dtm_shifted"]),
    "validate-raster-nocrs": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm_nocrs", "dsm_max", "dsm_p90"), "-o", o / "v.gpkg"], ["dtm_nocrs", "CRS"]),
    "validate-raster-truncated": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm_truncated", "dsm_max", "dsm_p90"), "-o", o / "v.gpkg"], ["dtm_truncated"]),
    "validate-raster-missing": (lambda i, o: ["validate", i["blocks"], "--dtm", o / "no.tif",
                                              "--dsm-max", i["dsm_max"], "--dsm-p90",
                                              i["dsm_p90"], "-o", o / "v.gpkg"], ["no.tif"]),
    "validate-not-covered": (lambda i, o: ["validate", i["far_blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "v.gpkg"], ["cover"]),
    "validate-dtm-nodata": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm_nodata", "dsm_max", "dsm_p90"), "-o", o / "v.gpkg"], ["dtm_nodata"]),
    "validate-dtm-nan": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm_nan", "dsm_max", "dsm_p90"), "-o", o / "v.gpkg"], ["dtm_nan"]),
    **{f"validate-width-{v}": (lambda i, o, v=v: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "--width", v, "-o", o / "v.gpkg"], ["width"])
       for v in ("0", "-2", "nan")},
    "validate-geoid-and-offset": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "--offset", "1", "--geoid", i["dtm"], "-o",
        o / "v.gpkg"], ["--geoid", "--offset"]),
    "validate-offset-nan": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "--offset", "nan", "-o", o / "v.gpkg"], ["offset"]),
    "validate-vcrs-junk": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "--reference-vcrs", "EPSG:0", "-o", o / "v.gpkg"],
        ["EPSG:0"]),
    "validate-rasters-geographic": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm_geo", "dsm_max_geo", "dsm_p90_geo"), "-o", o / "v.gpkg"],
        ["dtm_geo.tif", "not projected"]),
    "validate-blocks-is-atl03": (lambda i, o: ["validate", i["atl03"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "v.gpkg"], ["cannot read", "vegr_atl03"]),
    "validate-datum-mismatch": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90")[:-2], "--reference-vcrs", "EPSG:2949+5713", "-o",
        o / "v.gpkg"], ["--geoid", "--offset"]),
    "validate-slope-nan": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "--slope-threshold", "nan", "-o", o / "v.gpkg"],
        ["slope"]),
    "validate-bad-suffix": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "v.shp"], ["suffix"]),
    "validate-out-is-dir": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "d.gpkg"], ["d.gpkg"]),
    "validate-plots-is-file": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "v.gpkg", "--plots", o / "f.txt"],
        ["f.txt"]),
    "validate-atl08-and-rasters": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "--atl08", i["atl03"], "-o", o / "v.gpkg"],
        ["--atl08"]),
    # calibrate
    "calibrate-not-covered": (lambda i, o: ["calibrate", i["atl03"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "c.csv"], ["cover"]),
    "calibrate-truncated": (lambda i, o: ["calibrate", i["atl03_truncated"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "c.csv"], ["atl03_truncated"]),
    "calibrate-length-0": (lambda i, o: ["calibrate", i["sim_atl03"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "--length", "0", "-o", o / "c.csv"], ["length"]),
    "calibrate-width-0": (lambda i, o: ["calibrate", i["sim_atl03"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "--width", "0", "-o", o / "c.csv"], ["width"]),
    "calibrate-different-grids": (lambda i, o: ["calibrate", i["sim_atl03"], *R(
        i, "dtm_shifted", "dsm_max", "dsm_p90"), "-o", o / "c.csv"], ["grid"]),
    "calibrate-raster-missing": (lambda i, o: ["calibrate", i["sim_atl03"], "--dtm",
                                               o / "no.tif", "--dsm-max", i["dsm_max"],
                                               "--dsm-p90", i["dsm_p90"]], ["no.tif"]),
    "calibrate-raster-truncated": (lambda i, o: ["calibrate", i["sim_atl03"], *R(
        i, "dtm_truncated", "dsm_max", "dsm_p90")], ["dtm_truncated"]),
    "calibrate-raster-nocrs": (lambda i, o: ["calibrate", i["sim_atl03"], *R(
        i, "dtm_nocrs", "dsm_max", "dsm_p90")], ["dtm_nocrs"]),
    "calibrate-rasters-geographic": (lambda i, o: ["calibrate", i["sim_atl03"], *R(
        i, "dtm_geo", "dsm_max_geo", "dsm_p90_geo")], ["dtm_geo.tif", "not projected"]),
    "calibrate-dtm-nodata": (lambda i, o: ["calibrate", i["sim_atl03"], *R(
        i, "dtm_nodata", "dsm_max", "dsm_p90")], ["dtm_nodata"]),
    "calibrate-bad-suffix": (lambda i, o: ["calibrate", i["sim_atl03"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "c.shp"], ["suffix"]),
    # simulate
    **{f"simulate-{k}": (lambda i, o, k=k: ["simulate", i[k], "--azimuth", "10", "-o",
                                            o / "s.h5"], [f"{k}.laz"])
       for k in ("truncated", "header_only", "not_las", "nocrs", "feet")},
    **{f"simulate-{opt.strip('-')}-{v}": (lambda i, o, opt=opt, v=v: [
        "simulate", i["topo"], "--azimuth", "10", opt, v, "-o", o / "s.h5"],
        [opt.strip("-").replace("-", "_")])
       for opt, v in (("--diameter", "0"), ("--diameter", "nan"), ("--shot-spacing", "0"),
                      ("--mean-photons", "nan"), ("--noise-rate", "-1"))},
    "simulate-gedi-diameter": (lambda i, o: ["simulate", i["topo"], "--sensor", "gedi",
                                             "--azimuth", "10", "--diameter", "30", "-o",
                                             o / "s.h5"], ["--diameter", "22 m"]),
    "run-gedi-diameter": (lambda i, o: ["run", i["topo"], "--sensor", "gedi", "--diameter",
                                        "30", "-o", o / "run"], ["--diameter", "22 m"]),
    "simulate-azimuth-nan": (lambda i, o: ["simulate", i["topo"], "--azimuth", "nan", "-o",
                                           o / "s.h5"], ["azimuth"]),
    "simulate-line-off-tiles": (lambda i, o: ["simulate", i["topo"], "--line", "0,0,1,1", "-o",
                                              o / "s.h5"], ["lidR_Topography"]),
    "simulate-out-is-dir": (lambda i, o: ["simulate", i["topo"], "--azimuth", "10", "-o",
                                          o / "d.gpkg"], ["d.gpkg"]),
    "simulate-bad-suffix": (lambda i, o: ["simulate", i["topo"], "--azimuth", "10", "-o",
                                          o / "s.txt"], ["s.txt"]),
    # run
    "run-tiles-miss-track": (lambda i, o: ["run", i["topo"], "--photons", i["atl03"], "-o",
                                           o / "run"], ["cover"]),
    "run-truncated-tile": (lambda i, o: ["run", i["truncated"], "-o", o / "run"],
                           ["truncated.laz"]),
    "run-nocrs-tile": (lambda i, o: ["run", i["nocrs"], "-o", o / "run"], ["nocrs.laz"]),
    "run-feet-tile": (lambda i, o: ["run", i["feet"], "-o", o / "run"], ["feet.laz"]),
    "run-empty-tile": (lambda i, o: ["run", i["empty"], "-o", o / "run"], ["empty.laz"]),
    "run-length-nan": (lambda i, o: ["run", i["topo"], "--length", "nan", "-o", o / "run"],
                       ["length"]),
    "run-diameter-0": (lambda i, o: ["run", i["topo"], "--diameter", "0", "-o", o / "run"],
                       ["diameter"]),
    "run-resolution-0": (lambda i, o: ["run", i["topo"], "--resolution", "0", "-o",
                                       o / "run"], ["resolution"]),
    "run-width-nan": (lambda i, o: ["run", i["topo"], "--width", "nan", "-o", o / "run"],
                      ["width"]),
    "run-out-is-file": (lambda i, o: ["run", i["topo"], "-o", o / "f.txt"], ["f.txt"]),
    "run-out-parent-is-file": (lambda i, o: ["run", i["topo"], "-o", o / "f.txt" / "run"],
                               ["f.txt"]),
    "rasters-out-parent-is-file": (lambda i, o: ["rasters", i["topo"], "-o", o / "f.txt" / "r"],
                                   ["f.txt"]),
    "validate-out-parent-is-file": (lambda i, o: ["validate", i["blocks"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "f.txt" / "v.gpkg"], ["f.txt"]),
    "calibrate-out-parent-is-file": (lambda i, o: ["calibrate", i["sim_atl03"], *R(
        i, "dtm", "dsm_max", "dsm_p90"), "-o", o / "f.txt" / "c.csv"], ["f.txt"]),
    "run-photons-truncated": (lambda i, o: ["run", i["topo"], "--photons",
                                            i["atl03_truncated"], "-o", o / "run"],
                              ["atl03_truncated"]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_exits_2_with_one_line_and_leaves_nothing(inputs, out, case) -> None:
    build, needles = CASES[case]
    # pre-existing things the cases point outputs at (and that must survive untouched)
    (out / "d.gpkg").mkdir()
    (out / "p.png").mkdir()
    (out / "f.txt").write_text("keep me")
    before = files_under(out)
    r = run_cli(*map(str, build(inputs, out)))
    assert_bad_input(r, *needles)
    assert files_under(out) == before
    assert (out / "f.txt").read_text() == "keep me"


def test_output_in_a_read_only_folder(inputs, tmp_path) -> None:
    if os.geteuid() == 0:
        pytest.skip("root ignores folder permissions")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        r = run_cli("blocks", str(inputs["atl03"]), "-o", str(ro / "b.gpkg"))
        assert_bad_input(r, str(ro))
        r = run_cli("run", str(inputs["topo"]), "-o", str(ro / "run"), "--realisations", "0")
        assert_bad_input(r, str(ro))
        assert files_under(ro) == set()
    finally:
        ro.chmod(0o755)


def test_output_in_a_missing_folder_is_created(inputs, tmp_path) -> None:
    """A missing output folder is not an error: it is created (and holds only the output)."""
    target = tmp_path / "a" / "b" / "blocks.csv"
    r = run_cli("blocks", str(inputs["atl03"]), "--beam", "gt1r", "-o", str(target))
    assert r.returncode == 0, r.stderr
    assert files_under(tmp_path / "a") == {"b", "b/blocks.csv"}


def test_atl03_beam_with_zero_photons(inputs, tmp_path) -> None:
    """A beam whose photon datasets are empty: a clear error naming the beam, no output."""
    path = tmp_path / "atl03_empty_beam.h5"
    shutil.copy(inputs["atl03"], path)
    with h5py.File(path, "r+") as f:
        beams = [b for b in f if b.startswith("gt") and "heights" in f[b]]
        beam = beams[0]
        heights = f[beam]["heights"]
        for name in list(heights):
            dset = heights[name]
            if isinstance(dset, h5py.Dataset) and dset.shape and dset.shape[0] > 0:
                shape, dtype = (0, *dset.shape[1:]), dset.dtype
                attrs = dict(dset.attrs)
                del heights[name]
                new = heights.create_dataset(name, shape=shape, dtype=dtype,
                                             maxshape=(None, *shape[1:]))
                for k, v in attrs.items():
                    if k not in ("DIMENSION_LIST", "REFERENCE_LIST", "CLASS", "NAME"):
                        new.attrs[k] = v
        geo = f[beam].get("geolocation")
        if geo is not None and "ph_index_beg" in geo:
            geo["ph_index_beg"][...] = 0
            geo["segment_ph_cnt"][...] = 0
    out = tmp_path / "out"
    out.mkdir()
    r = run_cli("blocks", str(path), "--beam", beam, "-o", str(out / "b.gpkg"))
    assert_bad_input(r, beam)
    assert files_under(out) == set()


def test_mabel_file_with_an_empty_channel(tmp_path) -> None:
    """A MABEL channel with no photons: naming the channel, exit 2, no output."""
    path = tmp_path / "mabel_l2a_empty.h5"
    rng = np.random.default_rng(3)
    n = 2000
    lat = 33.0 + np.linspace(0, 0.01, n)
    lon = np.full(n, -111.0)
    with h5py.File(path, "w") as f:
        for ch, m in ((1, n), (2, 0)):
            g = f.create_group(f"photon/channel{ch:03d}")
            g["delta_time"] = np.linspace(0, 10, m)
            g["elev"] = (1500 + rng.normal(0, 5, m)).astype("f4")
            g["latitude"] = lat[:m]
            g["longitude"] = lon[:m]
            g["flag"] = np.zeros(m, "u1")
            g["photon_id"] = np.ones(m, "u2")
            g["shot_num"] = np.arange(m, dtype="i4")
    out = tmp_path / "out"
    out.mkdir()
    r = run_cli("blocks", str(path), "--channel", "2", "-o", str(out / "b.gpkg"))
    assert_bad_input(r, "channel")
    assert files_under(out) == set()
    r = run_cli("blocks", str(path), "--channel", "7", "-o", str(out / "b.gpkg"))
    assert_bad_input(r, "7")
    assert files_under(out) == set()


def test_run_over_a_tile_with_a_compound_crs(sample, tmp_path) -> None:
    """lidR_MixedConifer.laz declares a vertical CRS: the chain must still work."""
    r = run_cli("run", str(sample(CONIFER)), "-o", str(tmp_path / "run"), "--realisations",
                "0", "--length", "25")
    assert r.returncode == 0, r.stderr


def test_simulate_over_a_las_without_points(inputs, out) -> None:
    r = run_cli("simulate", str(inputs["empty"]), "--azimuth", "10", "-o", str(out / "s.h5"))
    assert_bad_input(r, "empty.laz")
    assert files_under(out) == set()


@pytest.mark.parametrize("fraction", [1.0, 0.5])
def test_atl03_with_nan_heights(inputs, tmp_path, fraction) -> None:
    """All heights NaN: an error naming the beam and file; half NaN: a warning with the
    exact count, and the blocks of the other half."""
    path = tmp_path / "atl03_nan.h5"
    shutil.copy(inputs["atl03"], path)
    with h5py.File(path, "r+") as f:
        h = f["gt1r/heights/h_ph"]
        a = h[...]
        n_nan = int(len(a) * fraction)
        a[:n_nan] = np.nan
        h[...] = a
    out = tmp_path / "out"
    out.mkdir()
    r = run_cli("blocks", str(path), "--beam", "gt1r", "-o", str(out / "b.csv"))
    if fraction == 1.0:
        assert_bad_input(r, "gt1r", "atl03_nan.h5", "h_ph", "none of its")
        assert files_under(out) == set()
    else:
        assert r.returncode == 0, r.stderr
        assert f"dropped {n_nan} of {len(a)} photons" in r.stderr
        assert f"{n_nan} in /gt1r/heights/h_ph" in r.stderr
        blocks = pd.read_csv(out / "b.csv")
        assert len(blocks) > 0 and np.isfinite(blocks.loc[blocks["flag"] == "ok", "top"]).all()


def test_simulated_gedi_states_and_keeps_its_tiles_datum(sample, gedi_l1b, tmp_path) -> None:
    """A GEDI L1B simulated over CGVD28 tiles holds CGVD28 elevations: the file says so on
    its elevations, the footprints, plots and validation use it (``run TILES --photons
    SIM.h5`` was refused as 'ellipsoidal heights against CGVD28' and plots said 'WGS84
    ellipsoid'); a real L1B stays WGS84-ellipsoidal."""
    from canopyblocks.readers.gedi import gedi_vertical_datum
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate.sensor_files import simulate_gedi_to_file
    from canopyblocks.simulate.tracks import line_through
    from canopyblocks.validation.footprints import validate_footprints
    from canopyblocks.workflows.waveforms import footprints_from_l1b

    tile = sample("als/lasR_bcts_1.laz")   # GeoTIFF keys: NAD83 / BC Albers + CGVD28
    pts = read_las([tile])
    l1b = tmp_path / "sim.h5"
    simulate_gedi_to_file(pts, line_through(pts.bounds, 10.0, inset=15.0), l1b, seed=1)
    with h5py.File(l1b) as f:
        beam = next(k for k in f if k.startswith("BEAM"))
        assert f[f"{beam}/geolocation/elevation_bin0"].attrs["vertical_crs"] == "EPSG:5713"
    assert gedi_vertical_datum(l1b) == "EPSG:5713"
    assert gedi_vertical_datum(gedi_l1b) == "EPSG:4979"
    fp, plots = footprints_from_l1b(l1b, plots_dir=tmp_path / "plots", plot_shots=None)
    assert fp.attrs["vertical_datum"] == "EPSG:5713"
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # neither refused nor 'compared as they are'
        val = validate_footprints(fp, [tile])
    assert val.datum == "same", val.datum   # EPSG:5713 both (GEDI's would be refused)
    g = val.stats[(val.stats["metric"] == "ground") & (val.stats["group"] == "all")].iloc[0]
    assert g["n"] >= 2 and abs(g["bias"]) < 1.0, g   # simulated from these very points
    real, _ = footprints_from_l1b(gedi_l1b, beams=["BEAM0101"])
    assert real.attrs["vertical_datum"] == "EPSG:4979"
