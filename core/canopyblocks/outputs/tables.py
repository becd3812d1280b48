"""Write and read block tables and layers: GeoPackage, GeoParquet, CSV (atomically)."""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from pathlib import Path

import geopandas as gpd
import pandas as pd

from ..atomic import atomic_output, atomic_outputs, check_writable
from ..errors import DependencyError, FileFormatError, InputError
from ..schema import LAYER_BLOCKS

__all__ = ["check_output_path", "write_table", "write_layers", "layer_files", "read_layer",
           "read_blocks", "SUFFIXES"]

log = logging.getLogger(__name__)

SUFFIXES = (".gpkg", ".parquet", ".geoparquet", ".csv")


def _suffix(path: Path, verb: str = "write") -> str:
    suf = path.suffix.lower()
    if suf not in SUFFIXES:
        raise InputError(
            f"cannot {verb} {path}: unknown suffix {suf!r}; use one of {', '.join(SUFFIXES)}"
        )
    return suf


def check_output_path(path: str | os.PathLike[str], *, layers: Iterable[str] = (),
                      reads: Iterable[tuple[str | os.PathLike[str], str | None]] = ()) -> Path:
    """Check an output table path before any work is done; return it as a Path.

    Parameters
    ----------
    path : path-like
        The output; its suffix must be one of :data:`SUFFIXES` and its folder writable.
    layers : iterable of str
        The layers the run will write (see :func:`layer_files`).
    reads : iterable of (path, layer or None)
        The tables the run reads.  Writing onto one of them is refused unless the
        output is a GeoPackage and the layer read is not among ``layers`` (the other
        layers of a GeoPackage are kept, so the input layer survives).

    Raises
    ------
    InputError
        Unknown suffix, or the output would replace a table that is being read.
    FileFormatError
        The output cannot be written.
    """
    p = Path(path)
    suf = _suffix(p)
    names = list(layers)
    files = list(layer_files(p, names).values()) if names else [p]
    for f in files:
        check_writable(f)
    for src, layer in reads:
        s = Path(src)
        if not s.exists():
            continue
        for f in files:
            if not (f.exists() and os.path.samefile(f, s)):
                continue
            if suf != ".gpkg" or layer is None or layer in names:
                what = f"its layer {layer!r}" if suf == ".gpkg" and layer else "it"
                raise InputError(f"{f}: the output would overwrite {what}, which is an "
                                 "input of this run; give another output file")
    return p


def _gpkg_writer() -> dict[str, object]:
    """Keyword arguments of ``to_file`` for GeoPackages: pyogrio through Arrow where it can
    (measured on 500,000 photons: 4.65 -> 2.11 s, the same layer read back), else the
    default engine (fiona in the QGIS runtime)."""
    try:
        import pyarrow
        import pyogrio
    except ImportError:
        return {}
    # Arrow writes need GDAL 3.6, pyogrio 0.8 and pyarrow 14 (the Arrow C stream protocol)
    if tuple(pyogrio.__gdal_version__) < (3, 6, 0) or \
            _major_minor(pyogrio.__version__) < (0, 8) or \
            _major_minor(pyarrow.__version__) < (14, 0):
        return {"engine": "pyogrio"}
    return {"engine": "pyogrio", "use_arrow": True}


def _major_minor(version: str) -> tuple[int, int]:
    """(major, minor) of a version string such as "0.8.0" or "14.0.2"."""
    parts = (version.split(".") + ["0"])[:2]
    try:
        return int(parts[0]), int("".join(c for c in parts[1] if c.isdigit()) or 0)
    except ValueError:
        return 0, 0


def _write_one(df: pd.DataFrame | Iterable[pd.DataFrame], tmp: Path, suf: str,
               layer: str) -> None:
    if not isinstance(df, pd.DataFrame):  # chunks (e.g. photons track by track)
        if suf != ".gpkg":
            df = pd.concat(list(df), ignore_index=True)
        else:
            first = True
            for chunk in df:
                _write_gpkg(chunk, tmp, layer, append=not first)
                first = False
            if first:
                raise InputError(f"nothing to write to layer {layer!r} of {tmp}: no rows")
            return
    if suf == ".gpkg":
        _write_gpkg(df, tmp, layer)
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


#: GeoPackage version of the files we create: 1.2, which every GDAL since 2.2 reads
#: without a word (GDAL >= 3.7 writes 1.4 by default, and the GDAL 3.6 of QGIS 3.40 warns
#: that a 1.4 file "may only be partially supported").
GPKG_VERSION = "1.2"


