"""Ways to damage a file: truncate, flip bits, patch bytes, edit HDF5 datasets, rewrite a
point cloud.  Used by :mod:`badinputs.make_corpus`."""

from __future__ import annotations

import shutil
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np

F32_MAX = float(np.finfo(np.float32).max)  # 3.4028235e38, the ICESat-2 float fill value


# ---- byte-level damage ------------------------------------------------------------------------


def truncated(src: Path, dst: Path, n: int) -> Path:
    """The first ``n`` bytes of ``src``."""
    with src.open("rb") as f:
        dst.write_bytes(f.read(max(n, 0)))
    return dst


def bit_flipped(src: Path, dst: Path, positions: list[int]) -> Path:
    """``src`` with one bit flipped at each byte position (bit chosen by the position)."""
    raw = bytearray(src.read_bytes())
    for p in positions:
        raw[p % len(raw)] ^= 1 << (p % 8)
    dst.write_bytes(bytes(raw))
    return dst


def patched(src: Path, dst: Path, patches: list[tuple[int, str, Any]]) -> Path:
    """``src`` with ``struct`` values written at byte offsets: ``[(offset, fmt, value)]``."""
    raw = bytearray(src.read_bytes())
    for offset, fmt, value in patches:
        struct.pack_into(fmt, raw, offset, *(value if isinstance(value, tuple) else (value,)))
    dst.write_bytes(bytes(raw))
    return dst


# ---- HDF5 damage ---------------------------------------------------------------------------------


def h5_edited(src: Path, dst: Path, edit: Callable[[h5py.File], None]) -> Path:
    shutil.copyfile(src, dst)
    with h5py.File(dst, "r+") as f:
        edit(f)
    return dst


def _replace(f: h5py.File, name: str, data: Any, keep_attrs: bool = True) -> None:
    attrs = dict(f[name].attrs) if keep_attrs and name in f else {}
    del f[name]
    ds = f.create_dataset(name, data=data)
    for k, v in attrs.items():
        if k != "_FillValue" or np.asarray(v).dtype.kind == ds.dtype.kind:
            ds.attrs[k] = v


