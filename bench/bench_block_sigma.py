"""Benchmark (accuracy): the per-block sigma of the ``atl08`` preset on unseen tiles.

The model (``blocks/uncertainty.py``, coefficients in ``uncertainty_model.json``) was fitted
by ``fit_block_sigma.py`` on the calibration tiles only. Here: simulated ICESat-2 tracks
(``block_sigma_data``: the accuracy bench's leak-free photons, night 0.15 MHz and day
1.5 / 3 / 4.5 MHz, strong and weak beams, six azimuths, seed 1000) over the three tiles it
never saw (lidR_Topography, pyfor_test, lidR_MixedConifer). Residual = block value minus
the footprint-matched reference (no bias correction).

Per beam x light, for Hmax and ground: the share of blocks with |residual| <= sigma (goal
61-75 %) and <= 2 sigma (goal 91-98 %). Then the ``low_confidence`` flag: the share of
blocks kept (``use``) and their Hmax RMSE, all beams, night and day together (goal <= 3.0 m
with >= 60 % kept). 25 m blocks unless ``--length``.

Usage: python bench/bench_block_sigma.py [--length 25] [--cache DIR]
The last line printed is ``hmax_sigma_coverage_1s=<share>`` (25 m, all beams and lights).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from block_sigma_data import unseen_blocks  # noqa: E402

from canopyblocks.blocks.uncertainty import mark_use, predict_sigma, sigma_model  # noqa: E402


def coverage_table(df: pd.DataFrame) -> pd.DataFrame:
    """Coverage per beam x light (and all), Hmax and ground."""
    rows = []
    for beam in ("strong", "weak", "all"):
        for light in (*sorted(df["light"].unique(), key=lambda v: (v != "night", v)), "all"):
            s = df[((df["beam"] == beam) | (beam == "all"))
                   & ((df["light"] == light) | (light == "all"))]
            zh = np.abs(s["res_hmax"]) / s["hmax_sigma"]
            zg = np.abs(s["res_ground"]) / s["ground_sigma"]
            rows.append({"beam": beam, "light": light, "n": len(s),
                         "hmax_1s": float(np.mean(zh <= 1)), "hmax_2s": float(np.mean(zh <= 2)),
                         "ground_1s": float(np.mean(zg <= 1)),
                         "ground_2s": float(np.mean(zg <= 2)),
                         "hmax_sigma_med": float(s["hmax_sigma"].median()),
                         "hmax_rmse": float(np.sqrt(np.mean(s["res_hmax"] ** 2))),
                         "kept": float(s["use"].mean()),
                         "hmax_rmse_kept": float(np.sqrt(np.mean(s["res_hmax"][s["use"]] ** 2)))})
    return pd.DataFrame(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--length", type=float, default=25.0, help="block length, m")
    ap.add_argument("--cache", default=None, help="directory to cache the simulations in")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    t0, c0 = time.perf_counter(), time.process_time()
    m = sigma_model()
    df = unseen_blocks(args.cache)
    df = df[np.isfinite(df["hmax"]) & np.isfinite(df["ground"])].copy()
    df["hmax_sigma"], df["ground_sigma"] = predict_sigma(df, m)
    mark_use(df, m)
    for length in sorted(df["length"].unique()):
        t = coverage_table(df[df["length"] == length])
        print(f"\n{length:g} m blocks (unseen tiles; coverage = share with |residual| <= 1 "
              "or 2 sigma; RMSE in m against the footprint reference):")
        print(t.round(3).to_string(index=False))
    t = coverage_table(df[df["length"] == args.length])
    a = t[(t["beam"] == "all") & (t["light"] == "all")].iloc[0]
    print(f"\nwall {time.perf_counter() - t0:.0f} s, CPU {time.process_time() - c0:.0f} s; "
          f"threshold hmax_sigma > {m.hmax_max:.2f} m or ground_sigma > {m.ground_max:.2f} m "
          f"= low_confidence; {args.length:g} m blocks, all beams and lights: Hmax coverage "
          f"{a['hmax_1s']:.3f} / {a['hmax_2s']:.3f} (1 / 2 sigma), ground {a['ground_1s']:.3f} "
          f"/ {a['ground_2s']:.3f}; kept {a['kept']:.3f} with Hmax RMSE "
          f"{a['hmax_rmse_kept']:.2f} m (all blocks {a['hmax_rmse']:.2f} m)")
    print(f"hmax_sigma_coverage_1s={a['hmax_1s']:.3f}")


if __name__ == "__main__":
    main()
