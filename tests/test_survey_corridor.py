"""`run` over a survey reads the track's corridor, and gives the same residuals as a run
given only the tiles under the track.

The two bundled BC tiles are cut into a catalog (tests/test_survey_rasters.py) and two
far-away decoy tiles are added; photons are simulated along a diagonal over the two whole
tiles.  Checks: the catalog + decoys run and the run on the two whole tiles give the same
residuals (the corridor's cells are computed from the same points); neither reads the
decoys; and the corridor rasters agree with whole-survey rasters (those of a run before
the corridor was used: the DTM fill is the only thing that can differ) within 0.05 m RMS
on the residuals.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from test_survey_rasters import catalog  # noqa: F401  (the module-scoped fixture)

gpd = pytest.importorskip("geopandas")
pytestmark = pytest.mark.slow  # a simulation and two runs: minutes

LINE = "885040,629180,885200,629680"


def _cli(*args: str) -> None:
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "-q", *args],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr


@pytest.fixture(scope="module")
def runs(tmp_path_factory, catalog):  # noqa: ANN001, F811
    folder, whole_tiles = catalog
    out = tmp_path_factory.mktemp("corridor")
    photons = out / "track.h5"
    _cli("simulate", *map(str, whole_tiles), "--line", LINE, "--seed", "2",
         "--realisations", "1", "-o", str(photons))
    tiles = sorted(str(p) for p in folder.iterdir())
    _cli("run", *tiles, "--photons", str(photons), "--offset", "0", "-o", str(out / "survey"))
    _cli("run", *map(str, whole_tiles), "--photons", str(photons), "--offset", "0",
         "-o", str(out / "under"))
    return out, whole_tiles


def _residuals(folder: Path) -> object:
    r = gpd.read_file(folder / "validation.gpkg", layer="residuals")
    return r.sort_values([c for c in ("track", "length", "block", "metric") if c in r]
                         ).reset_index(drop=True)


def test_survey_run_equals_run_on_the_tiles_under_the_track(runs) -> None:  # noqa: ANN001
    out, _ = runs
    a, b = _residuals(out / "survey"), _residuals(out / "under")
    assert len(a) == len(b) > 20
    num = [c for c in a.columns if c != "geometry" and pd.api.types.is_numeric_dtype(a[c])]
    for c in num:
        np.testing.assert_allclose(a[c].to_numpy(float), b[c].to_numpy(float), atol=1e-6,
                                   equal_nan=True, err_msg=c)


def test_corridor_rasters_cover_the_corridor_only(runs) -> None:  # noqa: ANN001
    rasterio = pytest.importorskip("rasterio")
    out, _ = runs
    with rasterio.open(out / "survey" / "rasters" / "dsm_max.tif") as src:
        a = src.read(1)
        bounds = src.bounds
    valid = a != src.nodata
    # a diagonal corridor: its bounding box is mostly outside it (no decoy far away)
    assert 0.1 < valid.mean() < 0.8
    assert bounds.right - bounds.left < 400 and bounds.top - bounds.bottom < 800


def test_corridor_residuals_agree_with_whole_survey_rasters(runs, tmp_path: Path) -> None:  # noqa: ANN001
    from canopyblocks.reference.rasters import make_reference_rasters
    from canopyblocks.validation.block_validation import validate_blocks

    out, whole_tiles = runs
    blocks = gpd.read_file(out / "under" / "blocks.gpkg", layer="blocks")
    full = make_reference_rasters(whole_tiles, tmp_path / "full", crs=blocks.crs)
    corridor = _residuals(out / "under")
    kw = {"width": 13.0, "offset": 0.0}
    v = validate_blocks(blocks, dtm=full.dtm, dsm_max=full.dsm_max, dsm_p90=full.dsm_p90, **kw)
    ref = v.residuals.sort_values([c for c in ("track", "length", "block", "metric")
                                   if c in v.residuals]).reset_index(drop=True)
    assert len(ref) == len(corridor)
    for col in ("res_ground", "res_top", "res_hmax", "res_h90"):
        d = ref[col].to_numpy(float) - corridor[col].to_numpy(float)
        d = d[np.isfinite(d)]
        assert d.size > 20, col
        assert float(np.sqrt(np.mean(d ** 2))) <= 0.05, col
