"""Checks of per-photon HDF5 datasets: shapes, types, and values a photon cannot have.

A damaged or unusual granule must give the right photons, flagged, or a refusal, never a
plausible-looking wrong number.  Two kinds of damage are told apart:

* a dataset of the wrong shape or type (a scalar, 2-D, text, shorter or longer than its
  siblings) leaves no way to know which value belongs to which photon: the file is refused
  (:class:`~canopyblocks.errors.FileFormatError` naming the dataset);
* single values that are NaN, infinite, the dataset's ``_FillValue``, the float32 fill of
  ICESat-2 products (3.4028235e38) or outside what any photon can have are read as missing:
  those photons are dropped with an :class:`InvalidPhotonsWarning` that counts them.  A
  column in which no value is valid is a damaged file, not "no photons".
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np

from ..errors import CanopyBlocksWarning, FileFormatError
from ._h5 import H5File

__all__ = ["InvalidPhotonsWarning", "PHOTON_LIMITS", "S_LIMIT", "FLOAT32_FILL", "check_photon_datasets",
           "valid_photon_mask", "drop_invalid_photons"]

FLOAT32_FILL = 3.4028235e38
"""The fill value ICESat-2 products use in float datasets (float32 max)."""

PHOTON_LIMITS: dict[str, tuple[float, float]] = {
    "h_ph": (-1000.0, 9000.0),  # m above the ellipsoid: every land surface lies in between
    "lat_ph": (-90.0, 90.0),  # degrees
    "lon_ph": (-180.0, 180.0),  # degrees
    "dist_ph_along": (-1000.0, 1000.0),  # m from the segment start (a segment is ~20 m)
    "delta_time": (-1e10, 1e10),  # s since 2018-01-01 (the mission lasts ~1e9 s)
    "signal_conf_ph": (-2.0, 4.0),  # the product's confidence classes
}
"""Closed ranges of values a photon can have, per ATL03 dataset (units in comments)."""

S_LIMIT = 5.0e7
"""|segment_dist_x| above this (m; one orbit is ~4.0e7 m) is a fill value."""


class InvalidPhotonsWarning(CanopyBlocksWarning):
    """Photons with NaN, infinite, fill or impossible values were dropped (and counted)."""


def check_photon_datasets(f: H5File, group: str, names: tuple[str, ...],
                          optional: tuple[str, ...] = ()) -> int:
    """Refuse per-photon datasets of the wrong shape or type; return the photon count.

    Parameters
    ----------
    f : H5File
        The open file.
    group : str
        Group holding the datasets, e.g. ``"gt1r/heights"``.
    names : tuple of str
        Datasets that must exist, be numeric and hold one value per photon; the first
        sets the photon count.
    optional : tuple of str
        Datasets checked the same way when present (a second dimension is allowed:
        ``signal_conf_ph`` has one column per surface type).

    Raises
    ------
    FileFormatError
        A dataset is missing, not numeric, or not one value per photon.
    """
    first = f"{group}/{names[0]}"
    shape = f.shape(first)
    if len(shape) != 1:
        raise FileFormatError(
            f"{f.path}: /{first} has shape {shape}, not one value per photon; the file is "
            "damaged or not the expected product")
    n = int(shape[0])
    for name in names + tuple(o for o in optional if f.is_dataset(f"{group}/{o}")):
        path = f"{group}/{name}"
        shp = f.shape(path)
        ok_shape = shp[:1] == (n,) and (len(shp) == 1 or (name in optional and len(shp) == 2))
        if not ok_shape:
            raise FileFormatError(
                f"{f.path}: /{path} has shape {shp} but /{first} has {n} photons; each "
                "per-photon dataset needs one value per photon, so the file is damaged")
        if f.dtype(path).kind not in "biuf":
            raise FileFormatError(
                f"{f.path}: /{path} holds {f.dtype(path)} values, not numbers; the file is "
                "damaged or not the expected product")
    return n


def valid_photon_mask(name: str, values: np.ndarray, fill: object = None) -> np.ndarray:
    """True where ``values`` of dataset ``name`` can belong to a photon.

    NaN, infinities, the declared ``fill`` (the dataset's ``_FillValue``), the float32
    fill and values outside :data:`PHOTON_LIMITS` are invalid.
    """
    lo, hi = PHOTON_LIMITS.get(name, (-np.inf, np.inf))
    v = np.asarray(values)
    fv = None
    if fill is not None:
        try:
            fv = float(np.asarray(fill).reshape(-1)[0])
        except (TypeError, ValueError, IndexError):
            fv = None
    if v.size and v.dtype.kind in "biuf":
        # the usual case, in two reductions: every value valid (a NaN fails the test)
        vmin, vmax = float(np.min(v)), float(np.max(v))
        if (lo <= vmin and vmax <= hi and max(-vmin, vmax) < FLOAT32_FILL * 0.999
                and not (fv is not None and vmin <= fv <= vmax)):
            return np.ones(v.shape, bool)
    with np.errstate(invalid="ignore"):
        ok = (v >= lo) & (v <= hi)  # False for NaN
        if v.dtype.kind == "f":
            ok &= np.abs(v) < FLOAT32_FILL * 0.999
    if fv is not None and np.isfinite(fv):
        ok &= v != fv
    return ok


def drop_invalid_photons(source: object, what: str, masks: Mapping[str, np.ndarray]
                         ) -> np.ndarray | None:
    """Combine per-dataset validity masks; warn with the counts; None when all are valid.

    Parameters
    ----------
    source : path-like or str
        The file, named in the messages.
    what : str
        What the photons are (e.g. ``"beam gt1r"``), named in the messages.
    masks : mapping of dataset path -> bool array
        From :func:`valid_photon_mask`, all of one length.

    Raises
    ------
    FileFormatError
        A dataset holds no valid value at all (the file is damaged).
    """
    keep: np.ndarray | None = None
    bad_counts: dict[str, int] = {}
    for name, ok in masks.items():
        n_bad = int(ok.size - np.count_nonzero(ok))
        if n_bad == 0:
            continue
        if n_bad == ok.size:
            raise FileFormatError(
                f"{source}: /{name}: none of its {ok.size} values is valid (NaN, "
                "infinite, fill or impossible values); the file is damaged")
        bad_counts[name] = n_bad
        keep = ok.copy() if keep is None else keep & ok
    if keep is None:
        return None
    if not keep.any():
        raise FileFormatError(
            f"{source}: {what}: no photon has valid values in every dataset; the file is "
            "damaged")
    detail = ", ".join(f"{n} in /{k}" for k, n in bad_counts.items())
    warnings.warn(
        f"{source}: {what}: dropped {keep.size - int(keep.sum())} of {keep.size} photons "
        f"whose values are NaN, infinite, fill values or impossible ({detail})",
        InvalidPhotonsWarning, stacklevel=3)
    return keep
