"""Benchmark of a whole granule: ``canopyblocks blocks`` against a plain h5py read.

Run: ``.venv/bin/python bench/bench_granule.py [--photons-per-beam 14000000] [--preset paper]
[--preset atl08] [--workdir DIR]``

A 6-beam ATL03 granule written like real v006 files (gzip level 6 on every dataset in
chunks of 10,000 rows, the shuffle filter on the integer ones such as the 2-D
``signal_conf_ph``, as ``tests/data/icesat2/harmony_ATL03_gt1l.h5``;
photons in time order with ``s`` out of order locally (``dist_ph_along`` scattered by
+-0.1 m), geolocation segments of 20 m; by default 14 M photons per strong beam
and 3.5 M per weak beam, 52.5 M in all: the granule of issue 13) is made once (cached in
``--workdir``; making it takes a few minutes). Then, each in its own process:

1. a plain single-process h5py read of the datasets the reader needs, every beam (the
   anchor of every ratio);
2. ``canopyblocks blocks FILE --length 10 --length 25 --length 100 --preset P -o OUT.parquet``
   for each preset P (``--preset``, repeatable; default both: ``paper``, the paper's
   method, and ``atl08``, the recommended ATL08-style classifier).

The read and the presets' commands run interleaved ``--repeat`` times (default 3) and the
medians count (the machines are shared and noisy; the fastest run is printed beside); the
CPU seconds (user + system, the command and the workers it waited for) are printed too,
the steadier figure on a loaded machine. The part that does not grow with the granule is
the same pair of commands on the bundled 1.6 MB beam. The commands run with bytecode cached
(in ``--workdir``), as an installed package has it.

Peak memory is the largest sum, over time, of the proportional set sizes of the command and
its worker processes (``--workers``, default the machine's cores), from one more run. Per
preset three lines ``granule_<preset>_cpu_ratio=``, ``granule_<preset>_peak_ratio=<peak /
bytes of the arrays read>`` and ``granule_<preset>_time_ratio=<median time / median plain
read time>``; the last line printed is the last preset's time ratio (the issue's goals:
paper <= 1.25, atl08 <= 1.5; peak <= 2).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PRESETS = ("paper", "atl08")
BEAMS = ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")
HEIGHTS = ("delta_time", "lat_ph", "lon_ph", "h_ph", "dist_ph_along", "signal_conf_ph")
GEOLOC = ("segment_id", "segment_dist_x", "segment_ph_cnt", "ph_index_beg", "segment_length",
          "reference_photon_lat", "reference_photon_lon", "delta_time")

PLAIN_READ = """
import sys, h5py
n = 0
with h5py.File(sys.argv[1], "r") as f:
    for b in {beams!r}:
        for k in {heights!r}:
            n += f[b + "/heights/" + k][()].nbytes
        for k in {geoloc!r}:
            n += f[b + "/geolocation/" + k][()].nbytes
