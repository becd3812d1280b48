"""Bytes and time a track's corridor costs when the survey is a COPC file on a server.

Run: ``.venv/bin/python bench/bench_copc_remote.py [--nx 4] [--ny 3] [--width 43] [--repeat 3]``

A survey of ``--nx`` x ``--ny`` shifted copies of the two bundled BC tiles (each copy 1.36 M
points over about 195 m x 543 m) is written once as one COPC file (``tests/copc_data.py``:
nodes of at most 20,000 points, hierarchy pages below level 3; cached in ``--workdir``,
default /work/benchdata/copc when it exists) and served by a static HTTP server with range
requests on the loopback address (``tests/loopback_servers.py``; no network).  A track
crosses the survey diagonally; its corridor is ``--width`` metres wide (13 m of ICESat-2
footprints plus 15 m each side for the co-registration search).  ``read_copc`` reads the
corridor over ``http://`` and from the local file, ``--repeat`` times each (medians); the
points must be identical, and the server counts the bytes it sends.  The last line is
``copc_remote_bytes_share=<bytes sent / file size> remote_s=<median> local_s=<median>
ratio=<remote / local> peak_mib=<the process's peak memory>`` (the goal: a share below 0.20;
the peak includes writing the survey on the first run).
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "core"))

TILES = ("lasR_bcts_1.laz", "lasR_bcts_2.laz")
STEP = (200.0, 550.0)  # metres between copies of the tile pair


def _survey(work: Path, nx: int, ny: int) -> Path:
    from copc_data import build_octree, shifted_grid, tile_points, write_copc

    out = work / f"bcts_{nx}x{ny}.copc.laz"
    if not out.exists():
        t = time.perf_counter()
        tiles = [ROOT / "tests" / "data" / "als" / n for n in TILES]
        pts = shifted_grid(tile_points(tiles), nx, ny, *STEP)
        tree = build_octree(pts, capacity=20_000)
        part = out.with_suffix(".part")
        write_copc(tiles, part, tree=tree, page_level=3)
        part.rename(out)
        print(f"survey written in {time.perf_counter() - t:.0f} s: {len(tree.counts)} nodes")
    return out


def _corridor(path: Path, width: float) -> object:
    import shapely

    from canopyblocks.readers.copc import copc_extent

    b = copc_extent(path).bounds
    x0, y0, x1, y1 = b[0], b[1], b[2], b[3]
    length = math.hypot(x1 - x0, y1 - y0) * 1.1
    angle = math.atan2(y1 - y0, (x1 - x0) * 0.35)  # steep: it crosses rows and columns
    ux, uy, w = math.cos(angle), math.sin(angle), width / 2
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    return shapely.Polygon([(cx + sa * length / 2 * ux - sw * w * uy,
                             cy + sa * length / 2 * uy + sw * w * ux)
                            for sa, sw in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nx", type=int, default=4)
    ap.add_argument("--ny", type=int, default=3)
    ap.add_argument("--width", type=float, default=43.0)
    ap.add_argument("--repeat", type=int, default=3)
    default = "/work/benchdata/copc" if Path("/work/benchdata").is_dir() else "cb_bench_copc"
    ap.add_argument("--workdir", default=default)
    args = ap.parse_args()

    import numpy as np

    from canopyblocks.readers import remote
    from canopyblocks.readers.copc import read_copc
    from loopback_servers import RangeHTTPServer

    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    path = _survey(work, args.nx, args.ny)
    size = path.stat().st_size
    poly = _corridor(path, args.width)
    local_t, remote_t, shares = [], [], []
    with RangeHTTPServer(work) as server:
        for _ in range(args.repeat):
            t = time.perf_counter()
            local = read_copc(path, polygon=poly)
            local_t.append(time.perf_counter() - t)
            remote.clear_cache()
            server.tally.reset()
            t = time.perf_counter()
            got = read_copc(f"{server.url}/{path.name}", polygon=poly)
            remote_t.append(time.perf_counter() - t)
            shares.append(server.tally.nbytes / size)
            same = all(np.array_equal(a, b) for a, b in
                       ((got.x, local.x), (got.y, local.y), (got.z, local.z)))
            if not same:
                raise SystemExit("the remote read differs from the local one")
    print(f"survey: {path.name}, {size / 1e6:.1f} MB; corridor {args.width:g} m wide: "
          f"{len(local):,} points; requests {server.tally.requests}")
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB (Linux: KiB)
    r, lo = statistics.median(remote_t), statistics.median(local_t)
    print(f"copc_remote_bytes_share={statistics.median(shares):.4f} remote_s={r:.2f} "
          f"local_s={lo:.2f} ratio={r / lo:.2f} peak_mib={peak:.0f}")


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    main()