def _write_gpkg(df: pd.DataFrame, tmp: Path, layer: str, append: bool = False) -> None:
    new_file = not append and not tmp.exists()
    if isinstance(df, gpd.GeoDataFrame):
        kw = _gpkg_writer()
        if append:
            kw = {**kw, "mode": "a"}
        if new_file and kw.get("engine") == "pyogrio":
            kw = {**kw, "dataset_options": {"VERSION": GPKG_VERSION}}
        df.to_file(tmp, layer=layer, driver="GPKG", **kw)
    else:  # attribute-only table (e.g. stats): a GeoPackage table without geometry
        import pyogrio

        pyogrio.write_dataframe(pd.DataFrame(df), tmp, layer=layer, driver="GPKG",
                                append=append,
                                dataset_options={"VERSION": GPKG_VERSION} if new_file
                                else None)


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
        GeoPackage only: the caller expects the file's other layers and keeps them
        quietly.  Without it they are kept too (only ``layer`` is replaced), with a
        logged warning naming them, since they may come from an earlier run.

    Returns
    -------
    Path
        The file written.
    """
    from ..arguments import check_frame, check_path
    check_frame(df, "write_table: df")
    check_path(path, "write_table: path")
    return write_layers({layer: df}, path, append=append)


def layer_files(path: str | os.PathLike[str], layers: Iterable[str]) -> dict[str, Path]:
    """The file each layer of :func:`write_layers` goes to.

    A GeoPackage holds every layer; a CSV or Parquet ``path`` holds one table, so with
    several layers each goes to ``<stem>_<layer><suffix>`` beside it (and ``path``
    itself is not written).
    """
    p = Path(path)
    names = list(layers)
    if _suffix(p) == ".gpkg" or len(names) <= 1:
        return {n: p for n in names}
    return {n: p.with_name(f"{p.stem}_{n}{p.suffix}") for n in names}


def write_layers(layers: dict[str, pd.DataFrame | Iterable[pd.DataFrame]],
                 path: str | os.PathLike[str], *, append: bool = False) -> Path:
    """Write several layers to one GeoPackage (or one table to CSV/Parquet), atomically.

    A layer may be given as an iterable of frames with the same columns (e.g. the photons
    of one track at a time): a GeoPackage receives them one after the other, so the whole
    layer is never held in memory.

    An existing GeoPackage keeps its other layers: only the layers written are replaced
    (with ``append=False`` a warning is logged naming the layers kept).  For
    .csv/.parquet with several layers, each layer goes to ``<stem>_<layer><suffix>``
    (see :func:`layer_files`); they are written all or none.

    Returns
    -------
    Path
        ``path`` for a GeoPackage or a single table; otherwise the first layer's file.
    """
    from ..arguments import check_mapping, check_path
    check_mapping(layers, "write_layers: layers", "a dict of layer name -> table")
    check_path(path, "write_layers: path")
    p = Path(path)
    suf = _suffix(p)
    if not layers:
        raise InputError(f"nothing to write to {p}: no layers given")
    files = layer_files(p, layers)
    if suf != ".gpkg" and len(layers) > 1:
        with atomic_outputs():
            for name, df in layers.items():
                with atomic_output(files[name]) as tmp:
                    _write_one(df, tmp, suf, name)
        log.info("wrote %s", ", ".join(str(f) for f in files.values()))
        return files[next(iter(layers))]
    kept: list[str] = []
    if suf == ".gpkg" and p.exists():
        kept = [n for n in _gpkg_layers(p) if n not in layers]
    with atomic_output(p, keep_existing=suf == ".gpkg") as tmp:
        for name, df in layers.items():
            _write_one(df, tmp, suf, name)
    if kept and not append:
        log.warning("%s already held layers %s; they were kept, and only %s replaced",
                    p, ", ".join(kept), ", ".join(layers))
    log.info("wrote %s (%s)", p, ", ".join(layers))
    return p


def gpkg_layer_names(path: str | os.PathLike[str]) -> list[str]:
    """Layer names of a GeoPackage, through pyogrio or, where it is absent (the QGIS
    runtime built on Debian's GDAL), fiona.  Raises what the driver raises."""
    try:
        import pyogrio
    except ImportError:
        import fiona

        return [str(n) for n in fiona.listlayers(str(path))]
    return [str(n) for n, _ in pyogrio.list_layers(path)]


def _gpkg_layers(p: Path) -> list[str]:
    """Layer names of an existing GeoPackage; refuse to replace a file that is not one."""
    try:
        return gpkg_layer_names(p)
    except Exception as exc:  # the drivers raise several types for files they cannot open
        raise FileFormatError(f"{p} exists and is not a readable GeoPackage ({exc}); "
                              "remove it or choose another output name") from None


def read_layer(path: str | os.PathLike[str], layer: str | None = None) -> pd.DataFrame:
    """Read a layer/table written by :func:`write_table` (GeoPackage, GeoParquet, CSV).

    A block, segment, footprint or residuals table written by an older version is upgraded
    to today's form here, once (:func:`~canopyblocks.blocks.uncertainty.upgrade_table`:
    missing error bars NaN, missing ``use`` from the flags, ``use`` a bool).

    Raises
    ------
    FileFormatError
        Missing file, unknown layer, or an unreadable file.
    """
    from ..arguments import check_path
    check_path(path, "read_layer: path", "a table file path (.gpkg, .parquet, .csv)")
    p = Path(path)
    if not p.exists():
        raise FileFormatError(f"{p}: no such file")
    from ..blocks.uncertainty import upgrade_table

    return upgrade_table(_read_layer(p, layer))


def _read_layer(p: Path, layer: str | None) -> pd.DataFrame:
    suf = _suffix(p, "read")
    try:
        if suf == ".gpkg":
            names = gpkg_layer_names(p)
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
    from ..arguments import check_path
    check_path(path, "read_blocks: path", "a table file path (.gpkg, .parquet, .csv)")
    df = read_layer(path, layer)
    if not isinstance(df, gpd.GeoDataFrame):
        if not {"x", "y"} <= set(df.columns):
            raise FileFormatError(f"{path}: not a block table (no x/y columns)")
        df = gpd.GeoDataFrame(df, geometry=gpd.points_from_xy(df["x"], df["y"]), crs=None)
    return df
