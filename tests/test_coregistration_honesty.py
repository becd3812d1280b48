"""Co-registration never invents an offset.

Photons are simulated (the project's simulator) over the bundled airborne tiles; the
simulated photons are exactly geolocated, so the truth is known: no offset as simulated,
or the shift the test inserts into the reported positions. The reference rasters are
made here with plain numpy (class-2 mean and maximum per 2 m cell), independent of the
code under test and of PDAL.

* zero offset, several tiles and seeds: ``undetermined``, or an offset smaller than its
  stated uncertainty;
* a known offset over six beams: found (``ok``) within its 95 % interval (two stated
  standard deviations per component);
* pure noise on textured synthetic terrain: never determined;
* rasters that do not cover the track, or cover too little of it: refused (exit 2, one
  line naming the share of the track's blocks on the rasters);
* ``coregister`` and ``validate --coregister`` give the same offsets for the same file,
  and an undetermined offset is not applied (exit 0, a warning).
"""

from __future__ import annotations

import contextlib
import io
import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyproj
import pytest
from scipy import ndimage

from canopyblocks.errors import CoverageError
from canopyblocks.photons import PhotonTrack
from canopyblocks.readers.las import read_las
from canopyblocks.reference.raster_sampling import RasterSurface
from canopyblocks.simulate import SimParams, line_through, simulate_photons
from canopyblocks.validation.coregistration import CoregParams, coregister, track_direction
from canopyblocks.validation.coregistration_targets import CoregTargets, targets_from_photons

pytestmark = pytest.mark.filterwarnings("ignore::canopyblocks.errors.SparseBlockWarning")

RES = 2.0


