"""Vertical datums: detection, refusal, geoid and constant-offset conversion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pyproj
import pytest
import rasterio
from affine import Affine

from canopyblocks.errors import CanopyBlocksWarning, CoverageError, DatumError, InputError
from canopyblocks.reference.datum import (
    apply_vertical_offset,
    check_vertical_datums,
    sample_geoid,
    vertical_part,
)


def test_vertical_part() -> None:
    assert vertical_part("EPSG:4979") == "ellipsoidal:World Geodetic System 1984 ensemble"
    v = vertical_part("EPSG:32612+5703")
    assert isinstance(v, pyproj.CRS) and "NAVD88" in v.name
    assert vertical_part("EPSG:5703").name == v.name
    assert vertical_part("EPSG:32612") is None
    assert vertical_part("EPSG:4326") is None


def test_check_decisions() -> None:
    assert check_vertical_datums("EPSG:4979", "EPSG:4979") == "same"
    assert check_vertical_datums("EPSG:32612+5703", "EPSG:26912+5703") == "same"
    with pytest.raises(DatumError, match="NAVD88.*--geoid"):
        check_vertical_datums("EPSG:4979", "EPSG:32612+5703")
    assert check_vertical_datums("EPSG:4979", "EPSG:32612+5703", offset=-17.0) == "differ"
    assert check_vertical_datums("EPSG:4979", "EPSG:5703", geoid="g.tif") == "differ"
    with pytest.warns(CanopyBlocksWarning, match="vertical datum unknown"):
        assert check_vertical_datums("EPSG:4979", "EPSG:32612") == "unknown"
    with pytest.warns(CanopyBlocksWarning):
        assert check_vertical_datums("EPSG:4979", None) == "unknown"
    with pytest.raises(InputError, match="not both"):
        check_vertical_datums("EPSG:4979", "EPSG:5703", geoid="g.tif", offset=1.0)


def _blocks() -> pd.DataFrame:
    return pd.DataFrame({"lon": [-106.565, -106.555, -106.515], "lat": [41.531, 41.538, 41.565],
                         "top": [2500.0, 2510.0, 2520.0], "ground": [2480.0, 2490.0, 2505.0],
                         "z90": [2495.0, 2505.0, 2515.0], "hmax": [20.0, 20.0, 15.0],
                         "h90": [15.0, 15.0, 10.0]})


def test_constant_offset() -> None:
    b = _blocks()
    out = apply_vertical_offset(b, offset=-17.5)  # N = -17.5 m: H = h + 17.5
    np.testing.assert_allclose(out["top"], [2517.5, 2527.5, 2537.5])
    np.testing.assert_allclose(out["ground"], [2497.5, 2507.5, 2522.5])
    np.testing.assert_allclose(out["hmax"], b["hmax"])  # differences unchanged
    assert b["top"].iloc[0] == 2500.0  # input untouched
    with pytest.raises(InputError, match="finite"):
        apply_vertical_offset(b, offset=float("nan"))


def _geoid(path: Path) -> Path:
    """0.01-degree geoid grid over 106.6-106.5 W, 41.5-41.6 N with N = -15 - 10 * row - col."""
    rows, cols = np.mgrid[0:10, 0:10]
    n = (-15.0 - 10.0 * rows - cols).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=10, height=10, count=1,
                       dtype="float32", crs="EPSG:4326", nodata=-9999.0,
                       transform=Affine(0.01, 0, -106.6, 0, -0.01, 41.6)) as dst:
        dst.write(n, 1)
    return path


def test_geoid_raster(tmp_path: Path) -> None:
    g = _geoid(tmp_path / "geoid.tif")
    b = _blocks()
    # by hand: (-106.565, 41.531) -> col 3, row 6; (-106.555, 41.538) -> col 4, row 6;
    # (-106.515, 41.565) -> col 8, row 3
    expected_n = np.array([-15 - 60 - 3, -15 - 60 - 4, -15 - 30 - 8], dtype=float)
    np.testing.assert_allclose(sample_geoid(g, b["lon"], b["lat"]), expected_n)
    out = apply_vertical_offset(b, geoid=g)
    np.testing.assert_allclose(out["top"], b["top"] - expected_n)
    np.testing.assert_allclose(out["h90"], b["h90"])
    far = b.assign(lon=[-100.0, -106.555, -106.515])
    with pytest.raises(CoverageError, match="does not cover 1 block"):
        apply_vertical_offset(far, geoid=g)
    with pytest.raises(InputError, match="not both"):
        apply_vertical_offset(b, geoid=g, offset=1.0)