def _part_mask(n: int, frac: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    m = np.zeros(n, bool)
    k = max(1, int(round(frac * n)))
    m[rng.choice(n, size=min(k, n), replace=False)] = True
    return m


def set_values(name: str, value: float | int, frac: float, *, fill_attr: bool = False,
               seed: int = 1) -> Callable[[h5py.File], None]:
    """Set ``frac`` of the rows of dataset ``name`` to ``value`` (optionally declaring it
    as ``_FillValue``)."""

    def edit(f: h5py.File) -> None:
        ds = f[name]
        arr = ds[()]
        n = arr.shape[0]
        m = _part_mask(n, frac, seed) if frac < 1 else np.ones(n, bool)
        if arr.dtype.kind in "iu":
            info = np.iinfo(arr.dtype)
            v = int(np.clip(value, info.min, info.max))
        else:
            v = value
        arr[m] = v
        ds[...] = arr
        if fill_attr:
            ds.attrs["_FillValue"] = np.asarray(v, dtype=arr.dtype)

    return edit


def delete(*names: str) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        for n in names:
            del f[n]

    return edit


def rename(name: str, new: str) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        f.move(name, new)

    return edit


def reshape(name: str, how: str) -> Callable[[h5py.File], None]:
    """Replace dataset ``name`` by a scalar, 2-D, string, shorter, longer, empty or
    retyped copy."""

    def edit(f: h5py.File) -> None:
        arr = f[name][()]
        n = arr.shape[0]
        if how == "scalar":
            new: Any = arr.reshape(-1)[0]
        elif how == "2d":
            new = np.stack([arr, arr], axis=-1)
        elif how == "string":
            new = np.array([str(v).encode() for v in arr.reshape(n, -1)[:, 0]], dtype="S16")
        elif how == "short1":
            new = arr[: n - 1]
        elif how == "half":
            new = arr[: n // 2]
        elif how == "long":
            new = np.concatenate([arr, arr[: max(1, n // 10)]])
        elif how == "empty":
            new = arr[:0]
        elif how == "retype":  # float -> float64, integer -> float32 (values unchanged)
            new = arr.astype(np.float64) if arr.dtype.kind == "f" else arr.astype(np.float32)
        else:
            raise ValueError(how)
        _replace(f, name, new)

    return edit


def keep_photons(beam: str, n_keep: int) -> Callable[[h5py.File], None]:
    """Keep the first ``n_keep`` photons of ``beam`` (and consistent segments)."""

    def edit(f: h5py.File) -> None:
        hg, gg = f"{beam}/heights", f"{beam}/geolocation"
        n = f[f"{hg}/h_ph"].shape[0]
        for k in list(f[hg].keys()):
            if isinstance(f[f"{hg}/{k}"], h5py.Dataset) and f[f"{hg}/{k}"].shape[:1] == (n,):
                _replace(f, f"{hg}/{k}", f[f"{hg}/{k}"][:n_keep])
        cnt = f[f"{gg}/segment_ph_cnt"][()]
        new_cnt = np.zeros_like(cnt)
        new_beg = np.zeros_like(f[f"{gg}/ph_index_beg"][()])
        if n_keep > 0:
            i = int(np.flatnonzero(cnt > 0)[0])
            new_cnt[i] = n_keep
            new_beg[i] = 1
        f[f"{gg}/segment_ph_cnt"][...] = new_cnt
        f[f"{gg}/ph_index_beg"][...] = new_beg

    return edit


def empty_beam_group(beam: str) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        for k in list(f[beam].keys()):
            del f[f"{beam}/{k}"]
        f[beam].create_group("heights")

    return edit


def shift(name: str, by: float) -> Callable[[h5py.File], None]:
    def edit(f: h5py.File) -> None:
        ds = f[name]
        ds[...] = ds[()] + np.asarray(by).astype(ds.dtype)
    return edit


def write_cloud(path: Path, x: np.ndarray, y: np.ndarray, z: np.ndarray, c: np.ndarray,
                crs: Any, *, scale: float = 0.01) -> Path:
    """A LAS/LAZ (by suffix) with the given points and CRS (None: no CRS records)."""
    import laspy

    # LAS 1.4 (WKT CRS records) for compound CRSs, which 1.2's GeoTIFF keys cannot hold
    compound = crs is not None and getattr(crs, "is_compound", False)
    h = laspy.LasHeader(point_format=6 if compound else 1, version="1.4" if compound else "1.2")
    if len(x):
        h.offsets = [float(np.floor(np.min(x))), float(np.floor(np.min(y))),
                     float(np.floor(np.min(z)))]
    h.scales = [scale, scale, scale]
    if crs is not None:
        h.add_crs(crs)
    las = laspy.LasData(h)
    las.x, las.y, las.z = x, y, z
    las.classification = c
    las.write(path)
    return path


def write_cloud_geokeys(path: Path, x: np.ndarray, y: np.ndarray, z: np.ndarray,
                        c: np.ndarray, keys: list[tuple[int, int]], *, version: str = "1.2",
                        scale: float = 0.01) -> Path:
    """A LAS/LAZ whose CRS is only GeoTIFF keys ``[(key id, inline value)]``, e.g.
    ``[(3072, 32613), (4096, 6360), (4099, 9003)]`` (UTM 13N + NAVD88 height in US survey
    feet), as LAS 1.2 writers state it (laspy's own ``add_crs`` writes no vertical key)."""
    import laspy
    from laspy.vlrs.known import GeoKeyDirectoryVlr, GeoKeyEntryStruct, GeoKeysHeaderStructs

    vlr = GeoKeyDirectoryVlr()
    head = GeoKeysHeaderStructs()
    head.key_directory_version, head.key_revision, head.minor_revision = 1, 1, 0
    head.number_of_keys = len(keys)
    vlr.geo_keys_header = head
    entries = []
    for kid, value in keys:
        e = GeoKeyEntryStruct()
        e.id, e.tiff_tag_location, e.count, e.value_offset = kid, 0, 1, value
        entries.append(e)
    vlr.geo_keys = entries
    h = laspy.LasHeader(point_format=6 if version == "1.4" else 1, version=version)
    if len(x):
        h.offsets = [float(np.floor(np.min(x))), float(np.floor(np.min(y))),
                     float(np.floor(np.min(z)))]
    h.scales = [scale, scale, scale]
    h.vlrs.append(vlr)
    las = laspy.LasData(h)
    las.x, las.y, las.z = x, y, z
    las.classification = c
    las.write(path)
    return path
