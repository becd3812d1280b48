"""Benchmark of ``canopyblocks batch``: 8 granules over the two bundled tiles, 1 vs 2 workers.

Run: ``.venv/bin/python bench/bench_batch.py [--backend processes|dask] [--workdir DIR]``

Eight ATL03-layout granules (six beams each, simulated over ``tests/data/als/lasR_bcts_*.laz``
with a dense photon rate so that a unit costs about as much as a real beam segment over two
tiles) are made once (cached in ``--workdir``), the tiles' reference rasters are built once,
then the batch runs twice from scratch (parts and manifest removed) with 1 and with 2
workers. Pool start-up is included: it is part of what a user waits for.

The last line printed is ``batch_speedup=<time with 1 worker / time with 2 workers>``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TILES = [ROOT / "tests" / "data" / "als" / f"lasR_bcts_{i}.laz" for i in (1, 2)]


def make_granules(folder: Path, n: int = 8) -> list[Path]:
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03

    folder.mkdir(parents=True, exist_ok=True)
    out = [folder / f"ATL03_bench{i}.h5" for i in range(n)]
    if all(p.exists() for p in out):
        return out
    pts = read_las([str(t) for t in TILES])
    b = pts.bounds
    cx, cy = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2
    for i, p in enumerate(out):
        tr = line_through(b, 8.0 + i, centre=(cx - 35 + 10 * i, cy), inset=7, name="gt1l")
        sim = simulate_photons(pts, tr, SimParams(mean_photons=12.0), realisations=6,
                               seed=100 + i)
        write_simulation_atl03(sim, p, realisations=range(6))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="processes", choices=("processes", "dask"))
    ap.add_argument("--workdir", default=str(Path(tempfile.gettempdir()) / "cb_bench_batch"))
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    from canopyblocks.workflows.batch import BatchConfig, run_batch

    work = Path(args.workdir)
    granules = make_granules(work / "granules")
    cfg = BatchConfig(lengths=(10.0, 25.0), width=13.0, offset=0.0)
    out = work / "out"
    run_batch(granules, TILES, out, cfg, backend="serial")  # rasters, once (cached)
    times = {}
    for workers in (1, 2):
        for sub in ("parts", "manifest.json", "stats.csv", "report.html"):
            p = out / sub
            shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
        t0 = time.perf_counter()
        res = run_batch(granules, TILES, out, cfg, backend=args.backend, workers=workers)
        times[workers] = time.perf_counter() - t0
        print(f"{args.backend} workers={workers}: {len(res.units)} units in "
              f"{times[workers]:.2f} s")
    print(f"batch_speedup={times[1] / times[2]:.2f}")


if __name__ == "__main__":
    main()
