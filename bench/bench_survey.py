"""A track validated against a whole survey, and the survey's rasters, at survey size.

The survey: shifted copies of the two bundled BC tiles (one cell = the two tiles, about
196 m x 544 m), ``--cols`` x ``--rows`` cells (default 5 x 8: 80 tiles, ~54 M points);
the copies are made by rewriting the LAZ header's offsets and extent (the compressed points
are the same bytes, so making 400 tiles takes seconds).  The track: photons simulated by
the project's simulator along the middle column over the tiles under it.

Measured, each command in its own process tree (peak = the largest resident set of any
process of it, from ``getrusage(RUSAGE_CHILDREN)`` in a wrapper):

(a) ``canopyblocks run ALL --photons track.h5 --offset 0`` against the same run given only
    the tiles under the track: time ratio, peaks, the largest residual difference;
(b) ``canopyblocks rasters ALL`` against a plain one-process laspy read of every tile's
    x, y, z and class: time ratio, peaks, the largest file in its output/temporary folders.

Usage::

    python bench/bench_survey.py [--cols 5 --rows 8] [--data /work/benchdata/survey]

The last line prints the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import struct
import subprocess
import sys
import threading
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BCTS = ("lasR_bcts_1.laz", "lasR_bcts_2.laz")
CELL = (196.0, 544.0)

WRAP = r"""
import resource, subprocess, sys, time, json
t = time.perf_counter()
r = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
wall = time.perf_counter() - t
u = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"rc": r.returncode, "wall": wall, "cpu": u.ru_utime + u.ru_stime,
                  "peak_mib": u.ru_maxrss / 1024.0, "err": r.stderr[-2000:]}))
"""

READ = r"""
import sys, laspy, numpy as np
n = 0
for p in sys.argv[1:]:
    las = laspy.read(p)
    x, y, z, c = (np.asarray(las.x), np.asarray(las.y), np.asarray(las.z),
                  np.asarray(las.classification))
    n += x.size
print(n)
"""


def _data_dir() -> Path:
    for d in (REPO / "tests" / "data" / "als", REPO.parent / "shared" / "data" / "als",
              Path("/work/shared/data/als")):
        if (d / BCTS[0]).is_file():
            return d
    raise SystemExit("the bundled BC tiles were not found")


def _shifted_copy(src: Path, dst: Path, dx: float, dy: float) -> None:
    """A copy of a LAS/LAZ file moved by (dx, dy): header offsets and extent rewritten."""
    data = bytearray(src.read_bytes())
    xo, yo = struct.unpack_from("<dd", data, 155)  # x, y offsets (after the scales)
    struct.pack_into("<dd", data, 155, xo + dx, yo + dy)
    maxx, minx, maxy, miny = struct.unpack_from("<dddd", data, 179)
    struct.pack_into("<dddd", data, 179, maxx + dx, minx + dx, maxy + dy, miny + dy)
    tmp = dst.with_suffix(".part")
    tmp.write_bytes(bytes(data))
    tmp.replace(dst)


def make_survey(out: Path, cols: int, rows: int) -> tuple[list[Path], list[Path]]:
    """The survey's tiles, and those of its middle column."""
    src = _data_dir()
    tiles = out / f"tiles_{cols}x{rows}"
    tiles.mkdir(parents=True, exist_ok=True)
    allp, mid = [], []
    for i in range(cols):
        for j in range(rows):
            for k, name in enumerate(BCTS):
                p = tiles / f"c{i:02d}_r{j:02d}_{k}.laz"
                if not p.exists():
                    _shifted_copy(src / name, p, i * CELL[0], j * CELL[1])
                allp.append(p)
                if i == cols // 2:
                    mid.append(p)
    return allp, mid


def measure(cmd: list[str], watch: list[Path] | None = None) -> dict:
    """Run ``cmd`` in a wrapper; wall, CPU, peak RSS and the largest file in ``watch``."""
    biggest = [0]
    stop = threading.Event()

    def poll() -> None:
        while not stop.is_set():
            for d in watch or []:
                for root, _, files in os.walk(d):
                    for f in files:
                        try:
                            biggest[0] = max(biggest[0], os.path.getsize(os.path.join(root, f)))
                        except OSError:
                            pass
            stop.wait(0.5)

    th = threading.Thread(target=poll, daemon=True)
    th.start()
    r = subprocess.run([sys.executable, "-c", WRAP, *cmd], capture_output=True, text=True)
    stop.set()
    th.join()
    res = json.loads(r.stdout.strip().splitlines()[-1])
    res["largest_file_mib"] = biggest[0] / 2 ** 20
    if res["rc"] != 0:
        raise SystemExit(f"{' '.join(cmd[:4])} failed: {res['err']}")
    return res


