"""A 13 m corridor across a survey spread over tens of kilometres: `rasters --polygon`.

The survey: ``--cells`` shifted copies of the two bundled BC tiles (one cell = the two
tiles, about 196 m x 544 m; default 10 cells = 20 tiles, ~13 M points) placed along a
diagonal line whose bounding box is ``--span`` km on a side (default 23; try 57); the
copies are made by rewriting the LAZ header's offsets and extent, as in bench_survey.py.
The corridor: a 13 m wide polygon along the line, through every cell.

Measured, each command in its own process tree (peak = the largest resident set of any
process of it): ``canopyblocks rasters DIR --polygon CORRIDOR`` against a plain
one-process laspy read of every tile's x, y, z and class: time ratio, peak memory (GiB)
and the megabytes written.

Usage::

    python bench/bench_corridor_survey.py [--span 23] [--cells 10] [--data /work/benchdata/corridor]

The last line prints the figures.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_survey import BCTS, CELL, READ, _data_dir, _shifted_copy, measure  # noqa: E402

X0, Y0 = 885022.0, 629156.0  # the bundled tiles' south-west corner (NAD83 / BC Albers)
WIDTH = 13.0


def make_survey(out: Path, span_km: float, cells: int) -> tuple[Path, str]:
    """The tiles' folder and the corridor's WKT: cells along the diagonal of the span."""
    src = _data_dir()
    tiles = out / f"tiles_{span_km:g}km_{cells}"
    tiles.mkdir(parents=True, exist_ok=True)
    step = (span_km * 1000.0 - CELL[1]) / max(cells - 1, 1)
    for i in range(cells):
        for k, name in enumerate(BCTS):
            p = tiles / f"c{i:02d}_{k}.laz"
            if not p.exists():
                _shifted_copy(src / name, p, i * step, i * step)
    # the line through every cell's centre, 13 m wide
    cx, cy = X0 + CELL[0] / 2, Y0 + CELL[1] / 2
    end = (cells - 1) * step
    import shapely

    line = shapely.LineString([(cx - 50.0, cy - 50.0), (cx + end + 50.0, cy + end + 50.0)])
    return tiles, line.buffer(WIDTH / 2, cap_style="flat").wkt


def _size_mib(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 2 ** 20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--span", type=float, default=23.0, help="bounding box side, km")
    ap.add_argument("--cells", type=int, default=10, help="pairs of tiles along the line")
    ap.add_argument("--data", type=Path, default=Path("/work/benchdata/corridor"))
    args = ap.parse_args()
    tiles, wkt = make_survey(args.data, args.span, args.cells)
    work = args.data / f"work_{args.span:g}km"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    poly = work / "corridor.wkt"
    poly.write_text(wkt)
    laz = sorted(tiles.glob("*.laz"))
    plain = measure([sys.executable, "-c", READ, *map(str, laz)])
    print({"read_s": round(plain["wall"], 2), "read_peak_mib": round(plain["peak_mib"])},
          flush=True)
    out = work / "rasters"
    rast = measure([sys.executable, "-m", "canopyblocks", "-q", "rasters", str(tiles),
                    "--polygon", wkt, "-o", str(out)], [out])
    figures = {"span_km": args.span, "tiles": len(laz), "read_s": plain["wall"],
               "rasters_s": rast["wall"], "ratio": rast["wall"] / plain["wall"],
               "peak_gib": rast["peak_mib"] / 1024.0, "written_mb": _size_mib(out) * 1.048576,
               "largest_file_mb": rast["largest_file_mib"] * 1.048576}
    print(" ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                   for k, v in figures.items()))


if __name__ == "__main__":
    main()