def _grid(x, y, z, bounds, stat, crs) -> RasterSurface:
    x0, y1 = np.floor(bounds[0]), np.ceil(bounds[3])
    nx = int(np.ceil((bounds[2] - x0) / RES))
    ny = int(np.ceil((y1 - bounds[1]) / RES))
    k = (np.clip(((y1 - y) // RES).astype(int), 0, ny - 1) * nx
         + np.clip(((x - x0) // RES).astype(int), 0, nx - 1))
    if stat == "mean":
        n = np.bincount(k, minlength=nx * ny)
        v = np.where(n > 0, np.bincount(k, z, minlength=nx * ny) / np.maximum(n, 1), np.nan)
    else:
        v = np.full(nx * ny, -np.inf)
        np.maximum.at(v, k, z)
        v[~np.isfinite(v)] = np.nan
    v = v.reshape(ny, nx)
    idx = ndimage.distance_transform_edt(np.isnan(v), return_distances=False,
                                         return_indices=True)
    return RasterSurface(v[tuple(idx)], x0, y1, RES, RES, crs)


_SCENES: dict[str, dict] = {}


def _scene(sample, name: str) -> dict:
    if name not in _SCENES:
        pts = read_las([sample(f"als/{name}")])
        crs = pyproj.CRS(pts.crs)
        b = (pts.x.min(), pts.y.min(), pts.x.max(), pts.y.max())
        g = pts.classification == 2
        _SCENES[name] = {"points": pts, "crs": crs, "bounds": b,
                         "dtm": _grid(pts.x[g], pts.y[g], pts.z[g], b, "mean", crs),
                         "dsm": _grid(pts.x, pts.y, pts.z, b, "max", crs)}
    return _SCENES[name]


def _track(sc: dict, seed: int, azimuth: float = 10.0, dx: float = 0.0,
           name: str = "gt1r") -> PhotonTrack:
    b = sc["bounds"]
    centre = ((b[0] + b[2]) / 2 + dx, (b[1] + b[3]) / 2)
    tr = line_through(b, azimuth, centre=centre, inset=8.0)
    return simulate_photons(sc["points"], tr, SimParams(), seed=seed).photon_track(0, name=name)


def _shifted(t: PhotonTrack, along: float, cross: float, dz: float) -> PhotonTrack:
    a = track_direction(t.x, t.y, t.s)
    c = (a[1], -a[0])
    return replace(t, x=t.x + along * a[0] + cross * c[0],
                   y=t.y + along * a[1] + cross * c[1], h=t.h + dz)


def _targets(tracks: list[PhotonTrack], crs) -> CoregTargets:
    return CoregTargets.concat([targets_from_photons(t, crs, track_index=i)
                                for i, t in enumerate(tracks)])


@pytest.mark.parametrize("tile", ["lasR_bcts_1.laz", "lidR_Topography.laz", "pyfor_test.laz"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_zero_offset_is_undetermined_or_within_its_uncertainty(sample, tile, seed):
    sc = _scene(sample, tile)
    t = _track(sc, seed, azimuth=10.0 if seed % 2 == 0 else 100.0)
    for name, o in coregister(_targets([t], sc["crs"]), sc["dtm"], sc["dsm"]).offsets.items():
        size = float(np.hypot(o.along_track, o.cross_track))
        sd = float(np.hypot(o.along_track_sd, o.cross_track_sd))
        assert (not o.determined) or size < sd, (name, o.along_track, o.cross_track, sd)
        if not o.determined:
            assert o.status == "undetermined" and o.reason != "ok"
        # the minimum detectable offset is stated, and it is not below the uncertainty
        assert o.detectable_along >= o.along_track_sd > 0
        assert o.detectable_cross >= o.cross_track_sd > 0


@pytest.mark.slow
@pytest.mark.parametrize("tile,seed", [("lasR_bcts_1.laz", 0), ("lidR_Topography.laz", 1)])
def test_known_offset_is_found_within_its_uncertainty(sample, tile, seed):
    """-4 m along, +6 m across, +0.8 m up inserted into six simulated beams."""
    sc = _scene(sample, tile)
    w = sc["bounds"][2] - sc["bounds"][0]
    beams = [_track(sc, 100 * seed + i, dx=dx, name=f"gt{i}")
             for i, dx in enumerate(np.linspace(-0.35 * w, 0.35 * w, 6))]
    moved = [_shifted(t, -4.0, 6.0, 0.8) for t in beams]
    o = coregister(_targets(moved, sc["crs"]), sc["dtm"], sc["dsm"]).offsets["all"]
    assert o.determined, o.reason
    # the shift to add is +4 along, -6 across; 95 % interval: two standard deviations
    assert abs(o.along_track - 4.0) <= 2 * o.along_track_sd, (o.along_track, o.along_track_sd)
    assert abs(o.cross_track + 6.0) <= 2 * o.cross_track_sd, (o.cross_track, o.cross_track_sd)
    assert o.heldout_t > o.heldout_critical
    assert o.heldout_rmse_after < o.heldout_rmse_before
    # the same beams unshifted: nothing is determined for them
    zero = coregister(_targets(beams, sc["crs"]), sc["dtm"], sc["dsm"]).offsets["all"]
    assert not zero.determined or np.hypot(zero.along_track, zero.cross_track) < np.hypot(
        zero.along_track_sd, zero.cross_track_sd)


@pytest.mark.slow
def test_pure_noise_is_never_determined():
    """Heights = a textured DTM + noise, exactly geolocated: 12 tracks, no offset found."""
    crs = pyproj.CRS(32610)
    yy, xx = np.mgrid[0:300, 0:150] * RES
    z = 500 + 6 * np.sin(xx / 23.0) * np.cos(yy / 31.0) + 3 * np.sin(yy / 9.0 + xx / 13.0)
    dtm = RasterSurface(z.astype(float), 0.0, 600.0, RES, RES, crs)
    found = 0
    for seed in range(12):
        rng = np.random.default_rng(seed)
        s = np.sort(rng.uniform(20, 580, 800))
        x = 150.0 + 0.1 * (s - 300) + rng.normal(0, 0.1, s.size)
        y = 600.0 - s
        zz = dtm.bilinear(x, y) + rng.standard_t(3, s.size) * 1.5
        t = CoregTargets(x, y, zz, s, np.zeros(s.size, np.int8),
                         np.full(s.size, "gt1l", dtype=object), (s // 10).astype(np.int64), crs)
        found += coregister(t, dtm, params=CoregParams(bootstrap=50)).offsets["all"].determined
    assert found <= 1, f"{found} of 12 noise-only tracks got a determined offset"


def test_rasters_that_miss_the_track_are_refused():
    crs = pyproj.CRS(32610)
    dtm = RasterSurface(np.random.default_rng(0).normal(50, 3, (100, 100)), 0.0, 200.0, RES,
                        RES, crs)
    s = np.arange(0.0, 400.0, 0.5)
    # a track running off the raster: 190 of its 400 m lie over it, then 40 m only
    for y0, covered in ((0.0, True), (160.0, False), (1e5, False)):
        x = np.full(s.size, 100.0)
        y = y0 + 10.0 + s
        t = CoregTargets(x, y, np.full(s.size, 50.0), s, np.zeros(s.size, np.int8),
                         np.full(s.size, "gt2l", dtype=object), (s // 10).astype(np.int64), crs)
        if covered:
            coregister(t, dtm, params=CoregParams(bootstrap=10))
            continue
        with pytest.raises(CoverageError) as err:
            coregister(t, dtm, params=CoregParams(bootstrap=10))
        msg = str(err.value)
        n_on = int(np.unique((s // 10)[np.isfinite(dtm.bilinear(x, y))]).size)
        assert f"cover {n_on} of 40 blocks ({100 * n_on / 40:.0f} %)" in msg, msg
        assert "\n" not in msg


# ---- the command line -------------------------------------------------------------------


def _cli(args: list[str]) -> tuple[int, str, str]:
    from canopyblocks.cli import cli
    from canopyblocks.cli.common import run_main

    out, err = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stdout(out), \
            contextlib.redirect_stderr(err):
        warnings.simplefilter("default")
        code = run_main(cli, args)
    return code, out.getvalue(), err.getvalue()


def _tif(surface: RasterSurface, path: Path, dx: float = 0.0) -> Path:
    import rasterio
    from rasterio.transform import Affine

    with rasterio.open(path, "w", driver="GTiff", width=surface.values.shape[1],
                       height=surface.values.shape[0], count=1, dtype="float32",
                       crs=surface.crs.to_wkt(), nodata=-9999,
                       transform=Affine(RES, 0.0, surface.x0 + dx, 0.0, -RES,
                                        surface.y0)) as dst:
        dst.write(surface.values.astype("float32"), 1)
    return path


@pytest.fixture(scope="module")
def files(sample, tmp_path_factory):
    """Blocks and photons of one unshifted simulated track, the rasters, and rasters
    moved 50 km east (no overlap) and 300 m east (a sliver of overlap)."""
    from canopyblocks.blocks import BlockParams
    from canopyblocks.outputs.tables import write_layers
    from canopyblocks.simulate.writers import write_simulation_atl03
    from canopyblocks.workflows.blocks import run_blocks

    d = tmp_path_factory.mktemp("coreg_cli")
    sc = _scene(sample, "lasR_bcts_1.laz")
    tr = line_through(sc["bounds"], 10.0, inset=8.0)
    sim = simulate_photons(sc["points"], tr, SimParams(), seed=3)
    h5 = write_simulation_atl03(sim, d / "sim.h5")
    blocks, _ = run_blocks([sim.photon_track(0)], BlockParams(lengths=(10.0,)))
    gpkg = d / "blocks.gpkg"
    write_layers({"blocks": blocks}, gpkg)
    width = sc["bounds"][2] - sc["bounds"][0]
    return {"h5": h5, "blocks": gpkg, "dir": d,
            "dtm": _tif(sc["dtm"], d / "dtm.tif"), "dsm": _tif(sc["dsm"], d / "dsm.tif"),
            "far": _tif(sc["dtm"], d / "far.tif", dx=50_000.0),
            "far_dsm": _tif(sc["dsm"], d / "far_dsm.tif", dx=50_000.0),
            "sliver": _tif(sc["dtm"], d / "sliver.tif", dx=width - 12.0),
            "sliver_dsm": _tif(sc["dsm"], d / "sliver_dsm.tif", dx=width - 12.0)}


def test_cli_refuses_rasters_that_miss_the_track(files):
    for dtm in ("far", "sliver"):
        out = files["dir"] / f"{dtm}.json"
        code, _, err = _cli(["coregister", str(files["h5"]), "--dtm", str(files[dtm]),
                             "--offset", "0", "--crs", "EPSG:3005", "-o", str(out)])
        assert code == 2, err
        lines = [ln for ln in err.splitlines() if ln.startswith("canopyblocks: error:")]
        assert len(lines) == 1 and "Traceback" not in err, err
        assert "blocks (0 %)" in lines[0] if dtm == "far" else "blocks (" in lines[0]
        assert "widen" not in err and not out.exists()
        dsm = str(files[f"{dtm}_dsm"])
        code, _, err = _cli(["validate", str(files["blocks"]), "--dtm", str(files[dtm]),
                             "--dsm-max", dsm, "--dsm-p90", dsm,
                             "--offset", "0", "--coregister", "-o",
                             str(files["dir"] / f"{dtm}.gpkg")])
        assert code == 2 and "cover" in err and "Traceback" not in err, err
        assert not (files["dir"] / f"{dtm}.gpkg").exists()


def test_coregister_equals_validate_coregister(files):
    d = files["dir"]
    common = ["--dtm", str(files["dtm"]), "--dsm-max", str(files["dsm"]), "--offset", "0"]
    code, out, err = _cli(["coregister", str(files["blocks"]), *common,
                           "-o", str(d / "c.json")])
    assert code == 0, err
    code2, _, err2 = _cli(["validate", str(files["blocks"]), *common, "--dsm-p90",
                           str(files["dsm"]), "--width", "13", "--coregister",
                           "-o", str(d / "v.gpkg")])
    assert code2 == 0, err2
    a = json.loads((d / "c.json").read_text())
    b = json.loads((d / "v_offsets.json").read_text())
    assert {k: v for k, v in a.items() if k != "_meta"} == \
        {k: v for k, v in b.items() if k != "_meta"}
    # unshifted photons: undetermined, said in a warning, and nothing applied
    if not a["all"]["determined"]:
        assert "undetermined" in err and "undetermined" in err2, (err, err2)
        from canopyblocks.outputs.tables import gpkg_layer_names

        assert "stats_uncorrected" not in gpkg_layer_names(d / "v.gpkg")
    else:
        e = a["all"]
        assert np.hypot(e["along_track"], e["cross_track"]) < np.hypot(
            e["uncertainty"]["along_track"], e["uncertainty"]["cross_track"])


def test_undetermined_photon_offset_is_a_warning_not_an_error(files):
    out = files["dir"] / "photons.json"
    code, stdout, err = _cli(["coregister", str(files["h5"]), "--dtm", str(files["dtm"]),
                              "--dsm-max", str(files["dsm"]), "--offset", "0", "--crs",
                              "EPSG:3005", "-o", str(out)])
    assert code == 0, err
    doc = json.loads(out.read_text())
    e = doc["all"]
    assert e["status"] in ("ok", "undetermined")
    assert set(e["minimum_detectable"]) == {"along_track", "cross_track"}
    assert e["coverage"]["share"] == 1.0
    if e["status"] == "undetermined":
        assert "canopyblocks: warning:" in err and "undetermined" in err
        assert "undetermined" in stdout
    for k in ("DESIGN", "issue", "seed 0"):
        assert k not in err + stdout


def test_a_track_off_the_rasters_is_undetermined_beside_covered_ones(tmp_path):
    """Two tracks, one 10 km away from the raster: that one is undetermined (naming its
    coverage), the joint search goes on, and the cost plot draws both."""
    from canopyblocks.outputs.coregistration_plot import write_cost_surfaces

    crs = pyproj.CRS(32610)
    yy, xx = np.mgrid[0:300, 0:150] * RES
    z = 500 + 6 * np.sin(xx / 23.0) * np.cos(yy / 31.0)
    dtm = RasterSurface(z.astype(float), 0.0, 600.0, RES, RES, crs)
    rng = np.random.default_rng(1)
    parts = []
    for i, x0 in enumerate((150.0, 10_150.0)):
        s = np.sort(rng.uniform(20, 580, 800))
        x = np.full(s.size, x0)
        y = 600.0 - s
        zz = dtm.bilinear(np.full(s.size, 150.0), y) + rng.normal(0, 0.3, s.size)
        parts.append(CoregTargets(x, y, zz, s, np.zeros(s.size, np.int8),
                                  np.full(s.size, f"gt{i + 1}l", dtype=object),
                                  (s // 10).astype(np.int64) + 10_000_000 * i, crs))
    res = coregister(CoregTargets.concat(parts), dtm, params=CoregParams(bootstrap=20))
    off = res.offsets["gt2l"]
    assert not off.determined and "cover 0 of" in off.reason
    assert np.isnan(off.along_track)
    assert res.offsets["gt1l"].coverage is not None
    assert res.offsets["gt1l"].coverage.share == 1.0
    png = write_cost_surfaces(res, tmp_path / "cost.png")
    assert png.stat().st_size > 5_000


def test_validate_coregister_from_photons_equals_coregister(files):
    """The README's pair: ``coregister PHOTONS`` and ``validate BLOCKS --coregister
    --coregister-photons PHOTONS`` report the same offsets."""
    d = files["dir"]
    common = ["--dtm", str(files["dtm"]), "--dsm-max", str(files["dsm"]), "--offset", "0"]
    code, _, err = _cli(["coregister", str(files["h5"]), *common, "--crs", "EPSG:3005",
                         "-o", str(d / "p.json")])
    assert code == 0, err
    code, _, err = _cli(["validate", str(files["blocks"]), *common, "--dsm-p90",
                         str(files["dsm"]), "--width", "13", "--coregister",
                         "--coregister-photons", str(files["h5"]), "-o", str(d / "vp.gpkg")])
    assert code == 0, err
    a = json.loads((d / "p.json").read_text())
    b = json.loads((d / "vp_offsets.json").read_text())
    assert {k: v for k, v in a.items() if k != "_meta"} == \
        {k: v for k, v in b.items() if k != "_meta"}
    if not b["all"]["determined"]:   # the warning names the file the offsets came from
        said = [ln for ln in err.splitlines() if "warning: " in ln and "undetermined" in ln]
        assert said and all(str(files["h5"]) in ln and str(files["blocks"]) not in ln
                            for ln in said), err
    code, _, err = _cli(["validate", str(files["blocks"]), *common, "--coregister-photons",
                         str(files["h5"]), "-o", str(d / "vq.gpkg")])
    assert code == 2 and "--coregister" in err and not (d / "vq.gpkg").exists(), err


@pytest.mark.pdal
@pytest.mark.slow
def test_run_coregister_says_what_it_applied(files, pdal_bin, sample, tmp_path):
    """``run --coregister`` on unshifted photons: the report must not claim an offset was
    applied when it is undetermined, and carries no internal section numbers."""
    from canopyblocks.outputs.tables import gpkg_layer_names

    out = tmp_path / "chain"
    code, _, err = _cli(["run", str(sample("als/lasR_bcts_1.laz")), "--photons",
                         str(files["h5"]), "--offset", "0", "--coregister", "-o", str(out)])
    assert code == 0, err
    doc = json.loads((out / "offsets.json").read_text())
    html = (out / "report.html").read_text()
    section = html[html.index("Co-registration"):]
    assert "DESIGN" not in section
    layers = gpkg_layer_names(out / "validation.gpkg")
    if doc["all"]["determined"]:
        assert "was applied horizontally" in section and "stats_uncorrected" in layers
    else:
        assert "was applied" not in section and "not applied" in section
        assert "stats_uncorrected" not in layers
        assert "undetermined" in err and "sim.h5" in err


def test_signed_rank_score_matches_scipy():
    """The held-out test's statistic against scipy's Wilcoxon (normal approximation, tie
    and continuity corrections, zeros dropped, one-sided)."""
    from scipy.special import ndtri
    from scipy.stats import wilcoxon

    from canopyblocks.validation.coregistration_checks import signed_rank_score

    rng = np.random.default_rng(0)
    for n in (8, 22, 60):
        for shift in (-0.5, 0.0, 0.3, 1.0):
            g = np.round(rng.standard_t(3, n) + shift, 1)
            g[:2] = 0.0
            with warnings.catch_warnings():  # the approximation is asked for: scipy 1.9
                warnings.filterwarnings("ignore", "Sample size too small", UserWarning)
                p = wilcoxon(g, alternative="greater", method="approx", correction=True,
                             zero_method="wilcox").pvalue
            assert signed_rank_score(g) == pytest.approx(float(ndtri(1 - p)), abs=1e-9)
    assert np.isnan(signed_rank_score(np.array([1.0, 2.0, 0.0, 0.0, 3.0])))


def test_apply_offset_refuses_an_undetermined_offset():
    import geopandas as gpd

    from canopyblocks.errors import InputError
    from canopyblocks.validation.coregistration_offset import CoregOffset
    from canopyblocks.validation.coregistration_targets import apply_offset

    crs = pyproj.CRS(3005)
    table = gpd.GeoDataFrame({"track": ["gt1r"], "x": [885100.0], "y": [629300.0],
                              "ground": [300.0], "top": [320.0]},
                             geometry=gpd.points_from_xy([885100.0], [629300.0]), crs=crs)
    nan = float("nan")
    off = CoregOffset("gt1r", 9.4, 0.0, 9.4, 0.0, 0.0, *([nan] * 5), *([nan] * 4), 10, 0,
                      False, False, "no significant improvement on held-out blocks",
                      crs.to_wkt())
    with pytest.raises(InputError, match="undetermined.*not applied"):
        apply_offset(table, off)
    moved = apply_offset(table, off, force=True)
    assert moved["x"].iloc[0] == pytest.approx(885109.4)
