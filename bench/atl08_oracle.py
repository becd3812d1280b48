"""Oracle of the ATL08-style classifier: save its output once, check a later version against it.

Run ``python bench/atl08_oracle.py save DIR`` with the classifier as it is, then
``python bench/atl08_oracle.py check DIR`` after a change: per track the classes, the
heights above the ground, the ground surface, the background rate, the block table of the
``atl08`` preset (lengths 10, 25, 100 m) and the 100 m segment table must be identical
(``np.array_equal``; tables with ``assert_frame_equal(check_exact=True)``).

Tracks: every beam of the bundled real clips (``tests/data/icesat2``), a MABEL channel and
ICESat-2 tracks simulated from the bundled airborne tiles (night 0.15 MHz and day 3 MHz,
strong and weak beams, fixed seeds), and a 2 M-photon synthetic daytime beam
(``bench_atl08_classify.synthetic_beam``, seed 0). The last line printed is
``atl08_oracle_mismatches=<n>``. The photons are saved with the outputs and checked from
the saved copy.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"


def tracks() -> Iterator[tuple[str, object]]:
    """(name, PhotonTrack) of every oracle track."""
    import h5py

    from canopyblocks.readers.atl03 import read_atl03
    from canopyblocks.readers.las import read_las
    from canopyblocks.readers.mabel import read_mabel
    from canopyblocks.simulate import SimParams, line_through, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03, write_simulation_mabel

    for f in sorted((DATA / "icesat2").glob("*ATL03*.h5")) + sorted(
            (DATA / "icesat2").glob("*atl03*.h5")):
        with h5py.File(f, "r") as h:
            beams = [b for b in h if b.startswith("gt") and "heights" in h[b]]
        for b in beams:
            yield f"{f.stem}:{b}", read_atl03(f, b)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pts = read_las(str(DATA / "als" / "lidR_Topography.laz"))
    with tempfile.TemporaryDirectory() as tmp:
        for i, (beam, mhz) in enumerate((("strong", 0.15), ("weak", 0.15), ("strong", 3.0),
                                         ("weak", 3.0))):
            for az in (0.0, 60.0):
                line = line_through(pts.bounds, az, inset=9.5)
                sim = simulate_photons(pts, line, SimParams(beam=beam,  # type: ignore[arg-type]
                                                            background_rate_mhz=mhz),
                                       seed=10 * i + int(az))
                path = write_simulation_atl03(sim, Path(tmp) / f"s{i}_{az:g}.h5")
                yield f"sim:{beam}:{mhz}:{az:g}", read_atl03(path, "gt1r", crs=pts.crs)
        sim = simulate_photons(pts, line_through(pts.bounds, 30.0, inset=9.5),
                               SimParams(instrument="mabel", background_rate_mhz=1.0), seed=7)
        path = write_simulation_mabel(sim, Path(tmp) / "mabel.h5")
        yield "sim:mabel", read_mabel(path, 1, crs=pts.crs)
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_atl08_classify import synthetic_beam

    yield "synthetic:2M:1.5MHz", synthetic_beam(2_000_000, 1.5, seed=0)
    for mhz, seed in ((0.15, 1), (3.0, 2)):
        t = synthetic_beam(300_000, mhz, seed=seed)
        t.background = None  # the rate estimated from the photons
        yield f"synthetic:300k:{mhz}MHz:estimated", t


def outputs(track: object) -> dict[str, object]:
    """The classifier's per-photon arrays and the block and segment tables of ``track``."""
    from canopyblocks.blocks import BlockParams
    from canopyblocks.blocks.atl08_classify import classify_photons
    from canopyblocks.blocks.atl08_segments import atl08_segments
    from canopyblocks.blocks.estimators import estimate_blocks, preset

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c = classify_photons(track)  # type: ignore[arg-type]
        blocks = estimate_blocks(track, BlockParams(lengths=(10.0, 25.0, 100.0)),  # type: ignore[arg-type]
                                 preset("atl08"))
        try:
            segs = pd.DataFrame(atl08_segments(track, c))  # type: ignore[arg-type]
        except Exception as e:  # noqa: BLE001 (a track without classified photons)
            segs = pd.DataFrame({"error": [type(e).__name__]})
    return {"classes": c.classes, "height": c.height, "surface_s": c.surface.s,
            "surface_z": c.surface.z, "supported": c.surface.supported,
            "candidates": c.surface.candidates, "background": c.background,
            "blocks": pd.DataFrame(blocks), "segments": segs}


def _safe(name: str) -> str:
    return name.replace(":", "_").replace("/", "_")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("save", "check"))
    ap.add_argument("dir", type=Path)
    args = ap.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    bad = 0
    for name, t in tracks():
        f = args.dir / (_safe(name) + ".pkl")
        if args.mode == "save":
            out = outputs(t)
            pd.to_pickle({**out, "track": t}, f)
            print(f"{name}: {len(out['classes'])} photons saved")  # type: ignore[arg-type]
            continue
        ref = pd.read_pickle(f)
        out = outputs(ref.pop("track"))  # the saved photons (a simulation may not repeat)
        diffs = []
        for k, v in ref.items():
            if isinstance(v, pd.DataFrame):
                try:
                    pd.testing.assert_frame_equal(out[k], v, check_exact=True)  # type: ignore[arg-type]
                except AssertionError as e:
                    diffs.append(f"{k}: {str(e).splitlines()[0]}")
            elif not np.array_equal(out[k], v, equal_nan=v.dtype.kind == "f"):  # type: ignore[call-overload]
                n = int(np.sum(np.asarray(out[k]) != v)) if np.shape(out[k]) == v.shape else -1
                diffs.append(f"{k}: {n} differ")
        bad += bool(diffs)
        print(f"{name}: {'identical' if not diffs else '; '.join(diffs)}")
    print(f"atl08_oracle_mismatches={bad}")


if __name__ == "__main__":
    main()
