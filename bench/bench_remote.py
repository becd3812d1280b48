"""Bytes a study area costs when the granule stays in object storage.

Run: ``.venv/bin/python bench/bench_remote.py [--km 300] [--per-metre 5] [--bbox-km 5]``

A ``--km`` long ATL03 granule of three strong beams (``--per-metre`` photons per metre each,
written as real v006 granules are: gzip chunks of 10,000 rows; ``tests/loopback_servers.py``)
is made once (cached in ``--workdir``) and served by an S3 server on the loopback address
(moto's S3 application on 127.0.0.1, a free port; no network).  ``canopyblocks blocks``'s
core call (:func:`canopyblocks.blocks_from_file`) then reads it from ``s3://`` twice, each
in a fresh process state (empty caches):

1. the whole granule;
2. a ``--bbox-km`` box (along the track) in its middle.

The server counts the GET requests and the body bytes it sends; they are printed beside the
file's size, with the blocks of each run checked identical to those of the local file.  The
same for a GEDI L1B granule of the same length (4 beams, the real waveforms of
``tests/data/gedi`` repeated, a shot every 60 m) served over https-style range requests
(a loopback HTTP server): the per-shot positions are read whole, the waveforms only for the
shots inside.  The
last line is ``remote_bbox_bytes_share=<bytes of the bbox run / file size>`` (the issue's
goal: < 0.20 for 5 km of a 300 km granule).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--km", type=float, default=300.0)
    ap.add_argument("--per-metre", type=float, default=5.0)
    ap.add_argument("--bbox-km", type=float, default=5.0)
    ap.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "cb_bench_remote"))
    args = ap.parse_args()

    import pandas as pd

    from canopyblocks import BlockParams, blocks_from_file
    from canopyblocks.readers import remote
    from loopback_servers import S3Server, write_track_granule

    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    path = work / f"ATL03_{int(args.km)}km_{args.per_metre:g}pm.h5"
    if not path.exists():
        t = time.perf_counter()
        write_track_granule(path, args.km, args.per_metre)
        print(f"granule made in {time.perf_counter() - t:.0f} s")
    size = path.stat().st_size
    mid = 41.5 + args.km * 500.0 * 9.0e-6  # the track runs north, 9e-6 deg of lat per m
    half = args.bbox_km * 500.0 * 9.0e-6
    bbox = (-106.58, mid - half, -106.55, mid + half)
    params = BlockParams(lengths=(25.0,))
    os.environ.update(AWS_ACCESS_KEY_ID="bench", AWS_SECRET_ACCESS_KEY="bench",
                      AWS_DEFAULT_REGION="us-east-1", AWS_EC2_METADATA_DISABLED="true")
    with S3Server() as server:
        os.environ["AWS_ENDPOINT_URL"] = server.endpoint
        url = server.put("granules", path.name, path)
        print(f"granule: {args.km:g} km, 3 beams, {args.per_metre:g} photons/m, "
              f"{size / 1e6:.1f} MB; served at {server.endpoint}")
        rows = []
        for name, box in (("whole granule", None), (f"{args.bbox_km:g} km bbox", bbox)):
            remote.clear_cache()
            server.tally.reset()
            t = time.perf_counter()
            got = blocks_from_file(url, params, bbox=box, workers=1).blocks
            secs = time.perf_counter() - t
            n_req, n_bytes = server.tally.requests, server.tally.nbytes
            local = blocks_from_file(str(path), params, bbox=box, workers=1).blocks
            pd.testing.assert_frame_equal(got, local, check_exact=True)
            rows.append((name, n_req, n_bytes))
            print(f"{name:>16}: {n_req:5d} requests, {n_bytes / 1e6:8.2f} MB "
                  f"({n_bytes / size:6.1%} of the file), {len(got)} blocks identical to "
                  f"the local file's, {secs:.1f} s")
    gedi_share(work, args.km, args.bbox_km)
    print(f"remote_bbox_bytes_share={rows[1][2] / size:.4f}")


def gedi_granule(work: Path, km: float) -> Path:
    """A GEDI L1B granule of 4 beams, ``km`` long (a shot every 60 m), its waveforms the real
    ones of tests/data/gedi repeated (the canopyblocks L1B layout: rxwaveform gzip-chunked)."""
    import dataclasses
    import zipfile

    import numpy as np

    from canopyblocks.outputs.h5_gedi_l1b import write_gedi_l1b
    from canopyblocks.readers.gedi import gedi_beams, read_gedi_l1b

    out = work / f"GEDI01_B_{int(km)}km.h5"
    if out.exists():
        return out
    with zipfile.ZipFile(ROOT / "tests/data/gedi/"
                         "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.zip") as zf:
        src = zf.extract([n for n in zf.namelist() if n.endswith(".h5")][0], work)
    n = int(km * 1000 / 60)
    s = np.arange(n) * 60.0
    batches = []
    for beam in gedi_beams(src)[:4]:
        b = read_gedi_l1b(src, beam)
        pick = np.arange(n) % len(b.shot_number)
        f = {fl.name: getattr(b, fl.name)[pick] for fl in dataclasses.fields(b)
             if isinstance(getattr(b, fl.name), np.ndarray)
             and getattr(b, fl.name).shape[:1] == b.shot_number.shape}
        lat = 40.0 + s * 9.0e-6
        f.update(lat_bin0=lat, lat_lastbin=lat, lon_bin0=np.full(n, -100.0),
                 lon_lastbin=np.full(n, -100.0), time=s / 7000.0,
                 shot_number=np.arange(1, n + 1, dtype=np.uint64))
        batches.append(dataclasses.replace(b, **f, extra={}))
    write_gedi_l1b(out, batches)
    Path(src).unlink()
    return out


def gedi_share(work: Path, km: float, bbox_km: float) -> None:
    """Bytes of a GEDI L1B granule read whole and for a bbox, from a loopback HTTP server."""
    from canopyblocks.readers import remote
    from canopyblocks.readers.gedi import iter_gedi_l1b
    from loopback_servers import RangeHTTPServer

    path = gedi_granule(work, km)
    size = path.stat().st_size
    mid = 40.0 + km * 500.0 * 9.0e-6
    half = bbox_km * 500.0 * 9.0e-6
    with RangeHTTPServer(path.parent) as server:
        url = f"{server.url}/{path.name}"
        for name, box in (("GEDI whole", None),
                          (f"GEDI {bbox_km:g} km bbox", (-100.1, mid - half, -99.9, mid + half))):
            remote.clear_cache()
            server.tally.reset()
            shots = sum(len(b.shot_number) for b in iter_gedi_l1b(url, bbox=box))
            local = sum(len(b.shot_number) for b in iter_gedi_l1b(path, bbox=box))
            assert shots == local
            print(f"{name:>16}: {server.tally.requests:5d} requests, "
                  f"{server.tally.nbytes / 1e6:8.2f} MB ({server.tally.nbytes / size:6.1%} of "
                  f"the {size / 1e6:.1f} MB file), {shots} shots")


if __name__ == "__main__":
    main()
