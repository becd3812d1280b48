"""Benchmark of the block engine and of the ATL03 file path, on one core.

Run: ``.venv/bin/python bench/bench_blocks.py [--photons 10000000] [--length 25]``

1. A seeded synthetic track (ground, canopy, solar noise; ~15 photons per metre like
   a strong ICESat-2 beam over forest) is built in memory and ``compute_blocks`` is
   timed; peak resident memory (``resource.getrusage`` maxrss, so no tracemalloc
   overhead) is compared with the bytes of the track's photon arrays.
2. A synthetic ATL03-layout file (``outputs.h5_layouts.write_atl03``) is read with
   ``readers.read_atl03`` and with a plain ``h5py`` read of the same datasets.

The last line printed is ``photons_per_s=<engine photons per second>``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
           "NUMEXPR_NUM_THREADS", "VECLIB_MAXIMUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

DENSITY = 15.0  # photons per metre along track


def maxrss_bytes() -> int:
    """Peak resident set size of this process so far (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def synthetic_columns(n: int, seed: int) -> dict[str, np.ndarray]:
    """Photon columns of a forest track, built with few temporaries."""
    rng = np.random.default_rng(seed)
    span = n / DENSITY
    s = rng.random(n)
    s *= span
    s.sort()
    # ground: rolling terrain; photon class: 45 % ground, 40 % canopy, 15 % noise
    h = np.sin(s / 700.0)
    h *= 40.0
    h += 2400.0
    h += 0.02 * s / 100.0
    u = rng.random(n)
    canopy_height = 8.0 + 20.0 * (0.5 + 0.5 * np.sin(s / 90.0))
    h += np.where(u < 0.45, rng.normal(0.0, 0.3, n),
                  np.where(u < 0.85, rng.random(n) * canopy_height,
                           rng.uniform(-60.0, 90.0, n)))
    del u, canopy_height
    return {"s": s, "h": h}


def make_track(n: int, seed: int):  # -> PhotonTrack
    import pyproj

    from canopyblocks import PhotonTrack

    cols = synthetic_columns(n, seed)
    s, h = cols["s"], cols["h"]
    x = s + 500000.0
    y = np.full(n, 4_600_000.0)
    lat = np.full(n, 41.5)
    lon = np.full(n, -106.57)
    t = s / 7000.0
    return PhotonTrack(time=t, lat=lat, lon=lon, h=h, x=x, y=y, s=s, track="gt1l",
                       crs=pyproj.CRS.from_epsg(32613))


def bench_engine(n: int, length: float, seed: int, repeat: int) -> float:
    from canopyblocks.blocks import BlockParams, compute_blocks
    from canopyblocks.errors import SparseBlockWarning

    track = make_track(n, seed)
    arrays = sum(getattr(track, f).nbytes for f in ("time", "lat", "lon", "h", "x", "y", "s"))
    params = BlockParams(lengths=(length,))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SparseBlockWarning)
        compute_blocks(make_track(min(n, 100_000), seed), params)  # warm-up (imports)
        base = maxrss_bytes()
        times, cpu = [], []
        for _ in range(repeat):
            c0, t0 = time.process_time(), time.perf_counter()
            out = compute_blocks(track, params)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    peak = maxrss_bytes()
    best = min(times)
    rate = n / best
    print(f"engine: {n:,} photons, {length:g} m blocks -> {len(out):,} blocks "
          f"({(out['flag'] == 'ok').mean():.1%} ok); best of {repeat}: {best:.3f} s "
          f"= {rate / 1e6:.1f} M photons/s wall (goal >= 20 M/s); CPU time {min(cpu):.3f} s "
          f"= {n / min(cpu) / 1e6:.1f} M/s (wall > CPU means the machine was busy)")
    print(f"memory: photon arrays {arrays / 2**20:.0f} MiB (7 float64 columns); process peak "
          f"RSS {peak / 2**20:.0f} MiB = {peak / arrays:.2f}x the arrays (goal <= 2x); "
          f"engine added {(peak - base) / 2**20:.0f} MiB over the RSS before it "
          f"({(peak - base) / n:.1f} bytes/photon)")
    return rate


def bench_file(n: int, seed: int, repeat: int) -> None:
    import h5py

    from canopyblocks.readers.atl03 import read_atl03

    try:
        from canopyblocks.outputs.h5_layouts import Atl03BeamData, write_atl03
    except ImportError:  # pragma: no cover - the writer is part of the package
        print("file path: canopyblocks.outputs.h5_layouts.write_atl03 missing; skipped")
        return
    cols = synthetic_columns(n, seed)
    s = cols["s"]
    # a track heading north near 41.5 N: 1 m ~ 9.0e-6 degrees of latitude
    lat = 41.5 + s * 9.0e-6
    lon = np.full(n, -106.57) + s * 1.0e-7
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench_atl03.h5"
        t0 = time.perf_counter()
        write_atl03(path, {"gt1l": Atl03BeamData(delta_time=s / 7000.0, lat=lat, lon=lon,
                                                 h=cols["h"], s=s)})
        t_write = time.perf_counter() - t0
        del cols, s, lat, lon
        size = path.stat().st_size

        def raw() -> int:
            with h5py.File(path, "r") as f:
                g = f["gt1l"]
                arrs = [g["heights/" + k][()] for k in ("delta_time", "lat_ph", "lon_ph",
                                                         "h_ph", "dist_ph_along",
                                                         "signal_conf_ph")]
                arrs += [g["geolocation/" + k][()] for k in ("segment_id", "segment_dist_x",
                                                              "segment_ph_cnt", "ph_index_beg",
                                                              "segment_length")]
                return arrs[0].size

        def reader() -> int:
            return len(read_atl03(path, "gt1l"))

        t_raw = min(_timed(raw) for _ in range(repeat))
        t_read = min(_timed(reader) for _ in range(repeat))
    print(f"file: {n:,} photons, {size / 2**20:.0f} MiB ATL03 layout written in {t_write:.2f} s; "
          f"plain h5py read {t_raw:.3f} s ({n / t_raw / 1e6:.1f} M/s), read_atl03 "
          f"{t_read:.3f} s ({n / t_read / 1e6:.1f} M/s): reader at {t_raw / t_read:.0%} of raw "
          "speed (goal >= 80 %; the reader also projects to UTM and builds s)")


def _timed(fn) -> float:  # type: ignore[no-untyped-def]
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--photons", type=int, default=10_000_000)
    ap.add_argument("--length", type=float, default=25.0, help="block length, m")
    ap.add_argument("--file-photons", type=int, default=None,
                    help="photons in the ATL03 file test (default: --photons)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed", type=int, default=20141001)
    ap.add_argument("--skip-file", action="store_true", help="engine only")
    a = ap.parse_args(argv)
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}, one thread")
    rate = bench_engine(a.photons, a.length, a.seed, a.repeat)
    if not a.skip_file:
        bench_file(a.file_photons or a.photons, a.seed, a.repeat)
    print(f"photons_per_s={rate:.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
