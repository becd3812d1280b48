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
    print(f"remote_bbox_bytes_share={rows[1][2] / size:.4f}")


if __name__ == "__main__":
    main()
