"""Flash-lidar (ESFL) cubes and dual-wavelength pairs -> the footprints layer: what
``canopyblocks waveforms`` (and ``run``, and the QGIS footprints algorithm) do when the
file is not GEDI L1B.

- ESFL cubes go through the flash-lidar paper's chain
  (:func:`~canopyblocks.waveforms.esfl.esfl_chain`: 4 x 4 pixel region, energy fraction,
  5 m grid, noise from each waveform's histogram + k sd, lowest Gaussian, outlier rule,
  multiscale curvature classification). One row per grid cell (or per footprint with
  ``cell = 0``). The pixels each row merges are a second layer, ``pixels``: the airborne
  reference of a row is what lies under them (``validate``).
- Dual-wavelength pairs go through the dual-wavelength paper's ground finder
  (:func:`~canopyblocks.waveforms.dual_wavelength.dual_wavelength_ground`): one row per
  footprint.

The layer has the GEDI layer's shape where the meaning is shared: ``beam`` (the sensor,
``ESFL`` or ``dual``), ``shot_number`` (row index), ``lon``/``lat`` (degrees WGS84),
``ground`` and ``top`` (m, the file's vertical datum), ``height`` (m), ``flag``, and a
PointZ geometry at the ground in the file's metric CRS (or ``crs``). ``height`` is the
canopy height each paper measures: ESFL ``top - ground`` (top: the highest sample above
the noise threshold); dual the paper's tree height, from the first return above noise
to the ground start (so not ``top - ground``: ``ground`` is the ground return's centre).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd

from ..arguments import check_instance
from ..errors import InputError, NoUsableDataError
from ..progress import Progress, as_progress
from ..schema import FLAG_OK

__all__ = ["LAYER_PIXELS", "esfl_footprints", "dual_footprints", "sensor_footprints",
           "SENSOR_OF_PRODUCT", "SensorOptions"]

log = logging.getLogger(__name__)

#: Layer of the pixels each flash-lidar row merges (``shot_number`` of the row, ``x``,
#: ``y`` pixel centre in the layer's CRS, ``pixel_size`` m, ``along_x``/``along_y``).
LAYER_PIXELS = "pixels"
#: The ``beam`` value (the sensor) of each product's rows.
SENSOR_OF_PRODUCT = {"ESFL": "ESFL", "dual": "dual"}


def _file_crs(crs_text: str, path: object) -> Any:
    from ..errors import CRSError
    from ..geo import as_crs

    if not crs_text:
        raise CRSError(f"{path}: the file states no CRS (root attribute crs); it was not "
                       "written by `canopyblocks simulate`")
    return as_crs(crs_text, f"{path}: crs")


def _opened(path: str | os.PathLike[str], read: Callable[[Any], Any],
            progress: Progress | None, what: str, step: str) -> tuple[Progress, Any, Any]:
    """The progress, the file ``read`` from ``path`` and its CRS (refused without one),
    announcing the reading of ``what`` and then the ``step`` that follows."""
    prog = as_progress(progress)
    prog.update(0.0, f"reading {what}")
    f = read(path)
    src = _file_crs(f.crs, path)
    prog.update(0.2, step)
    return prog, f, src


def _layer(frame: pd.DataFrame, x: np.ndarray, y: np.ndarray, src_crs: Any, crs: Any,
           vertical_datum: str) -> gpd.GeoDataFrame:
    """Lon/lat columns and the PointZ geometry (at the ground) in ``crs`` (default the
    file's)."""
    import pyproj

    from ..geo import as_crs

    ll = pyproj.Transformer.from_crs(src_crs, "EPSG:4326", always_xy=True)
    lon, lat = ll.transform(x, y)
    frame.insert(2, "lon", np.asarray(lon, float))
    frame.insert(3, "lat", np.asarray(lat, float))
    target = as_crs(crs, "crs") if crs is not None else src_crs
    if not target.equals(src_crs, ignore_axis_order=True):
        tr = pyproj.Transformer.from_crs(src_crs, target, always_xy=True)
        x, y = (np.asarray(v, float) for v in tr.transform(x, y))
    z = frame["ground"].to_numpy(float)
    gdf = gpd.GeoDataFrame(frame, geometry=gpd.points_from_xy(x, y, z, crs=target),
                           crs=target)
    gdf.attrs["vertical_datum"] = vertical_datum
    return gdf


def esfl_footprints(path: str | os.PathLike[str], params: Any = None, *, crs: Any = None,
                    progress: Progress | None = None
                    ) -> tuple[gpd.GeoDataFrame, pd.DataFrame]:
    """Footprints (one row per grid cell) and pixels of a flash-lidar cubes file.

    Parameters
    ----------
    path : path
        ESFL cubes (``canopyblocks simulate --sensor esfl``).
    params : EsflParams, optional
        The chain's parameters (the paper's by default: f = 0.5, 5 m grid, 4 sd).
    crs : CRS-like, optional
        Metric CRS of the layer (default the file's).

    Returns
    -------
    (GeoDataFrame, DataFrame)
        The footprints layer (module docstring; also ``n_pixels``, ``noise_mean``,
        ``noise_sd``, ``n_gaussians``, ``ground_gauss`` (m, the lowest Gaussian before
        the filters), ``mcc_ground`` (bool)) and the pixels layer (:data:`LAYER_PIXELS`).
        Flags: ``ok``; ``terrain_outlier`` (the paper's outlier rule: terrain 10 m below
        its neighbours, or height over 60 m); ``no_signal`` (no sample above noise).
    """
    from ..readers.flash_dual import read_esfl_file
    from ..waveforms.esfl import EsflCubes, EsflParams, esfl_chain

    p = check_instance(EsflParams() if params is None else params, EsflParams, "params",
                       "an EsflParams for flash-lidar cubes (None: the defaults)")
    prog, f, src = _opened(path, read_esfl_file, progress, "flash-lidar cubes",
                           "flash-lidar chain")
    wf, res = esfl_chain(EsflCubes(f.cubes, f.top, f.bin_size, f.x, f.y, f.along,
                                   f.pixel_size), p)
    prog.check()
    n = len(res)
    flag = np.full(n, FLAG_OK, dtype=object)
    top = res["top"].to_numpy(float)
    flag[res["outlier"].to_numpy(bool)] = "terrain_outlier"
    flag[~np.isfinite(top) | ~np.isfinite(res["terrain"].to_numpy(float))] = "no_signal"
    frame = pd.DataFrame({
        "beam": np.full(n, "ESFL", dtype=object), "shot_number": np.arange(n, dtype=np.int64),
        "ground": res["terrain"].to_numpy(float), "top": top,
        "height": res["height"].to_numpy(float), "n_pixels": res["n_pixels"].to_numpy(),
        "noise_mean": res["noise_mean"].to_numpy(float),
        "noise_sd": res["noise_sd"].to_numpy(float),
        "n_gaussians": res["n_gaussians"].to_numpy(np.int64),
        "ground_gauss": res["ground_gauss"].to_numpy(float),
        "mcc_ground": res["mcc_ground"].to_numpy(bool), "flag": flag})
    gdf = _layer(frame, res["x"].to_numpy(float), res["y"].to_numpy(float), src, crs,
                 f.vertical_datum)
    gdf.attrs["grid_cell"] = float(p.cell)
    px, py = wf.pixel_x, wf.pixel_y
    if not gdf.crs.equals(src, ignore_axis_order=True):
        import pyproj

        tr = pyproj.Transformer.from_crs(src, gdf.crs, always_xy=True)
        px, py = (np.asarray(v, float) for v in tr.transform(px, py))
    pixels = pd.DataFrame({"shot_number": np.asarray(wf.pixel_group, np.int64),
                           "x": np.asarray(px, float), "y": np.asarray(py, float),
                           "pixel_size": float(wf.pixel_size),
                           "along_x": float(wf.along[0]), "along_y": float(wf.along[1])})
    prog.update(1.0, f"{n} flash-lidar waveforms")
    return gdf, pixels


def dual_footprints(path: str | os.PathLike[str], params: Any = None, *, crs: Any = None,
                    progress: Progress | None = None) -> gpd.GeoDataFrame:
    """Footprints of a dual-wavelength pairs file (one row per footprint).

    Parameters
    ----------
    path : path
        Dual-wavelength pairs (``canopyblocks simulate --sensor dual``).
    params : DualParams, optional
        The ground finder's parameters (the paper's steps by default; ``method="refined"``
        adds this project's three steps).
    crs : CRS-like, optional
        Metric CRS of the layer (default the file's).

    Returns
    -------
    GeoDataFrame
        The footprints layer (module docstring; ``ground`` the ground return's centre,
        also ``ground_start``, ``ground_end`` (m) and ``smoothing_width`` (samples; 0: the
        refined gap rule)). Flags: ``ok``; ``no_signal`` (no sample above noise in both
        bands); ``no_ground`` (no single ground edge found).
    """
    from ..readers.flash_dual import read_dual_file
    from ..waveforms.dual_wavelength import DualParams, dual_wavelength_ground

    p = check_instance(DualParams() if params is None else params, DualParams, "params",
                       "a DualParams for dual-wavelength pairs (None: the defaults)")
    prog, f, src = _opened(path, read_dual_file, progress, "dual-wavelength pairs",
                           "dual-wavelength ground")
    g = dual_wavelength_ground(f.visible, f.nir, noise_mean=f.noise_mean,
                               noise_sd=f.noise_sd, params=p)
    prog.check()
    n = len(f.top)

    def elevation(pos: np.ndarray) -> np.ndarray:
        return f.top - np.asarray(pos, float) * f.bin_size

    first = g.first if g.first is not None else np.full(n, np.nan)
    flag = np.full(n, FLAG_OK, dtype=object)
    flag[~g.found] = "no_ground"
    flag[~np.isfinite(first) | ~np.isfinite(f.top)] = "no_signal"
    frame = pd.DataFrame({
        "beam": np.full(n, "dual", dtype=object), "shot_number": np.arange(n, dtype=np.int64),
        "ground": elevation(g.centre), "top": elevation(first),
        "height": g.tree_height(f.bin_size), "ground_start": elevation(g.start),
        "ground_end": elevation(g.end), "smoothing_width": np.asarray(g.width, float),
        "flag": flag})
    gdf = _layer(frame, f.x, f.y, src, crs, f.vertical_datum)
    # how the pairs were read: the like-with-like reference reads its own pairs alike
    gdf.attrs.update({"noise": f.noise, "bin_size": f.bin_size, "dual_params": p})
    prog.update(1.0, f"{n} dual-wavelength footprints")
    return gdf


@dataclass(frozen=True)
class SensorOptions:
    """The command line's options for ESFL and dual files, None where not given.

    ``fraction`` (ESFL: energy fraction defining a footprint's pixels), ``cell`` (ESFL:
    grid cell, m; 0 one waveform per footprint), ``noise_fit`` (ESFL: ``ml`` or ``lsq``),
    ``noise_threshold`` (both: sd above the noise mean, the papers' 4), ``dual_method``
    (dual: ``paper`` or ``refined``)."""

    fraction: float | None = None
    cell: float | None = None
    noise_fit: str | None = None
    noise_threshold: float | None = None
    dual_method: str | None = None

    def given(self) -> list[str]:
        """The command line names of the options given (``--k-sigma`` for the threshold)."""
        return [name for name, v in (("--fraction", self.fraction), ("--cell", self.cell),
                                     ("--noise-fit", self.noise_fit),
                                     ("--k-sigma", self.noise_threshold),
                                     ("--dual-method", self.dual_method)) if v is not None]

    def esfl_params(self, path: object) -> Any:
        """EsflParams with the options given (the dual one refused)."""
        from ..waveforms.esfl import EsflParams

        if self.dual_method is not None:
            raise InputError(f"{path} holds flash-lidar (ESFL) cubes: --dual-method applies "
                             "to dual-wavelength pairs only")
        kw: dict[str, Any] = {k: v for k, v in (
            ("fraction", self.fraction), ("cell", self.cell), ("noise_fit", self.noise_fit),
            ("k", self.noise_threshold)) if v is not None}
        return replace(EsflParams(), **kw)

    def dual_params(self, path: object) -> Any:
        """DualParams with the options given (the flash-lidar ones refused)."""
        from ..waveforms.dual_wavelength import DualParams

        given = [name for name, v in (("--fraction", self.fraction), ("--cell", self.cell),
                                      ("--noise-fit", self.noise_fit)) if v is not None]
        if given:
            verb = "applies" if len(given) == 1 else "apply"
            raise InputError(f"{path} holds dual-wavelength pairs: {', '.join(given)} "
                             f"{verb} to flash-lidar (ESFL) cubes only; leave it out")
        kw: dict[str, Any] = {k: v for k, v in (("method", self.dual_method),
                                                ("k", self.noise_threshold)) if v is not None}
        return replace(DualParams(), **kw)


def sensor_footprints(path: str | os.PathLike[str], product: str, *, esfl: Any = None,
                      dual: Any = None, options: SensorOptions | None = None,
                      crs: Any = None, progress: Progress | None = None
                      ) -> dict[str, pd.DataFrame]:
    """The layers of an ESFL or dual file: ``{"footprints": ..., "pixels": ...}`` (pixels
    for ESFL only). ``product`` as :func:`~canopyblocks.readers.flash_dual.waveform_product`
    tells; parameters either as ``esfl`` / ``dual`` (EsflParams / DualParams) or as the
    command line's ``options`` (:class:`SensorOptions`)."""
    from ..schema import LAYER_FOOTPRINTS

    opts = options or SensorOptions()
    if product == "ESFL":
        p = esfl if esfl is not None else opts.esfl_params(path)
        fp, pixels = esfl_footprints(path, p, crs=crs, progress=progress)
        return {LAYER_FOOTPRINTS: fp, LAYER_PIXELS: pixels}
    if product == "dual":
        p = dual if dual is not None else opts.dual_params(path)
        return {LAYER_FOOTPRINTS: dual_footprints(path, p, crs=crs, progress=progress)}
    raise NoUsableDataError(f"{path}: {product} is neither ESFL cubes nor dual-wavelength "
                            "pairs")
