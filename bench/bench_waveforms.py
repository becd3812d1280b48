"""Benchmark: GEDI waveforms processed per second on one core, against decoding them.

A GEDI L1B-like file is made from the real subset in ``tests/data/gedi`` by repeating its
300 shots (beam BEAM0101's layout: gzip-compressed ``rxwaveform`` in chunks of 14,200
samples, as the real file) to ``N`` shots (default 20,000). Timed, one core each, best of
three:

- decode: a plain h5py read of ``rxwaveform``, ``rx_sample_count`` and
  ``rx_sample_start_index`` (what any reader must do);
- read: ``canopyblocks.readers.gedi.iter_gedi_l1b`` (the same plus the padded 2-D array);
- process: ``process_waveforms`` (L2A-style, setting a1) on the batches read;
- decompose: the Gaussian decomposition on 1,000 shots (an option; goal: GEDI real time).

Goal (issue 8): processing at least as fast as decoding. GEDI acquires about 1,900
waveforms per second (4 lasers at 242 Hz, 8 beams).

Usage: python bench/bench_waveforms.py [N]
The last line printed is ``waveforms_per_s=<processing rate>``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import zipfile  # noqa: E402
from pathlib import Path  # noqa: E402

import h5py  # noqa: E402
import numpy as np  # noqa: E402

from canopyblocks.readers.gedi import iter_gedi_l1b  # noqa: E402
from canopyblocks.waveforms.decompose import decompose_waveforms  # noqa: E402
from canopyblocks.waveforms.process import process_waveforms  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "gedi"
BEAM = "BEAM0101"


def make_file(src: Path, out: Path, n: int) -> None:
    """``n`` shots of ``BEAM`` repeated from the real subset, in the L1B layout."""
    with h5py.File(src) as f:
        g = f[BEAM]
        start = g["rx_sample_start_index"][:].astype(np.int64)
        count = g["rx_sample_count"][:].astype(np.int64)
        rx = g["rxwaveform"][:]
        per_shot = {k: g[k][:] for k in ("shot_number", "delta_time", "noise_mean_corrected",
                                         "noise_stddev_corrected", "stale_return_flag")}
        geo = {k: g["geolocation"][k][:] for k in (
            "elevation_bin0", "elevation_lastbin", "latitude_bin0", "latitude_lastbin",
            "longitude_bin0", "longitude_lastbin", "degrade")}
    reps = -(-n // len(count))
    idx = np.tile(np.arange(len(count)), reps)[:n]
    rel = start - start[0]
    pieces = [rx[rel[i]:rel[i] + count[i]] for i in range(len(count))]
    wave = np.concatenate([pieces[i] for i in idx])
    counts = count[idx]
    starts = np.concatenate([[1], 1 + np.cumsum(counts)[:-1]]).astype(np.uint64)
    with h5py.File(out, "w") as f:
        g = f.create_group(BEAM)
        g.attrs["description"] = "Full power beam"
        g.create_dataset("rxwaveform", data=wave, chunks=(14200,), compression="gzip")
        g.create_dataset("rx_sample_count", data=counts.astype(np.uint16))
        g.create_dataset("rx_sample_start_index", data=starts)
        for k, v in per_shot.items():
            data = v[idx]
            if k == "shot_number":
                data = np.arange(n, dtype=np.uint64) + np.uint64(10**16)
            if k == "delta_time":
                data = np.arange(n, dtype=np.float64) / 242.0
            g.create_dataset(k, data=data)
        for k, v in geo.items():
            g.create_dataset(f"geolocation/{k}", data=v[idx])


def best(fn, repeat: int = 3) -> float:  # noqa: ANN001
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 20_000
    with tempfile.TemporaryDirectory() as tmp:
        zips = sorted(DATA.glob("GEDI01_B_*.zip"))
        with zipfile.ZipFile(zips[0]) as z:
            name = z.namelist()[0]
            z.extract(name, tmp)
        src = Path(tmp) / name
        path = Path(tmp) / "big_l1b.h5"
        make_file(src, path, n)

        def decode() -> None:
            with h5py.File(path) as f:
                g = f[BEAM]
                g["rxwaveform"][:]
                g["rx_sample_count"][:]
                g["rx_sample_start_index"][:]

        batches = list(iter_gedi_l1b(path, BEAM))

        def read() -> None:
            list(iter_gedi_l1b(path, BEAM))

        def process() -> None:
            for b in batches:
                process_waveforms(b)

        t_dec, t_read, t_proc = best(decode), best(read), best(process)
        sub = batches[0].subset(np.arange(min(1000, len(batches[0]))))
        t_gauss = best(lambda: decompose_waveforms(sub)) / len(sub)
        print(f"{n} waveforms of {BEAM} ({path.stat().st_size / 2**20:.1f} MiB gzip), "
              "CPU seconds, best of 3, one core")
        print(f"decode (plain h5py)      {t_dec:7.2f} s  {n / t_dec:10.0f} waveforms/s")
        print(f"read (iter_gedi_l1b)     {t_read:7.2f} s  {n / t_read:10.0f} waveforms/s")
        print(f"process (L2A-style, a1)  {t_proc:7.2f} s  {n / t_proc:10.0f} waveforms/s")
        print(f"decomposition            {1000 * t_gauss:7.2f} ms per shot "
              f"{1 / t_gauss:10.0f} waveforms/s")
        print(f"processing / decoding rate: {t_dec / t_proc:.2f} (goal >= 1); GEDI acquires "
              "about 1,900 waveforms/s")
        print(f"waveforms_per_s={n / t_proc:.0f}")


if __name__ == "__main__":
    main()
