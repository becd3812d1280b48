"""Many granules from object storage: ``batch`` given ``s3://`` URLs (a prefix or a list)
on a loopback S3 server; Dask workers read their granules from storage themselves (the
units carry URLs, not bytes) and the validated blocks equal those of the local files."""

from __future__ import annotations

import shutil

import pandas as pd
import pytest

pytest.importorskip("s3fs")
pytest.importorskip("moto")
pytest.importorskip("distributed")

from canopyblocks.readers import remote  # noqa: E402
from canopyblocks.readers.las import read_las  # noqa: E402
from canopyblocks.simulate import SimParams, line_through, simulate_photons  # noqa: E402
from canopyblocks.simulate.writers import write_simulation_atl03  # noqa: E402
from canopyblocks.workflows.batch import BatchConfig, run_batch  # noqa: E402
from loopback_servers import S3Server  # noqa: E402

pytestmark = [pytest.mark.pdal, pytest.mark.slow,
              pytest.mark.filterwarnings("ignore::canopyblocks.errors.CanopyBlocksWarning")]

CONFIG = BatchConfig(lengths=(25.0,), width=13.0, offset=0.0)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, sample, pdal_bin):
    root = tmp_path_factory.mktemp("remote_batch")
    tiles = root / "tiles"
    tiles.mkdir()
    for name in ("lasR_bcts_1.laz", "lasR_bcts_2.laz"):
        shutil.copy(sample(f"als/{name}"), tiles / name)
    pts = read_las(sorted(str(p) for p in tiles.iterdir()))
    b = pts.bounds
    cx, cy = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2
    granules = root / "granules"
    granules.mkdir()
    for i, (az, dx) in enumerate(((10.0, -40.0), (5.0, 0.0))):
        tr = line_through(b, az, centre=(cx + dx, cy), inset=7, name="gt1r")
        sim = simulate_photons(pts, tr, SimParams(), realisations=2, seed=40 + i)
        write_simulation_atl03(sim, granules / f"ATL03_sim{i}.h5", realisations=(0, 1))
    return {"granules": granules, "tiles": tiles}


def test_dask_workers_read_urls_same_blocks_as_local(inputs, tmp_path, monkeypatch):
    with S3Server() as server:
        for p in sorted(inputs["granules"].iterdir()):
            server.put("store", f"atl03/{p.name}", p)
        for var in ("AWS_PROFILE", "AWS_SESSION_TOKEN", "AWS_ENDPOINT_URL_S3"):
            monkeypatch.delenv(var, raising=False)
        # the workers are other processes: they inherit this environment
        monkeypatch.setenv("AWS_ACCESS_KEY_ID", "testing")
        monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "testing")
        monkeypatch.setenv("AWS_DEFAULT_REGION", "us-east-1")
        monkeypatch.setenv("AWS_ENDPOINT_URL", server.endpoint)
        monkeypatch.setenv("AWS_EC2_METADATA_DISABLED", "true")
        monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "none"))
        monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "none"))
        remote.clear_cache()
        local = run_batch(sorted(str(p) for p in inputs["granules"].iterdir()),
                          [inputs["tiles"]], tmp_path / "local", CONFIG, backend="serial")
        listing = tmp_path / "granules.txt"
        listing.write_text("s3://store/atl03/ATL03_sim0.h5\ns3://store/atl03/ATL03_sim1.h5\n",
                           encoding="utf-8")
        for name, given in (("prefix", ["s3://store/atl03/"]), ("listing", [str(listing)])):
            out = tmp_path / name
            res = run_batch(given, [inputs["tiles"]], out, CONFIG, backend="dask", workers=2)
            assert not res.failed, res.failed
            granules = {u["granule"] for u in res.units}
            assert granules == {"s3://store/atl03/ATL03_sim0.h5",
                                "s3://store/atl03/ATL03_sim1.h5"}
            a = pd.read_parquet(tmp_path / "local" / "residuals.parquet")
            b = pd.read_parquet(out / "residuals.parquet")
            assert len(a) > 0
            pd.testing.assert_frame_equal(a, b, check_exact=True)
        assert len(local.units) == len(res.units)
