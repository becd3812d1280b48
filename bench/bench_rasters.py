"""Benchmark: reference rasters (DTM, DSM max, DSM p90) per airborne point.

Runs ``make_reference_rasters`` on the two bundled BC tiles (1.36 M points, 1 m cells)
three times and prints the median wall time per point.  Since issue 13 the tiles are
decoded once by PDAL (the DTM) and once by laspy for both DSMs (numpy cell statistics on
PDAL's neighbourhood rule); before, three PDAL passes plus a text CSV of every point.
Measured on this 2-core machine with farm-bench (whole ``canopyblocks rasters`` command,
medians of 3): 9.21 s before, 3.98 s after, i.e. 6.8 -> 2.9 us per point.

Usage: python bench/bench_rasters.py
The last line printed is ``rasters_us_per_point=<microseconds>``.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "core"))

from canopyblocks.reference.rasters import make_reference_rasters  # noqa: E402

TILES = [ROOT / "tests/data/als/lasR_bcts_1.laz", ROOT / "tests/data/als/lasR_bcts_2.laz"]


def main() -> None:
    import laspy

    n = sum(int(laspy.open(t).header.point_count) for t in TILES)
    times = []
    for _ in range(3):
        with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            make_reference_rasters(TILES, Path(tmp) / "r", resolution=1.0)
            times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    print(f"{n:,} points, runs {', '.join(f'{t:.2f}' for t in times)} s, median {med:.2f} s")
    print(f"rasters_us_per_point={med / n * 1e6:.2f}")


if __name__ == "__main__":
    main()
