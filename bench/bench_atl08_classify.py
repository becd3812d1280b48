"""Benchmark (speed): the ATL08-style photon classifier, microseconds per photon.

A synthetic strong beam (Poisson 1.9 signal photons a 0.7 m shot over rolling terrain and a
patchy 2-25 m canopy) with daytime background (``--rate`` MHz, default 1.5, uniform in a
200 m telemetry window around the terrain's 1 km trend) -- about 3.9 photons a shot, as
a daytime ATL03 strong beam. ``classify_photons`` with its defaults and the rate given as
ATL03's ``bckgrd_rate``; best of ``--repeat`` runs, one core, wall and CPU seconds.

Goal: under ~0.5 us a photon, so the 52 M photons of a 6-beam granule (bench_granule) add
well under a minute.

Usage: python bench/bench_atl08_classify.py [--photons 2000000] [--rate 1.5] [--repeat 3]
The last line printed is ``atl08_us_per_photon=<us>`` (best wall time / photons).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import pyproj  # noqa: E402

from canopyblocks.blocks.atl08_classify import classify_photons  # noqa: E402
from canopyblocks.photons import SPEED_OF_LIGHT, BackgroundRate, PhotonTrack  # noqa: E402

SHOT = 0.7  # m between shots
WINDOW = 200.0  # m, telemetry window


def synthetic_beam(n_photons: int, rate_mhz: float, seed: int = 0) -> PhotonTrack:
    """A strong beam of about ``n_photons`` photons (signal + background)."""
    rng = np.random.default_rng(seed)
    noise_per_shot = rate_mhz * 1e6 * 2.0 / SPEED_OF_LIGHT * WINDOW
    n_shots = int(n_photons / (1.9 + noise_per_shot))
    shots = np.arange(n_shots) * SHOT
    trend = 0.02 * shots + 30.0 * np.sin(shots / 5000.0)

    def ground(s: np.ndarray) -> np.ndarray:
        return 0.02 * s + 30.0 * np.sin(s / 5000.0) + 4.0 * np.sin(s / 150.0)

    ss = np.repeat(shots, rng.poisson(1.9, n_shots))
    cover = np.sin(ss / 60.0) + np.sin(ss / 23.0) > -0.5
    can = cover & (rng.random(ss.size) < 0.6)
    top = 14.0 + 10.0 * np.sin(ss / 400.0)
    hs = ground(ss) + np.where(can, rng.uniform(0.15, 1.0, ss.size) * top,
                               rng.normal(0.0, 0.25, ss.size))
    sn = np.repeat(shots, rng.poisson(noise_per_shot, n_shots))
    hn = np.interp(sn, shots, trend) + rng.uniform(-WINDOW / 2, WINDOW / 2, sn.size)
    s = np.concatenate([ss, sn])
    h = np.concatenate([hs, hn])
    order = np.argsort(s, kind="stable")
    s, h = s[order], h[order]
    t = s / 7000.0
    n = s.size
    bg = BackgroundRate(np.arange(0.0, t[-1] + 0.01, 0.005),
                        np.full(np.arange(0.0, t[-1] + 0.01, 0.005).size, rate_mhz * 1e6))
    return PhotonTrack(time=t, lat=np.zeros(n), lon=np.zeros(n), h=h, x=s.copy(),
                       y=np.zeros(n), s=s, track="gt1l", crs=pyproj.CRS.from_epsg(32612),
                       background=bg)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons", type=int, default=2_000_000)
    ap.add_argument("--rate", type=float, default=1.5, help="background rate, MHz")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="print a cProfile of one run")
    args = ap.parse_args()
    track = synthetic_beam(args.photons, args.rate)
    n = len(track)
    if args.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.enable()
        classify_photons(track)
        prof.disable()
        pstats.Stats(prof).sort_stats("cumulative").print_stats(30)
    walls, cpus = [], []
    for _ in range(args.repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        res = classify_photons(track)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    counts = res.counts()
    print(f"{n:,} photons ({n / len(np.unique(track.s)):.2f} a shot), classes {counts}")
    print(f"wall best {min(walls):.2f} s, CPU best {min(cpus):.2f} s; "
          f"52.5 M-photon granule: ~{min(walls) / n * 52.5e6:.0f} s")
    print(f"atl08_us_per_photon={min(walls) / n * 1e6:.3f}")


if __name__ == "__main__":
    main()
