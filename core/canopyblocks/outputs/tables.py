"""Write and read block tables and layers: GeoPackage, GeoParquet, CSV (atomically)."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import geopandas as gpd
import pandas as pd

from ..errors import DependencyError, FileFormatError, InputError
from ..schema import LAYER_BLOCKS
from .atomic import atomic_output, check_writable

__all__ = ["check_output_path", "write_table", "write_layers", "read_layer", "read_blocks", "SUFFIXES"]

log = logging.getLogger(__name__)

SUFFIXES = (".gpkg", ".parquet", ".geoparquet", ".csv")


def _suffix(path: Path, verb: str = "write") -> str:
    suf = path.suffix.lower()
    if suf not in SUFFIXES:
        raise InputError(
            f"cannot {verb} {path}: unknown suffix {suf!r}; use one of {', '.join(SUFFIXES)}"
        )
    return suf


def check_output_path(path: str | os.PathLike[str]) -> Path:
    """Check an output table path's suffix before any work is done; return it as a Path."""
    p = Path(path)
    _suffix(p)
    check_writable(p)
    return p


def _write_one(df: pd.DataFrame, tmp: Path, suf: str, layer: str) -> None:
    if suf == ".gpkg":
        if isinstance(df, gpd.GeoDataFrame):
            df.to_file(tmp, layer=layer, driver="GPKG")
        else:  # attribute-only table (e.g. stats): a GeoPackage table without geometry
            import pyogrio

            pyogrio.write_dataframe(pd.DataFrame(df), tmp, layer=layer, driver="GPKG")
    elif suf in (".parquet", ".geoparquet"):
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise DependencyError(
                "writing Parquet needs pyarrow: pip install 'canopyblocks[parquet]'"
            ) from None
        if isinstance(df, gpd.GeoDataFrame):
            df.to_parquet(tmp, index=False)
        else:
            pd.DataFrame(df).to_parquet(tmp, index=False)
    else:
        out = pd.DataFrame(df.drop(columns="geometry", errors="ignore"))
        out.to_csv(tmp, index=False, float_format="%.4f")


def write_table(df: pd.DataFrame, path: str | os.PathLike[str], *, layer: str = LAYER_BLOCKS,
                append: bool = False) -> Path:
    """Write one table/layer to ``path`` by its suffix (.gpkg, .parquet, .csv), atomically.

    Parameters
    ----------
    df : DataFrame or GeoDataFrame
        For GeoPackage and GeoParquet a GeoDataFrame keeps its geometry and CRS.
    path : path-like
        Output file.  CSV and Parquet hold one table each.
    layer : str
        GeoPackage layer name.
    append : bool
        GeoPackage only: keep the file's other layers (the file is still replaced
        atomically; an existing layer of the same name is overwritten).
    """
    return write_layers({layer: df}, path, append=append)


def write_layers(layers: dict[str, pd.DataFrame], path: str | os.PathLike[str], *,
                 append: bool = False) -> Path:
    """Write several layers to one GeoPackage (or one table to CSV/Parquet), atomically.

    For .csv/.parquet with several layers, each layer goes to ``<stem>_<layer><suffix>``.
    """
    p = Path(path)
    suf = _suffix(p)
    if suf != ".gpkg" and len(layers) > 1:
        for name, df in layers.items():
            write_table(df, p.with_name(f"{p.stem}_{name}{p.suffix}"), layer=name)
        return p
    with atomic_output(p, keep_existing=append and suf == ".gpkg") as tmp:
        for name, df in layers.items():
            _write_one(df, tmp, suf, name)
    log.info("wrote %s (%s)", p, ", ".join(layers))
    return p


def read_layer(path: str | os.PathLike[str], layer: str | None = None) -> pd.DataFrame:
    """Read a layer/table written by :func:`write_table` (GeoPackage, GeoParquet, CSV).

    Raises
    ------
    FileFormatError
        Missing file, unknown layer, or an unreadable file.
    """
    p = Path(path)
    if not p.exists():
        raise FileFormatError(f"{p}: no such file")
    suf = _suffix(p, "read")
    try:
        if suf == ".gpkg":
            import pyogrio

            names = [n for n, _ in pyogrio.list_layers(p)]
            if layer is not None and layer not in names:
                raise FileFormatError(
                    f"{p}: no layer {layer!r}; the file has {', '.join(names) or 'no layers'}"
                )
            return gpd.read_file(p, layer=layer)
        if suf in (".parquet", ".geoparquet"):
            try:
                return gpd.read_parquet(p)
            except (ValueError, KeyError):
                return pd.read_parquet(p)
        return pd.read_csv(p)
    except FileFormatError:
        raise
    except Exception as exc:  # pyogrio/pyarrow raise many types for corrupt files
        raise FileFormatError(f"{p}: cannot read ({type(exc).__name__}: {exc})") from None


def read_blocks(path: str | os.PathLike[str], layer: str = LAYER_BLOCKS) -> gpd.GeoDataFrame:
    """Read a block table; a CSV is turned into points from its ``x``/``y`` columns.

    A CSV carries no CRS: the result then has ``crs=None`` and callers must set it.
    """
    df = read_layer(path, layer)
    if not isinstance(df, gpd.GeoDataFrame):
        if not {"x", "y"} <= set(df.columns):
            raise FileFormatError(f"{path}: not a block table (no x/y columns)")
        df = gpd.GeoDataFrame(df, geometry=gpd.points_from_xy(df["x"], df["y"]), crs=None)
    return df
