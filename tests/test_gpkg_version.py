"""GeoPackages we write are version 1.2 (read by every GDAL since 2.2 without a warning;
QGIS 3.40's GDAL 3.6 warns on the 1.4 files GDAL >= 3.7 writes by default): read from the
file header with sqlite3, not through GDAL."""

from __future__ import annotations

import sqlite3

import geopandas as gpd
import pandas as pd

from canopyblocks.outputs.tables import write_layers, write_table


def _version(path) -> tuple[bytes, int]:  # noqa: ANN001
    con = sqlite3.connect(path)
    try:
        app = con.execute("PRAGMA application_id").fetchone()[0]
        user = con.execute("PRAGMA user_version").fetchone()[0]
    finally:
        con.close()
    return app.to_bytes(4, "big"), user


def test_geopackages_are_version_1_2(tmp_path) -> None:
    g = gpd.GeoDataFrame({"a": [1, 2]}, geometry=gpd.points_from_xy([0, 1], [0, 1]),
                         crs=32613)
    many = write_layers({"blocks": g, "stats": pd.DataFrame({"x": [1.0]})},
                        tmp_path / "many.gpkg")
    one = write_table(g, tmp_path / "one.gpkg", layer="blocks")
    table = write_table(pd.DataFrame({"x": [1.0]}), tmp_path / "table.gpkg", layer="stats")
    for path in (many, one, table):
        assert _version(path) == (b"GPKG", 10200), path
    # a layer added to an existing file keeps its version
    write_table(g, one, layer="more", append=True)
    assert _version(one) == (b"GPKG", 10200)