print(n)
"""


# the granule kinds: (background share of the photons, height window of the background
# (m), terrain slope (m/m), with a bckgrd_atlas group); the original bench granule is
# "flat-night" (15 % background in a 150 m window, no bckgrd_atlas)
KINDS = {
    "flat-night": (0.15, 150.0, 0.0, False),
    "flat-night-bckgrd": (0.15, 150.0, 0.0, True),
    "steep-day": (0.45, 500.0, 0.3, False),
    "steep-day-bckgrd": (0.45, 500.0, 0.3, True),
}


def make_granule(path: Path, per_beam: int, seed: int = 3, kind: str = "flat-night") -> Path:
    """Six beams of a forest track, written with write_atl03 then repacked with gzip."""
    import h5py

    from canopyblocks.outputs.h5_layouts import Atl03Background, Atl03BeamData, write_atl03

    if path.exists():
        return path
    share, window, slope, with_bg = KINDS[kind]
    rng = np.random.default_rng(seed)
    beams = {}
    for i, b in enumerate(BEAMS):
        n = per_beam if b.endswith("l") else per_beam // 4  # weak beams: a quarter
        s = np.sort(rng.random(n)) * (n / 15.0)
        ground = 2400.0 + 40.0 * np.sin(s / 700.0) + slope * 300.0 * np.sin(s / 300.0)
        u = rng.random(n)
        signal = 1.0 - share  # ground : canopy as 45 : 40
        h = ground + np.where(
            u < signal * (0.45 / 0.85), rng.normal(0, 0.3, n),
            np.where(u < signal, rng.random(n) * 25.0,
                     rng.uniform(-window * 0.4, window * 0.6, n)))
        lat = 41.5 + s * 9.0e-6
        lon = -106.57 + i * 1e-3 + s * 1.0e-7
        t = s / 7000.0
        bg = None
        if with_bg:  # 50-shot spans (5 ms): photons per second of the noise in the window
            dt = np.arange(0.0, t[-1] + 0.005, 0.005)
            # noise photons per shot per metre of height, times c / 2 (10 kHz, 7 km/s)
            per_s = share * 15.0 / window / (10_000 / 7000.0) * 1.5e8
            bg = Atl03Background(delta_time=dt, rate=np.full(dt.size, per_s))
        beams[b] = Atl03BeamData(delta_time=t, lat=lat, lon=lon, h=h, s=s, background=bg)
    raw = path.with_suffix(".raw.h5")
    write_atl03(raw, beams)
    with h5py.File(raw, "r") as src, h5py.File(path.with_suffix(".tmp"), "w") as dst:
        def copy(name: str, obj: object) -> None:
            if isinstance(obj, h5py.Dataset):
                data = obj[()]
                if name.endswith("heights/dist_ph_along"):
                    # as in real granules: photons in time order, s out of order locally
                    data = data + rng.uniform(-0.1, 0.1, data.shape).astype(data.dtype)
                kw = {}
                if obj.ndim >= 1 and obj.shape[0] > 0:
                    # v006: chunks of 10,000 rows, gzip level 6 on every dataset, the
                    # shuffle filter on the integer ones (signal_conf_ph among them)
                    kw = {"compression": "gzip", "compression_opts": 6,
                          "chunks": (10_000, *obj.shape[1:]),
                          "maxshape": (None, *obj.shape[1:]),
                          "shuffle": np.dtype(obj.dtype).kind in "iu"}
                d = dst.create_dataset(name, data=data, **kw)
                for k, v in obj.attrs.items():
                    d.attrs[k] = v
            elif isinstance(obj, h5py.Group):
                g = dst.require_group(name)
                for k, v in obj.attrs.items():
                    g.attrs[k] = v
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        src.visititems(copy)
    raw.unlink()
    path.with_suffix(".tmp").rename(path)
    return path


def _tree(root: int) -> list[int]:
    """``root`` and its descendants (/proc/<pid>/task/<tid>/children)."""
    out, todo = [], [root]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in Path(f"/proc/{p}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
    return out


def _pss(pid: int) -> int:
    """Proportional set size of ``pid`` in bytes (shared pages split between sharers, so
    forked workers are not counted twice); 0 when it is gone."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _env(work: Path) -> dict[str, str]:
    """The commands' environment: one thread per BLAS, and bytecode cached (in
    ``work``, not next to the sources) as an installed package has it -- a shell with
    PYTHONDONTWRITEBYTECODE would otherwise have every run compile the package again."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "PYTHONPYCACHEPREFIX": str(work / "pycache")}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def child(cmd: list[str], env: dict[str, str], sample: bool = False
          ) -> tuple[float, float, int, str]:
    """Run ``cmd``; wall time (s), CPU time (s, user + system of it and the workers it
    waited for), with ``sample`` the peak over time of the summed PSS of it and its worker
    processes (bytes; sampled every 20 ms -- reading PSS slows the command, so time and
    memory come from separate runs), stdout."""
    import resource
    import threading

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    peak = [0]

    def sampler() -> None:
        while proc.poll() is None:
            peak[0] = max(peak[0], sum(_pss(p) for p in _tree(proc.pid)))
            time.sleep(0.02)

    th = threading.Thread(target=sampler, daemon=True)
    if sample:
        th.start()
    out, err = proc.communicate()
    t = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if sample:
        th.join()
    if proc.returncode != 0:
        raise SystemExit(f"{cmd[:4]} failed ({proc.returncode}): {err[-2000:]}")
    return t, cpu, peak[0], out


def _median(cmd: list[str], env: dict[str, str], repeat: int) -> tuple[float, float]:
    """Median wall time and median CPU time of ``repeat`` runs (s)."""
    runs = [child(cmd, env)[:2] for _ in range(repeat)]
    return (float(np.median([r[0] for r in runs])), float(np.median([r[1] for r in runs])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons-per-beam", type=int, default=14_000_000,
                    help="photons of a strong beam (weak: a quarter); the default makes "
                         "the 52.5 M-photon granule of issue 13")
    ap.add_argument("--workers", type=int, default=None,
                    help="canopyblocks blocks --workers (default: its own default)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs timed; the median counts (the fastest is printed beside)")
    ap.add_argument("--preset", action="append", choices=PRESETS, default=None,
                    help="estimator preset(s) timed against the read (repeatable; default "
                         "both: paper, atl08)")
    ap.add_argument("--kind", action="append", choices=tuple(KINDS), default=None,
                    help="granule kind(s) (repeatable; default flat-night): night or day "
                         "background, flat or steep (30 %% slopes) terrain, with or without "
                         "bckgrd_atlas; the ratios printed last are the worst over the kinds")
    ap.add_argument("--workdir", default=str(Path(tempfile.gettempdir()) / "cb_bench_granule"))
    args = ap.parse_args()
    presets = tuple(args.preset or PRESETS)
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    worst: dict[str, float] = {}
    compile_s = _compile_seconds(work)
    for kind in args.kind or ("flat-night",):
        name = f"ATL03_bench_{args.photons_per_beam}_v3.h5" if kind == "flat-night" else \
            f"ATL03_bench_{args.photons_per_beam}_{kind}_v4.h5"
        g = make_granule(work / name, args.photons_per_beam, kind=kind)
        print(f"granule ({kind}): {g} ({g.stat().st_size / 2**20:.0f} MiB)")
        for k, v in _one_granule(g, presets, args, work).items():
            worst[k] = max(worst.get(k, 0.0), v)
    if compile_s is not None:
        print(f"first run's compile (cold cache, one 1.6 MB beam): {compile_s:.2f} s more "
              "than a warm run")
    lines = []
    for name in presets:
        lines += [f"granule_{name}_{k}_ratio={worst[f'{name}_{k}']:.2f}"
                  for k in ("cpu", "peak", "time")]
    if compile_s is not None:  # beside the last ratio
        lines[-1] += f" compile_s={compile_s:.2f}"
    for line in lines:
        print(line)


def _compile_seconds(work: Path) -> float | None:
    """Seconds the compiled kernels' first run adds (an empty cache against a warm one),
    on the bundled beam with the ``atl08`` preset; None without numba."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return None
    small = Path(__file__).resolve().parents[1] / "tests" / "data" / "icesat2" \
        / "harmony_ATL03_gt1l.h5"
    cache = work / "numba_cold"
    cmd = [sys.executable, "-m", "canopyblocks", "-q", "blocks", str(small), "--preset",
           "atl08", "-o", str(work / "compile.parquet")]
    env = {**_env(work), "NUMBA_CACHE_DIR": str(cache)}
    child(cmd, env)  # bytecode and files warm
    times = []
    for _ in range(2):
        subprocess.run(["rm", "-rf", str(cache)], check=True)
        cold = child(cmd, env)[0]
        warm = child(cmd, env)[0]
        times.append(cold - warm)
    return float(np.median(times))


