"""Benchmark (accuracy): the per-block sigma of the ``atl08`` preset on unseen tiles.

The model (``blocks/uncertainty.py``, coefficients in ``uncertainty_model.json``) was fitted
by ``fit_block_sigma.py`` on the calibration tiles only. Here: simulated ICESat-2 tracks
(``block_sigma_data``: the accuracy bench's leak-free photons, night 0.15 MHz and day
1.5 / 3 / 4.5 MHz, strong and weak beams, six azimuths, seed 1000) over the three tiles it
never saw (lidR_Topography, pyfor_test, lidR_MixedConifer), each track reported 0, 3 and
6 m off its true place (a random direction per line and offset). Residual = block value
minus the footprint-matched reference taken along the reported line (no bias correction).

Per beam x light x offset, for Hmax and ground: the share of blocks with |residual| <=
sigma (goal 61-75 %) and <= 2 sigma (goal 91-98 %); the share of blocks kept (``use``:
not ``low_confidence``) and their Hmax RMSE (goal <= 3.0 m). Night = 0.15 MHz, day = 1.5,
3 and 4.5 MHz pooled. 25 m blocks unless ``--length``; the other lengths are printed
first. About 5 min wall on the shared machine (3 tiles x 6 azimuths x 8 tracks).

Usage: python bench/bench_block_sigma.py [--length 25] [--cache DIR]
The last lines printed are the coverage table (25 m), then
``sigma_rows_in_band=<k>/<n>``: the rows whose four coverages are all inside the bands.
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

BANDS = ((0.61, 0.75), (0.91, 0.98))


def _row(s: pd.DataFrame) -> dict[str, float]:
    zh = np.abs(s["res_hmax"]) / s["hmax_sigma"]
    zg = np.abs(s["res_ground"]) / s["ground_sigma"]
    use = s["use"].to_numpy(bool)
    return {"n": len(s), "hmax_1s": float(np.mean(zh <= 1)), "hmax_2s": float(np.mean(zh <= 2)),
            "ground_1s": float(np.mean(zg <= 1)), "ground_2s": float(np.mean(zg <= 2)),
            "kept": float(use.mean()),
            "rmse_kept": float(np.sqrt(np.mean(s["res_hmax"].to_numpy(float)[use] ** 2))),
            "rmse_all": float(np.sqrt(np.mean(s["res_hmax"] ** 2)))}


def coverage_table(df: pd.DataFrame) -> pd.DataFrame:
    """Coverage per beam x night/day x offset, Hmax and ground; kept share and RMSE."""
    rows = []
    day = np.where(df["light"] == "night", "night", "day")
    for beam in ("strong", "weak"):
        for light in ("night", "day"):
            for off in sorted(df["offset"].unique()):
                m = (df["beam"] == beam).to_numpy() & (day == light) & (df["offset"] == off)
                rows.append({"beam": beam, "light": light, "offset_m": off, **_row(df[m])})
    return pd.DataFrame(rows)


def in_band(t: pd.DataFrame) -> np.ndarray:
    """Rows whose Hmax and ground coverages at 1 and 2 sigma are all inside the bands."""
    (a1, b1), (a2, b2) = BANDS
    ok = np.ones(len(t), bool)
    for c in ("hmax", "ground"):
        ok &= t[f"{c}_1s"].between(a1, b1).to_numpy() & t[f"{c}_2s"].between(a2, b2).to_numpy()
    return ok


def kept_lines(df: pd.DataFrame) -> list[str]:
    """Kept share and Hmax RMSE, all beams, night and day, per offset."""
    out = []
    day = np.where(df["light"] == "night", "night", "day")
    for light in ("night", "day"):
        for off in sorted(df["offset"].unique()):
            r = _row(df[(day == light) & (df["offset"] == off).to_numpy()])
            out.append(f"  {light:5s} {off:g} m off: kept {r['kept']:.3f} with Hmax RMSE "
                       f"{r['rmse_kept']:.2f} m (all blocks {r['rmse_all']:.2f} m, n {r['n']})")
    return out


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
        if length == args.length:
            continue
        t = coverage_table(df[df["length"] == length])
        print(f"\n{length:g} m blocks: {int(in_band(t).sum())}/{len(t)} rows in the bands")
        print(t.round(3).to_string(index=False))
    d = df[df["length"] == args.length]
    print(f"\nwall {time.perf_counter() - t0:.0f} s, CPU {time.process_time() - c0:.0f} s; "
          f"low_confidence = hmax_sigma > {m.hmax_max:.2f} m or ground_sigma > "
          f"{m.ground_max:.2f} m; {args.length:g} m blocks, all beams:")
    print("\n".join(kept_lines(d)))
    t = coverage_table(d)
    print(f"\n{args.length:g} m blocks, unseen tiles (coverage = share with |residual| <= 1 "
          "or 2 sigma; goal 0.61-0.75 and 0.91-0.98; kept = not low_confidence, RMSE of "
          "their Hmax in m):")
    print(t.round(3).to_string(index=False))
    ok = in_band(t)
    print(f"sigma_rows_in_band={int(ok.sum())}/{len(t)}")


if __name__ == "__main__":
    main()
