"""Benchmark: co-registration's false detections, its error against a known offset, speed.

Photons are simulated (the project's simulator, ICESat-2 13 m footprints, default
parameters) along tracks over the bundled airborne tiles; the simulated photons are
exactly geolocated, so the true offset is known: zero as simulated, or the shift this
script inserts. The DTM/DSM are made here with plain numpy (class-2 mean and all-return
maximum per 2 m cell, holes filled from the nearest cell), independent of the code
under test and of PDAL.

1. Zero offset: six parallel beams per (tile, azimuth, seed), searched one by one and
   all together (7 offsets). A false detection is an offset reported ``ok`` that is not
   smaller than its stated uncertainty. Printed: offsets reported ``ok``, false detections.
2. Known offset: the same beams with their reported positions shifted by -4 m along
   track, +6 m across and +0.8 m up. Printed: the share found (``ok``), the median and
   largest horizontal error of those found, and the share whose both components lie
   within one and two stated standard deviations.
3. Speed: a 10 km synthetic track (one target per 0.7 m along a rolling-terrain DTM),
   full search with the checks; the time is printed last.

Usage: python bench/bench_coregistration.py [--quick]
The last line printed is ``coregister_10km_s=<seconds>``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import pyproj  # noqa: E402
from scipy import ndimage  # noqa: E402

from canopyblocks.errors import CanopyBlocksWarning, CoverageError  # noqa: E402
from canopyblocks.photons import PhotonTrack  # noqa: E402
from canopyblocks.readers.las import read_las  # noqa: E402
from canopyblocks.reference.raster_sampling import RasterSurface  # noqa: E402
from canopyblocks.simulate import SimParams, line_through, simulate_photons  # noqa: E402
from canopyblocks.validation.coregistration import coregister, track_direction  # noqa: E402
from canopyblocks.validation.coregistration_targets import (  # noqa: E402
    CoregTargets,
    targets_from_photons,
)

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "als"
TILES = ("lasR_bcts_1.laz", "lidR_Topography.laz", "lidR_MixedConifer.laz", "pyfor_test.laz")
RES = 2.0
SHIFT = (-4.0, 6.0, 0.8)  # along, cross, vertical inserted into the reported positions


def grid(x: np.ndarray, y: np.ndarray, z: np.ndarray, bounds: Any, stat: str,
         crs: pyproj.CRS) -> RasterSurface:
    """Class-2 mean or maximum per 2 m cell, holes filled from the nearest cell."""
    x0, y1 = np.floor(bounds[0]), np.ceil(bounds[3])
    nx, ny = int(np.ceil((bounds[2] - x0) / RES)), int(np.ceil((y1 - bounds[1]) / RES))
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


def scene(path: Path) -> dict[str, Any]:
    pts = read_las([path])
    crs = pyproj.CRS(pts.crs)
    bounds = (pts.x.min(), pts.y.min(), pts.x.max(), pts.y.max())
    g = pts.classification == 2
    return {"points": pts, "crs": crs, "bounds": bounds, "name": path.name,
            "dtm": grid(pts.x[g], pts.y[g], pts.z[g], bounds, "mean", crs),
            "dsm": grid(pts.x, pts.y, pts.z, bounds, "max", crs)}


def shifted(t: PhotonTrack, along: float, cross: float, dz: float) -> PhotonTrack:
    """The track as an instrument mis-geolocated by (along, cross, dz) would report it."""
    a = track_direction(t.x, t.y, t.s)
    c = (a[1], -a[0])
    return replace(t, x=t.x + along * a[0] + cross * c[0],
                   y=t.y + along * a[1] + cross * c[1], h=t.h + dz)


def beams(sc: dict[str, Any], seed: int, azimuth: float) -> list[PhotonTrack]:
    """Six parallel beams across the tile (simulator seeds 100 * seed + beam)."""
    b = sc["bounds"]
    along_x = abs(np.sin(np.radians(azimuth))) > 0.5  # the track runs east-west
    span = (b[3] - b[1]) if along_x else (b[2] - b[0])
    out = []
    for i, d in enumerate(np.linspace(-0.35 * span, 0.35 * span, 6)):
        cx, cy = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2
        centre = (cx, cy + d) if along_x else (cx + d, cy)
        tr = line_through(b, azimuth, centre=centre, inset=8.0)
        sim = simulate_photons(sc["points"], tr, SimParams(), seed=100 * seed + i)
        out.append(sim.photon_track(0, name=f"gt{i}"))
    return out


def search(sc: dict[str, Any], ts: list[PhotonTrack]) -> dict[str, Any]:
    targets = CoregTargets.concat([targets_from_photons(t, sc["crs"], track_index=i)
                                   for i, t in enumerate(ts)])
    return coregister(targets, sc["dtm"], sc["dsm"]).offsets


def accuracy(seeds: range, azimuths: tuple[float, ...]) -> None:
    zero_n = zero_ok = zero_false = 0
    known_n = 0
    found: list[tuple[float, float, float, float, bool]] = []  # errors, sds, joint?
    for name in TILES:
        sc = scene(DATA / name)
        for az in azimuths:
            for seed in seeds:
                ts = beams(sc, seed, az)
                try:
                    zero = search(sc, ts)
                except CoverageError as exc:
                    print(f"{name} az {az:g} seed {seed}: refused ({exc})")
                    continue
                known = search(sc, [shifted(t, *SHIFT) for t in ts])
                for key, o in zero.items():
                    zero_n += 1
                    size = float(np.hypot(o.along_track, o.cross_track))
                    sd = float(np.hypot(o.along_track_sd, o.cross_track_sd))
                    zero_ok += int(o.determined)
                    zero_false += int(o.determined and not size < sd)
                    k = known[key]
                    known_n += 1
                    ea, ec = k.along_track + SHIFT[0], k.cross_track + SHIFT[1]
                    if k.determined:
                        found.append((ea, ec, k.along_track_sd, k.cross_track_sd,
                                      key == "all"))
                    if key == "all":
                        print(f"{name} az {az:g} seed {seed} all: zero {o.status} "
                              f"({o.along_track:+.2f} {o.cross_track:+.2f} +-{sd:.2f}, score "
                              f"{o.heldout_t:+.1f}); known {k.status} error {ea:+.2f} "
                              f"{ec:+.2f} (sd {k.along_track_sd:.2f} {k.cross_track_sd:.2f}, "
                              f"score {k.heldout_t:+.1f}); detectable {o.detectable_along:.1f}/"
                              f"{o.detectable_cross:.1f} m", flush=True)
    f = np.array(found, dtype=float).reshape(-1, 5)
    herr = np.hypot(f[:, 0], f[:, 1])
    joint = f[:, 4] > 0
    in1 = (np.abs(f[:, 0]) <= f[:, 2]) & (np.abs(f[:, 1]) <= f[:, 3])
    in2 = (np.abs(f[:, 0]) <= 2 * f[:, 2]) & (np.abs(f[:, 1]) <= 2 * f[:, 3])

    def pct(v: np.ndarray) -> str:
        return f"{100 * v.mean():.0f} %" if v.size else "n/a"

    def med(v: np.ndarray) -> str:
        return f"{np.median(v):.2f}" if v.size else "nan"

    print(f"zero offset: {zero_n} offsets (single beams and six together), reported ok "
          f"{zero_ok}, false detections (ok, and not smaller than the uncertainty) "
          f"{zero_false}")
    print(f"known offset ({SHIFT[0]:+g} along, {SHIFT[1]:+g} across, {SHIFT[2]:+g} up): found "
          f"{len(f)} of {known_n} ({int(joint.sum())} joint, {int((~joint).sum())} single "
          f"beams); horizontal error median {med(herr)} m (joint {med(herr[joint])} m), max "
          f"{herr.max() if herr.size else float('nan'):.2f} m; both components within 1 sd "
          f"{pct(in1)}, within 2 sd {pct(in2)}")
    print(f"coregister_zero_offset_false_detection_rate={zero_false / max(zero_n, 1):.3f}")
    print(f"coregister_known_offset_found_rate={len(f) / max(known_n, 1):.3f}")
    print(f"coregister_known_offset_median_error_m={med(herr)}")
    print(f"coregister_known_offset_within_2sd_rate={in2.mean() if in2.size else float('nan'):.3f}")


def speed() -> float:
    crs = pyproj.CRS("EPSG:32612")
    length, width = 10_000.0, 200.0
    xs = np.arange(0.0, width, RES)
    ys = np.arange(0.0, length, RES)
    xx, yy = np.meshgrid(xs, ys[::-1])
    z = 1500 + 30 * np.sin(yy / 400.0) + 12 * np.cos(xx / 37.0 + yy / 250.0) + 4 * np.sin(yy / 55.0)
    dtm = RasterSurface(z, 0.0, length, RES, RES, crs)
    s = np.arange(0.0, length - 40, 0.7) + 20
    x = np.full_like(s, width / 2)
    zz = dtm.bilinear(x, s)
    rng = np.random.default_rng(0)
    t = CoregTargets(x=x + 3.0, y=s - 2.0, z=zz + 0.5 + rng.normal(0, 0.3, s.size), s=s,
                     kind=np.zeros(s.size, np.int8), track=np.full(s.size, "gt1r", object),
                     group=(s // 10).astype(np.int64), crs=crs)
    t0 = time.perf_counter()
    off = coregister(t, dtm).offsets["all"]
    dt = time.perf_counter() - t0
    print(f"10 km track, {s.size} targets moved 3 m east, 2 m south, 0.5 m up: found along "
          f"{off.along_track:+.2f} cross {off.cross_track:+.2f} vertical {off.vertical:+.2f} "
          f"(expected +2, -3, -0.5) {off.status} in {dt:.2f} s")
    return dt


def main() -> None:
    quick = "--quick" in sys.argv
    seeds = range(2) if quick else range(5)
    azimuths = (10.0,) if quick else (10.0, 100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CanopyBlocksWarning)
        accuracy(seeds, azimuths)
    dt = speed()
    print(f"coregister_10km_s={dt:.2f}")


if __name__ == "__main__":
    main()
