"""The real samples of ``tests/data`` and what the corpus derives from them once per session:
an uncompressed LAS copy, reference rasters made with numpy, simulated blocks, a photon
table."""

from __future__ import annotations

import os
from collections.abc import Callable
from functools import cached_property
from pathlib import Path
from typing import Any

import h5py
import numpy as np


class Base:
    """Paths of the real samples and artefacts derived from them (made on first use)."""

    def __init__(self, data_file: Callable[[str], Path], folder: Path) -> None:
        self.data_file = data_file
        self.folder = folder
        folder.mkdir(parents=True, exist_ok=True)

    # ATL03 / ATL08
    @cached_property
    def vegr(self) -> Path:
        return self.data_file("icesat2/vegr_atl03_clip.h5")

    @cached_property
    def harmony(self) -> Path:
        return self.data_file("icesat2/harmony_ATL03_gt1l.h5")

    @cached_property
    def atl08(self) -> Path:
        return self.data_file("icesat2/vegr_atl08_clip.h5")

    # point clouds
    @cached_property
    def conifer(self) -> Path:
        """The damaged clouds' source; CANOPYBLOCKS_CORPUS_TILE swaps in another tile (a
        fresh corpus from a file the checks were not written against)."""
        other = os.environ.get("CANOPYBLOCKS_CORPUS_TILE")
        return Path(other) if other else self.data_file("als/lidR_MixedConifer.laz")

    @cached_property
    def topo(self) -> Path:
        return self.data_file("als/lidR_Topography.laz")

    @cached_property
    def conifer_las(self) -> Path:
        """An uncompressed LAS 1.2 copy of the MixedConifer tile."""
        import laspy

        out = self.folder / "conifer.las"
        if not out.exists():
            las = laspy.read(self.conifer)
            las.write(out)
        return out

    @cached_property
    def conifer_points(self) -> dict[str, np.ndarray]:
        """The MixedConifer points as laspy reads them (x, y, z metres, class)."""
        import laspy

        las = laspy.read(self.conifer)
        return {"x": np.asarray(las.x, float), "y": np.asarray(las.y, float),
                "z": np.asarray(las.z, float),
                "c": np.asarray(las.classification, np.uint8)}

    # reference rasters over the Topography tile (numpy, independent of PDAL)
    @cached_property
    def rasters(self) -> dict[str, Any]:
        return _make_rasters(self.topo, self.folder / "rasters")

    @cached_property
    def blocks(self) -> Path:
        """Simulated blocks over the Topography tile (GeoPackage, layer blocks)."""
        return _make_blocks(self.topo, self.folder / "blocks")

    @cached_property
    def photon_csv(self) -> Path:
        """gt1r of the vegr clip as a lon/lat/h/time table."""
        import pandas as pd

        out = self.folder / "photons.csv"
        if not out.exists():
            with h5py.File(self.vegr) as f:
                g = f["gt1r/heights"]
                pd.DataFrame({"lon": g["lon_ph"][:], "lat": g["lat_ph"][:],
                              "h": g["h_ph"][:].astype(float),
                              "time": g["delta_time"][:]}).to_csv(out, index=False)
        return out


RASTER_RES = 4.0  # metres


def _make_rasters(tile: Path, folder: Path) -> dict[str, Any]:
    """DTM (mean of class 2), DSM max and p90 on a 4 m grid, nodata -9999 declared."""
    import laspy
    import rasterio
    from rasterio.transform import Affine

    folder.mkdir(parents=True, exist_ok=True)
    las = laspy.read(tile)
    crs = las.header.parse_crs()
    x, y, z = (np.asarray(v, float) for v in (las.x, las.y, las.z))
    cls = np.asarray(las.classification)
    xmin, ymax = float(np.floor(x.min())), float(np.ceil(y.max()))
    w = int(np.ceil((x.max() - xmin) / RASTER_RES))
    h = int(np.ceil((ymax - y.min()) / RASTER_RES))
    col = np.minimum(((x - xmin) / RASTER_RES).astype(int), w - 1)
    row = np.minimum(((ymax - y) / RASTER_RES).astype(int), h - 1)
    cell = row * w + col
    g = cls == 2
    s = np.bincount(cell[g], z[g], w * h)
    n = np.bincount(cell[g], None, w * h)
    dtm = np.where(n > 0, s / np.maximum(n, 1), np.nan)
    top = np.full(w * h, -np.inf)
    np.maximum.at(top, cell, z)
    top[~np.isfinite(top)] = np.nan
    order = np.lexsort((z, cell))
    cs, zs = cell[order], z[order]
    first = np.searchsorted(cs, np.arange(w * h))
    count = np.bincount(cs, None, w * h).astype(int)
    p90 = np.full(w * h, np.nan)
    has = count > 0
    p90[has] = zs[first[has] + np.floor(0.9 * (count[has] - 1)).astype(int)]
    profile = dict(driver="GTiff", width=w, height=h, count=1, dtype="float32",
                   nodata=-9999.0, crs=crs.to_wkt(),
                   transform=Affine(RASTER_RES, 0.0, xmin, 0.0, -RASTER_RES, ymax))
    paths = {}
    for name, arr in (("dtm", dtm), ("dsm_max", top), ("dsm_p90", p90)):
        p = folder / f"{name}.tif"
        with rasterio.open(p, "w", **profile) as dst:
            dst.write(np.where(np.isnan(arr), -9999.0, arr).reshape(h, w).astype("float32"), 1)
        paths[name] = p
    return {"paths": paths, "profile": profile, "crs": crs,
            "ranges": {"dtm": (float(np.nanmin(dtm)), float(np.nanmax(dtm))),
                       "dsm_max": (float(np.nanmin(top)), float(np.nanmax(top))),
                       "dsm_p90": (float(np.nanmin(p90)), float(np.nanmax(p90)))}}


def _make_blocks(tile: Path, folder: Path) -> Path:
    from canopyblocks import BlockParams, read_las
    from canopyblocks.simulate import SimParams, line_through, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03
    from canopyblocks.workflows.blocks import blocks_from_file

    folder.mkdir(parents=True, exist_ok=True)
    out = folder / "blocks.gpkg"
    if out.exists():
        return out
    pts = read_las(tile)
    track = line_through(pts.bounds, 30.0, inset=10.0)
    sim = simulate_photons(pts, track, SimParams(), realisations=1, seed=1)
    h5 = write_simulation_atl03(sim, folder / "sim_atl03.h5")
    blocks_from_file(h5, BlockParams(lengths=(25.0,)), crs=pts.crs, output=out)
    return out
