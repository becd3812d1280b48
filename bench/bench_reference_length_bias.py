"""Hmax, H90 and ground bias of the ``atl08`` blocks against the footprint-matched
reference at 10, 25 and 50 m, per reference statistic (``pooled`` and ``footprint-mean``).

Photons: the project's simulator over the bundled airborne tiles (ICESat-2, 13 m
footprints, temperate 1.9 photons per strong-beam shot), straight tracks at three azimuths,
night background (0.15 MHz, uniform in the telemetry window), strong beam, several seeds;
each track written as an ATL03-layout file and read back. Blocks: 10, 25 and 50 m from the
track start, the ``atl08`` preset. References from the airborne points only, along the
reported (here: true) line. Bias = mean of block minus reference over the blocks that
enter the statistics (``use``: block kept, reference ok), per tile group: the tiles never
used for fitting (lidR_Topography, pyfor_test, lidR_MixedConifer) and the calibration
tiles (lasR_bcts_1/2).

    python bench/bench_reference_length_bias.py [--seeds 3] [--azimuths 0,60,120]

Prints a table (group, statistic, length, n, Hmax bias with its 95 % interval -- a block
bootstrap along each track, runs of 100 m -- H90 / ground bias, Hmax RMSE); the
last line: ``hmax_bias_pooled_unseen_m=<10 m>/<25 m>/<50 m>``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import warnings
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from canopyblocks.blocks import BlockParams  # noqa: E402
from canopyblocks.blocks.estimators import preset  # noqa: E402
from canopyblocks.readers import read_atl03  # noqa: E402
from canopyblocks.readers.las import read_las  # noqa: E402
from canopyblocks.reference.footprint import FootprintCloud  # noqa: E402
from canopyblocks.reference.footprint_blocks import (  # noqa: E402
    block_footprint_reference,
    estimate_statistic,
)
from canopyblocks.reference.footprint_params import FootprintReferenceParams  # noqa: E402
from canopyblocks.simulate import SimParams, line_through, simulate_photons  # noqa: E402
from canopyblocks.simulate.writers import write_simulation_atl03  # noqa: E402
from canopyblocks.validation.facts import RUN_METRES, interval95  # noqa: E402
from canopyblocks.workflows.blocks import run_blocks  # noqa: E402

ALS = Path(__file__).resolve().parents[1] / "tests" / "data" / "als"
GROUPS = {
    "unseen": ("lidR_Topography", "pyfor_test", "lidR_MixedConifer"),
    "calibration": ("lasR_bcts",),
}
TILES = {"lidR_Topography": ("lidR_Topography.laz",), "pyfor_test": ("pyfor_test.laz",),
         "lidR_MixedConifer": ("lidR_MixedConifer.laz",),
         "lasR_bcts": ("lasR_bcts_1.laz", "lasR_bcts_2.laz")}
LENGTHS = (10.0, 25.0, 50.0)
STATISTICS = ("pooled", "footprint-mean")
DIAMETER = 13.0
NIGHT_MHZ = 0.15


def site_rows(name: str, azimuths: tuple[float, ...], seeds: int) -> pd.DataFrame:
    """Blocks of every (azimuth, seed) track of a site joined to both references."""
    pts = read_las([str(ALS / f) for f in TILES[name]])
    cloud = FootprintCloud(pts, FootprintReferenceParams())
    est = preset("atl08")
    threshold, level = estimate_statistic(est.label())
    frames = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, az in enumerate(azimuths):
            line = line_through(pts.bounds, az, inset=DIAMETER / 2 + 3.0)
            refs: dict[str, pd.DataFrame] = {}
            for seed in range(seeds):
                sim = simulate_photons(pts, line, SimParams(beam="strong",
                                                            background_rate_mhz=NIGHT_MHZ),
                                       seed=1000 + 100 * i + seed)
                path = write_simulation_atl03(sim, Path(tmp) / f"{name}_{i}_{seed}.h5")
                track = read_atl03(path, "gt1r", crs=pts.crs)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    blocks, _ = run_blocks([track], BlockParams(lengths=LENGTHS, s0=0.0),
                                           estimators=est)
                for stat in STATISTICS:
                    if stat not in refs:  # the same line for every seed
                        refs[stat] = block_footprint_reference(
                            blocks, cloud, statistic=stat,
                            top_level=level if stat == "pooled" else 98,
                            canopy_threshold=threshold)
                    frames.append(_frame(name, az, seed, stat, blocks, refs[stat]))
                if "levels" not in refs:
                    lv = refs["pooled"][["track", "length", "block", "ref_flag", "ref_h90",
                                          "ref_ground"]].copy()
                    for q in MATCH_LEVELS:
                        lv[f"q{q}"] = block_footprint_reference(
                            blocks, cloud, top_level=q, canopy_threshold=threshold
                        )["ref_hmax"].to_numpy()
                    refs["levels"] = lv
                frames.append(_frame(name, az, seed, "pooled, level of n photons", blocks,
                                     _matched(blocks, refs["levels"])))
    return pd.concat(frames, ignore_index=True)


#: Percentiles of the reference to interpolate the one n canopy photons' 98th percentile
#: reaches on average (diagnosis of the estimate's finite-sample bias).
MATCH_LEVELS = (80, 85, 88, 90, 92, 94, 95, 96, 97, 98)


def _matched(blocks: pd.DataFrame, levels: pd.DataFrame) -> pd.DataFrame:
    """The pooled reference with Hmax at the level the 98th percentile (numpy's linear
    method) of the block's n canopy photons has on average: order statistic
    0.98 (n - 1) + 1 of n, whose expected CDF value is that over n + 1."""
    key = ["length", "block"]
    lv = blocks[key + ["n_between"]].merge(levels, on=key, how="left")
    n = lv["n_between"].to_numpy(float)
    q = 100.0 * (0.98 * (n - 1) + 1) / (n + 1)
    table = lv[[f"q{v}" for v in MATCH_LEVELS]].to_numpy(float)
    lv["ref_hmax"] = [np.interp(qi, MATCH_LEVELS, row) if np.isfinite(qi) else np.nan
                      for qi, row in zip(q, table)]
    return lv


def _frame(name: str, az: float, seed: int, stat: str, blocks: pd.DataFrame,
           ref: pd.DataFrame) -> pd.DataFrame:
    key = ["length", "block"]  # the first seed's blocks: another seed may end elsewhere
    ref = blocks[key].merge(ref.drop(columns="track"), on=key, how="left")
    use = blocks["use"].to_numpy(bool) & (ref["ref_flag"] == "ok").to_numpy()
    return pd.DataFrame({
        "site": name, "azimuth": az, "seed": seed, "statistic": stat,
        "length": blocks["length"].to_numpy(float), "block": blocks["block"].to_numpy(),
        "use": use,
        "res_hmax": blocks["hmax"].to_numpy(float) - ref["ref_hmax"].to_numpy(),
        "res_h90": blocks["h90"].to_numpy(float) - ref["ref_h90"].to_numpy(),
        "res_ground": blocks["ground"].to_numpy(float) - ref["ref_ground"].to_numpy()})


def summary(rows: pd.DataFrame) -> pd.DataFrame:
    out = []
    for group, sites in GROUPS.items():
        g = rows[rows["site"].isin(sites) & rows["use"]]
        for (stat, length), s in g.groupby(["statistic", "length"], sort=True):
            s = s.sort_values(["site", "azimuth", "seed", "block"])
            track = (s["site"] + "|" + s["azimuth"].astype(str) + "|"
                     + s["seed"].astype(str)).to_numpy()
            lo, hi, _, _, _ = interval95(s["res_hmax"].to_numpy(float), track=track,
                                         run=max(1, int(round(RUN_METRES / length))))
            out.append({"tiles": group, "statistic": stat, "length": length, "n": len(s),
                        "hmax_bias": s["res_hmax"].mean(), "hmax_bias_lo": lo,
                        "hmax_bias_hi": hi, "h90_bias": s["res_h90"].mean(),
                        "ground_bias": s["res_ground"].mean(),
                        "hmax_rmse": float(np.sqrt(np.mean(s["res_hmax"] ** 2)))})
    return pd.DataFrame(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--azimuths", default="0,60,120")
    ap.add_argument("--sites", default=",".join(TILES))
    a = ap.parse_args()
    az = tuple(float(v) for v in a.azimuths.split(","))
    rows = pd.concat([site_rows(n, az, a.seeds) for n in a.sites.split(",")],
                     ignore_index=True)
    table = summary(rows)
    print(table.round(3).to_string(index=False))
    u = table[(table["tiles"] == "unseen") & (table["statistic"] == "pooled")]
    print("hmax_bias_pooled_unseen_m=" + "/".join(f"{v:.2f}" for v in u["hmax_bias"]))


if __name__ == "__main__":
    main()
