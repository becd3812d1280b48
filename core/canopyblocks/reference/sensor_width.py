"""The one corridor-width rule: the footprint of the sensor the photons came from.

A block is compared with the reference over a corridor as wide as the laser footprint
that took its photons: ICESat-2 about 13 m (ATLAS's footprint diameter early in the
mission), MABEL 2 m (the 2 m corridor of the paper, whose airborne footprint
is about 2 m). Every door (``validate``, ``calibrate``, ``run``, ``batch``, QGIS, Python)
asks :func:`corridor_width` when the user gives no width; a photon table of no known
sensor needs an explicit width.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from ..errors import InputError
from ..photons import sensor_of_track

__all__ = ["SENSOR_WIDTHS", "sensor_width", "corridor_width", "sensor_of_product",
           "width_help"]

#: Corridor width (m) per sensor: its laser footprint diameter.
SENSOR_WIDTHS: dict[str, float] = {"ICESat-2": 13.0, "MABEL": 2.0}

_PRODUCT_SENSORS = {"ATL03": "ICESat-2", "ATL08": "ICESat-2", "MABEL": "MABEL"}


def width_help() -> str:
    """The rule in one sentence, for option help texts."""
    return ("Corridor width, m (default: the footprint of the photons' sensor, "
            + ", ".join(f"{k} {v:g} m" for k, v in SENSOR_WIDTHS.items())
            + "; needed for photon tables of no known sensor).")


def sensor_width(sensor: str) -> float:
    """The corridor width (m) of ``sensor`` (``"ICESat-2"`` or ``"MABEL"``)."""
    try:
        return SENSOR_WIDTHS[sensor]
    except KeyError:
        raise InputError(f"unknown sensor {sensor!r}; the widths known are "
                         f"{', '.join(f'{k} {v:g} m' for k, v in SENSOR_WIDTHS.items())}"
                         ) from None


def sensor_of_product(product: str) -> str | None:
    """The sensor of a photon product (``readers.detect_product``): ``ATL03``/``ATL08``
    -> ICESat-2, ``MABEL`` -> MABEL, a table -> None."""
    return _PRODUCT_SENSORS.get(str(product))


def corridor_width(width: float | None, tracks: Iterable[str] = (), *,
                   sensor: str | None = None, source: str = "the photons") -> float:
    """The corridor width to use: ``width`` when given, else the footprint of the sensor.

    Parameters
    ----------
    width : float or None
        A width the user gave (m, > 0), used as it is.
    tracks : iterable of str
        Track ids of the blocks (``gt1l`` .. ``gt3r``: ICESat-2; ``channelNNN``: MABEL),
        used when ``sensor`` is None.
    sensor : str, optional
        ``"ICESat-2"`` or ``"MABEL"`` when known from the file.
    source : str
        The file named in the error.

    Raises
    ------
    InputError
        A width that is not a positive number; no width and no known sensor; tracks of
        two sensors with different widths.
    """
    if width is not None:
        if not (isinstance(width, (int, float)) and math.isfinite(width) and width > 0):
            raise InputError(f"corridor width must be a positive number of metres; got "
                             f"{width!r}")
        return float(width)
    if sensor is not None:
        return sensor_width(sensor)
    ids = {str(t) for t in tracks}
    sensors = {sensor_of_track(t) for t in ids}
    if not ids or None in sensors:
        unknown = sorted(t for t in ids if sensor_of_track(t) is None)[:3]
        what = f" (tracks {', '.join(unknown)})" if unknown else ""
        raise InputError(f"{source}: no known sensor{what}, so no default corridor width; "
                         "give the width in metres (--width; ICESat-2 13, MABEL 2)")
    widths = {sensor_width(s) for s in sensors if s is not None}
    if len(widths) > 1:
        raise InputError(f"{source}: holds tracks of {' and '.join(sorted(map(str, sensors)))}"
                         ", whose footprints differ; give the width in metres (--width)")
    return widths.pop()
