"""Horn slope/aspect against analytic planes and quadrics; per-block classes."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from canopyblocks.errors import InputError
from canopyblocks.reference.corridor import block_corridors
from canopyblocks.reference.terrain import (
    aspect_class,
    block_terrain,
    horn_slope_aspect,
    slope_class,
)
from test_zonal import RES, X0, Y0, make_blocks, write_tif

DIRECTIONS = {"N": 0.0, "NE": 45.0, "E": 90.0, "SE": 135.0, "S": 180.0, "SW": 225.0,
              "W": 270.0, "NW": 315.0}


def plane(facing_deg: float, gradient: float, shape: tuple[int, int] = (40, 50),
          res: float = RES) -> np.ndarray:
    """Heights of a plane whose downhill direction is ``facing_deg`` (clockwise from N)."""
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
    east = (cols + 0.5) * res
    north = -(rows + 0.5) * res
    a = np.radians(facing_deg)
    return 500.0 - gradient * (np.sin(a) * east + np.cos(a) * north)


@pytest.mark.parametrize("name", list(DIRECTIONS))
@pytest.mark.parametrize("gradient", [0.1, 0.7])
def test_planes_facing_eight_directions(name: str, gradient: float) -> None:
    z = plane(DIRECTIONS[name], gradient)
    slope, aspect = horn_slope_aspect(z, RES, RES)
    inner = (slice(1, -1), slice(1, -1))
    np.testing.assert_allclose(slope[inner], np.degrees(np.arctan(gradient)), atol=1e-9)
    diff = (aspect[inner] - DIRECTIONS[name] + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(diff, 0.0, atol=1e-9)
    assert np.isnan(slope[0]).all() and np.isnan(aspect[:, -1]).all()  # outer ring
    assert list(aspect_class(aspect[inner][:3, 0], slope[inner][:3, 0])) == [name] * 3


def test_quadric_against_analytic_gradient() -> None:
    """Horn's weighted central differences are exact for z = a x^2 + b y^2 + c x y."""
    a, b, c, res = 0.003, -0.002, 0.0015, 1.5
    rows, cols = np.mgrid[0:30, 0:35]
    x = (cols + 0.5) * res
    y = -(rows + 0.5) * res
    z = a * x**2 + b * y**2 + c * x * y
    slope, aspect = horn_slope_aspect(z, res, res)
    gx = 2 * a * x + c * y
    gy = 2 * b * y + c * x
    inner = (slice(1, -1), slice(1, -1))
    np.testing.assert_allclose(slope[inner], np.degrees(np.arctan(np.hypot(gx, gy)))[inner],
                               atol=1e-9)
    want = np.degrees(np.arctan2(-gx, -gy)) % 360
    diff = (aspect[inner] - want[inner] + 180) % 360 - 180
    np.testing.assert_allclose(diff, 0.0, atol=1e-7)


def test_flat_nodata_and_classes() -> None:
    z = np.full((5, 5), 10.0)
    slope, aspect = horn_slope_aspect(z, 2.0, 2.0)
    assert (slope[1:-1, 1:-1] == 0).all() and np.isnan(aspect).all()
    z[2, 2] = np.nan
    slope, _ = horn_slope_aspect(z, 2.0, 2.0)
    assert np.isnan(slope[1:-1, 1:-1]).all()  # every inner cell sees the NaN (GDAL rule)
    assert list(aspect_class([10.0, 22.4, 22.6, 337.4, 337.6, 90.0, np.nan],
                             [5, 5, 5, 5, 5, 1.9, np.nan])) == \
        ["N", "N", "NE", "NW", "N", "flat", "unknown"]
    assert list(slope_class([0, 4.99, 5, 10, 19.9, 20, 30, 75, np.nan])) == \
        ["0-5", "0-5", "5-10", "10-20", "10-20", "20-30", ">30", ">30", "unknown"]
    with pytest.raises(InputError, match="2-D"):
        horn_slope_aspect(np.zeros(5), 1.0, 1.0)


