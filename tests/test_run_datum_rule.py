"""``run --photons`` applies the one datum rule (issue 10, item 1).

The tiles carry an orthometric vertical datum (here CGVD28, EPSG:5713); the reference
rasters are made in the photons' UTM zone. The rasters' heights keep the tiles' datum,
so ellipsoidal ATL03 heights against them must be refused without --geoid/--offset,
exactly as ``validate`` refuses them, and accepted with an explicit offset.
"""

from __future__ import annotations

import subprocess
import sys

import laspy
import numpy as np
import pyproj
import pytest

from canopyblocks.readers.las import read_las
from canopyblocks.simulate import SimParams, line_through, simulate_photons
from canopyblocks.simulate.writers import write_simulation_atl03

pytestmark = pytest.mark.filterwarnings("ignore::canopyblocks.errors.SparseBlockWarning")


@pytest.fixture(scope="module")
def inputs(sample, pdal_bin, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("run_datum")
    src = sample("als/lasR_bcts_1.laz")
    las = laspy.convert(laspy.read(src), point_format_id=6, file_version="1.4")
    compound = pyproj.CRS.from_user_input("EPSG:3005+5713")
    las.header.vlrs = [v for v in las.header.vlrs if "GeoKey" not in type(v).__name__
                       and "Wkt" not in type(v).__name__]
    las.header.add_crs(compound, keep_compatibility=False)
    tile = tmp / "bcts_cgvd28.laz"
    las.write(tile)
    with laspy.open(tile) as reader:
        assert reader.header.parse_crs().is_compound
    pts = read_las([tile])
    bounds = (pts.x.min(), pts.y.min(), pts.x.max(), pts.y.max())
    sim = simulate_photons(pts, line_through(bounds, 10.0, inset=5), SimParams(), seed=2)
    h5 = tmp / "photons.h5"
    write_simulation_atl03(sim, h5)
    return tile, h5, tmp


def _run(*args):
    return subprocess.run([sys.executable, "-m", "canopyblocks", "run", *map(str, args)],
                          capture_output=True, text=True, timeout=900)


def test_run_refuses_ellipsoidal_photons_against_orthometric_tiles(inputs):
    tile, h5, tmp = inputs
    out = tmp / "refused"
    r = _run(tile, "--photons", h5, "-o", out, "--no-compare")
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert "ellipsoidal" in r.stderr and "--geoid" in r.stderr and "--offset" in r.stderr
    assert not out.exists() or not any(out.iterdir())
    ok = tmp / "accepted"
    r = _run(tile, "--photons", h5, "-o", ok, "--offset", "0", "--no-compare")
    assert r.returncode == 0, r.stderr
    assert (ok / "validation.gpkg").exists()
    # the simulated heights are the tiles' own: with N = 0 the ground bias is the
    # paper estimator's (+1 to +2 m), not tens of metres
    import pandas as pd

    stats = pd.read_csv(ok / "stats.csv")
    g = stats[(stats["metric"] == "ground") & (stats["group"] == "all")]
    assert np.all(np.abs(g["bias"]) < 3.0)


def test_run_reads_the_vertical_datum_from_geotiff_keys(inputs, sample):
    """The bundled LAS 1.2 tile states CGVD28 only in its GeoTIFF keys (PDAL reads it
    so); run used to label it 'unknown' and compare ellipsoidal heights after a warning."""
    _, h5, tmp = inputs
    out = tmp / "refused_keys"
    r = _run(sample("als/lasR_bcts_1.laz"), "--photons", h5, "-o", out, "--no-compare")
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert "CGVD28" in r.stderr and "--geoid" in r.stderr and "--offset" in r.stderr
    assert not out.exists() or not any(out.iterdir())