def _one_granule(g: Path, presets: tuple[str, ...], args: argparse.Namespace, work: Path
                 ) -> dict[str, float]:
    """Time, CPU and peak ratios of each preset on one granule, printed and returned."""
    script = PLAIN_READ.format(beams=BEAMS, heights=HEIGHTS, geoloc=GEOLOC)
    env = _env(work)
    out = work / "blocks.parquet"

    def blocks(path: Path, preset: str) -> list[str]:
        return [sys.executable, "-m", "canopyblocks", "-q", "blocks", str(path),
                "--length", "10", "--length", "25", "--length", "100", "--preset", preset,
                "-o", str(out), *(["--workers", str(args.workers)] if args.workers else [])]

    read = [sys.executable, "-c", script, str(g)]
    # the part that does not grow with the granule: the same commands on a 1.6 MB beam
    small = Path(__file__).resolve().parents[1] / "tests" / "data" / "icesat2" \
        / "harmony_ATL03_gt1l.h5"
    child(blocks(small, presets[0]), env)   # warm-up: bytecode cached, files in the page cache
    s_read, s_read_cpu = _median([sys.executable, "-c", script.replace(
        repr(BEAMS), "('gt1l',)"), str(small)], env, args.repeat)
    _, _, _, stdout = child(read, env)
    nbytes = int(stdout.strip())
    # the read and the presets' runs interleaved, so a change of the machine's load hits
    # all of them alike; each ratio is of medians
    runs: dict[str, list[tuple[float, float]]] = {k: [] for k in ("read", *presets)}
    for _ in range(args.repeat):
        runs["read"].append(child(read, env)[:2])
        for name in presets:
            runs[name].append(child(blocks(g, name), env)[:2])
    t_read, c_read = (float(np.median([r[i] for r in runs["read"]])) for i in (0, 1))
    print(f"plain h5py read: {t_read:.2f} s median, {min(r[0] for r in runs['read']):.2f} s "
          f"fastest ({c_read:.2f} s CPU), {nbytes / 2**20:.0f} MiB of arrays")
    ratios: dict[str, float] = {}
    for name in presets:
        t, c = (float(np.median([r[i] for r in runs[name]])) for i in (0, 1))
        _, _, peak, _ = child(blocks(g, name), env, sample=True)
        s_t, s_c = _median(blocks(small, name), env, args.repeat)
        print(f"canopyblocks blocks --preset {name} (3 lengths, GeoParquet, workers: "
              f"{args.workers or 'default'}): {t:.2f} s median, "
              f"{min(r[0] for r in runs[name]):.2f} s fastest ({c:.2f} s CPU), peak "
              f"{peak / 2**20:.0f} MiB (all its processes); fixed part (one 1.6 MB beam): "
              f"{s_t - s_read:.2f} s ({s_c - s_read_cpu:.2f} s CPU) more than its read")
        ratios.update({f"{name}_cpu": c / c_read, f"{name}_peak": peak / nbytes,
                       f"{name}_time": t / t_read})
        print(f"  {g.name} {name}: time ratio {t / t_read:.2f}, CPU {c / c_read:.2f}, "
              f"peak {peak / nbytes:.2f}")
    return ratios


if __name__ == "__main__":
    main()