@pytest.mark.parametrize("name", list(DIRECTIONS))
def test_block_terrain_on_geotiff(tmp_path: Path, name: str) -> None:
    gradient = 0.25  # 14.04 degrees
    dtm = write_tif(tmp_path / "dtm.tif", plane(DIRECTIONS[name], gradient))
    blocks = make_blocks(4, 15.0, 20.0, X0 + 20.0, Y0 - 50.0)
    ter = block_terrain(block_corridors(blocks, width=4.0), dtm)
    np.testing.assert_allclose(ter["slope"], np.degrees(np.arctan(gradient)), atol=1e-4)
    diff = (ter["aspect"] - DIRECTIONS[name] + 180) % 360 - 180
    np.testing.assert_allclose(diff, 0.0, atol=1e-3)
    assert list(ter["aspect_class"]) == [name] * 4
    assert list(ter["slope_class"]) == ["10-20"] * 4
    assert list(ter["block"]) == [0, 1, 2, 3]


def test_block_circular_mean_and_flat(tmp_path: Path) -> None:
    """Half the block faces NW (315), half NE (45): the circular mean is N, not 180."""
    rows, cols = np.mgrid[0:40, 0:50]
    east = (cols + 0.5) * RES
    north = -(rows + 0.5) * RES
    g = 0.3 / np.sqrt(2)
    z = 500.0 - g * np.abs(east - 50.0) - g * north  # a ridge along x = X0 + 50 m
    dtm = write_tif(tmp_path / "dtm.tif", z)
    # a north-running block centred on the seam at column 25 (x = X0 + 50)
    blocks = make_blocks(2, 20.0, 90.0, X0 + 50.0, Y0 - 75.0)
    ter = block_terrain(block_corridors(blocks, width=10.0), dtm)
    d = (ter["aspect"].to_numpy() + 180) % 360 - 180
    assert np.all(np.abs(d) < 10.0)
    assert list(ter["aspect_class"]) == ["N", "N"]
    flat = write_tif(tmp_path / "flat.tif", plane(90.0, 0.02))  # 1.15 degrees
    ter = block_terrain(block_corridors(blocks, width=4.0), flat)
    assert list(ter["aspect_class"]) == ["flat", "flat"]
    ter = block_terrain(block_corridors(blocks, width=4.0), flat, slope_threshold=1.0)
    assert list(ter["aspect_class"]) == ["E", "E"]


def _gdal_python() -> bool:
    try:
        from osgeo import gdal  # noqa: F401
    except ImportError:
        return False
    return True


@pytest.mark.skipif(not (_gdal_python() or shutil.which("gdaldem")),
                    reason="GDAL (osgeo or gdaldem) is not installed in this environment")
def test_against_gdaldem(tmp_path: Path) -> None:  # pragma: no cover - needs GDAL
    rng = np.random.default_rng(3)
    z = 300 + np.cumsum(np.cumsum(rng.normal(0, 0.3, (30, 40)), 0), 1) * 0.2
    src = write_tif(tmp_path / "z.tif", z, nodata=None)
    outs = {}
    for what in ("slope", "aspect"):
        out = tmp_path / f"{what}.tif"
        if shutil.which("gdaldem"):
            subprocess.run(["gdaldem", what, str(src), str(out), "-alg", "Horn"], check=True,
                           capture_output=True)
        else:
            from osgeo import gdal
            gdal.DEMProcessing(str(out), str(src), what, alg="Horn")
        import rasterio
        with rasterio.open(out) as ds:
            outs[what] = ds.read(1).astype(float)
    slope, aspect = horn_slope_aspect(z.astype(np.float32).astype(float), RES, RES)
    inner = (slice(1, -1), slice(1, -1))
    np.testing.assert_allclose(slope[inner], outs["slope"][inner], atol=1e-3)
    # GDAL works in float32: compare aspects where the slope makes them well defined
    steep = slope[inner] > 2.0
    assert steep.mean() > 0.5
    d = (aspect[inner] - outs["aspect"][inner] + 180) % 360 - 180
    np.testing.assert_allclose(d[steep], 0.0, atol=0.05)  # a convention slip is >= 90
