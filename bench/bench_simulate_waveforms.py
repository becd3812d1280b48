"""Benchmark: GEDI footprints simulated per second over a real airborne tile.

Tile: tests/data/als/lasR_bcts_1.laz + lasR_bcts_2.laz (about 1.1 M points, 11-14 pts/m2,
conifer forest, EPSG:3005). Footprints every 2 m along tracks at 12 azimuths through the
survey (overlapping footprints: a dense test of the point search), sigma 5.5 m, 1 ns
samples; the spatial index is built once; the time covers its queries, weights, binning, pulse convolution,
noise and the truth (including the noise-free processing for RH). One core, CPU time,
best of three.

Usage: python bench/bench_simulate_waveforms.py
The last line printed is ``footprints_per_s=<number>``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import time  # noqa: E402
from pathlib import Path  # noqa: E402

from canopyblocks.readers.las import read_las  # noqa: E402
from canopyblocks.reference.footprint_returns import footprint_index  # noqa: E402
from canopyblocks.simulate import line_through  # noqa: E402
from canopyblocks.simulate.gedi_waveforms import GediSimParams, simulate_gedi  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "als"


def main() -> None:
    pts = read_las([DATA / "lasR_bcts_1.laz", DATA / "lasR_bcts_2.laz"])
    b = pts.bounds
    params = GediSimParams(spacing=2.0)
    tracks = [line_through(b, az, inset=17.0) for az in range(0, 180, 15)]
    index = footprint_index(pts)   # built once, as for any study of many tracks
    best = float("inf")
    n = 0
    for _ in range(3):
        t0 = time.process_time()
        n = sum(len(simulate_gedi(pts, t, params=params, seed=i, index=index).truth)
                for i, t in enumerate(tracks))
        best = min(best, time.process_time() - t0)
    print(f"{n} footprints on {len(tracks)} tracks over {len(pts.x):,} points: "
          f"{best:.2f} CPU s (best of 3)")
    print(f"footprints_per_s={n / best:.0f}")


if __name__ == "__main__":
    main()