def _residuals(folder: Path):  # noqa: ANN202
    import geopandas as gpd

    r = gpd.read_file(folder / "validation.gpkg", layer="residuals")
    keys = [c for c in ("track", "length", "block", "metric") if c in r]
    return r.sort_values(keys).reset_index(drop=True)


def residual_difference(a: Path, b: Path) -> float:
    """The largest difference of the residual columns (``res_*``) of two runs, metres."""
    import numpy as np

    ra, rb = _residuals(a), _residuals(b)
    if len(ra) != len(rb):
        return float("inf")
    cols = [c for c in ra.columns if c.startswith("res_")]
    d = [np.nanmax(np.abs(ra[c].to_numpy(float) - rb[c].to_numpy(float)), initial=0.0)
         for c in cols]
    return float(max(d, default=0.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cols", type=int, default=5)
    ap.add_argument("--rows", type=int, default=8)
    ap.add_argument("--data", type=Path, default=Path("/work/benchdata/survey"))
    ap.add_argument("--skip-run", action="store_true", help="only the rasters part")
    args = ap.parse_args()
    data = args.data
    allp, mid = make_survey(data, args.cols, args.rows)
    cb = [sys.executable, "-m", "canopyblocks", "-q"]
    tag = f"{args.cols}x{args.rows}"
    work = data / f"work_{tag}"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    tmp = work / "tmp"
    tmp.mkdir()
    os.environ["TMPDIR"] = str(tmp)
    figures: dict[str, float] = {"tiles": len(allp)}
    if not args.skip_run:
        x0 = 885022.0 + (args.cols // 2) * CELL[0] + CELL[0] / 2
        y0, y1 = 629156.0 + 20.0, 629156.0 + args.rows * CELL[1] - 20.0
        track = data / f"track_{tag}.h5"
        if not track.exists():
            r = subprocess.run([*cb, "simulate", *map(str, mid), "--line",
                                f"{x0 - 30},{y0},{x0 + 30},{y1}", "--realisations", "1",
                                "--seed", "1", "-o", str(track)], capture_output=True,
                               text=True)
            if r.returncode:
                raise SystemExit(r.stderr)
        a = measure([*cb, "run", *map(str, allp), "--photons", str(track), "--offset", "0",
                     "-o", str(work / "run_all")], [work / "run_all", tmp])
        b = measure([*cb, "run", *map(str, mid), "--photons", str(track), "--offset", "0",
                     "-o", str(work / "run_under")], [work / "run_under", tmp])
        figures.update(run_s=a["wall"], run_under_s=b["wall"], run_ratio=a["wall"] / b["wall"],
                       run_peak_mib=a["peak_mib"], run_under_peak_mib=b["peak_mib"])
        print(figures, flush=True)
        figures["run_residual_max_diff_m"] = residual_difference(work / "run_all",
                                                                 work / "run_under")
    plain = measure([sys.executable, "-c", READ, *map(str, allp)])
    print({"read_s": plain["wall"], "read_peak_mib": plain["peak_mib"]}, flush=True)
    rast = measure([*cb, "rasters", *map(str, allp), "-o", str(work / "rasters")],
                   [work / "rasters", tmp])
    figures.update(read_s=plain["wall"], read_cpu_s=plain["cpu"],
                   read_peak_mib=plain["peak_mib"],
                   rasters_s=rast["wall"], rasters_cpu_s=rast["cpu"],
                   rasters_cpu_ratio=rast["cpu"] / plain["cpu"],
                   rasters_ratio=rast["wall"] / plain["wall"],
                   rasters_peak_mib=rast["peak_mib"],
                   rasters_largest_file_mib=rast["largest_file_mib"])
    for k, v in figures.items():
        print(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}")
    print(" ".join(f"{k}={v:.3g}" for k, v in figures.items()))


if __name__ == "__main__":
    main()
