"""A COPC file or an EPT dataset made from the bundled BC tiles gives the rasters of the
tiles themselves, cell by cell (the survey catalog sends it to the COPC/EPT readers).

Runs once the COPC/EPT readers are in the package (``canopyblocks.readers.copc`` and
``tests/copc_data.py``, which writes COPC/EPT from tiles); skipped before.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canopyblocks.reference.raster_tiles import cloud_kind
from canopyblocks.reference.rasters import make_reference_rasters
from canopyblocks.workflows.rasters import make_survey_rasters

copc_data = pytest.importorskip("copc_data", reason="the COPC/EPT test writer is not here yet")
pytest.importorskip("canopyblocks.readers.copc", reason="the COPC reader is not here yet")
rasterio = pytest.importorskip("rasterio")

BCTS = ("als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz")
# 60 m x 80 m across the two tiles' shared edge (y = 629400)
BOUNDS = (885080.0, 629360.0, 885140.0, 629440.0)


def _bands(folder: Path) -> dict[str, np.ndarray]:
    out = {}
    for name in ("dtm", "dsm_max", "dsm_p90", "dtm_fill_mask"):
        with rasterio.open(folder / f"{name}.tif") as src:
            out[name] = src.read(1)
    return out


def test_source_kinds() -> None:
    assert cloud_kind("https://host/a/b.copc.laz?sig=1") == "copc"
    assert cloud_kind("s3://bucket/survey/ept.json") == "ept"
    assert cloud_kind("/data/tile.laz") is None


@pytest.mark.parametrize("kind", ["copc", "ept"])
def test_cloud_source_equals_the_tiles(tmp_path: Path, sample, kind: str) -> None:  # noqa: ANN001
    tiles = [sample(p) for p in BCTS]
    if kind == "copc":
        source = tmp_path / "bcts.copc.laz"
        copc_data.write_copc(tiles, source)
    else:
        copc_data.write_ept(tiles, tmp_path / "ept")
        source = tmp_path / "ept" / "ept.json"
    want = make_reference_rasters(tiles, tmp_path / "tiles", bounds=BOUNDS)
    got = make_survey_rasters(str(source), tmp_path / kind, bounds=BOUNDS, backend="serial")
    g, w = got.grid, want.grid
    assert (g.origin_x, g.origin_y, g.width, g.height) == (w.origin_x, w.origin_y, w.width,
                                                           w.height)
    a, b = _bands(tmp_path / kind), _bands(tmp_path / "tiles")
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
