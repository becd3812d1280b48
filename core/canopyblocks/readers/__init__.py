"""Readers of photon files: ICESat-2 ATL03 (+ ATL08 classes), MABEL L2A, tables;
of GEDI L1B waveforms (:mod:`.gedi`) and L2A/L2B products (:mod:`.gedi_l2`); and of
airborne LAS/LAZ point clouds (:mod:`.las`).

Each reader returns one :class:`~canopyblocks.photons.PhotonTrack` (one beam or
channel), optionally subset by a WGS84 ``bbox`` or an along-track ``s_range``
before the photon columns are read.  :func:`open_track` picks the reader from the
file's content; :func:`file_info` summarises a file for ``canopyblocks info``.
"""

from __future__ import annotations

from .atl03 import BEAMS, BeamInfo, atl03_beams, read_atl03
from .atl08 import read_atl08_photons
from .gedi import (
    GEDI_BEAMS,
    gedi_beam_info,
    gedi_beams,
    is_gedi_l1b,
    iter_gedi_l1b,
    read_gedi_l1b,
)
from .gedi_l2 import read_gedi_l2a, read_gedi_l2b
from .las import LasPoints, las_crs, read_las
from .mabel import mabel_channels, read_mabel
from .sniff import default_beam, detect_product, file_info, format_info, open_track
from .table import read_table

__all__ = [
    "BEAMS",
    "BeamInfo",
    "atl03_beams",
    "read_atl03",
    "read_atl08_photons",
    "LasPoints",
    "las_crs",
    "read_las",
    "mabel_channels",
    "read_mabel",
    "read_table",
    "open_track",
    "file_info",
    "format_info",
    "detect_product",
    "default_beam",
    "GEDI_BEAMS",
    "gedi_beams",
    "gedi_beam_info",
    "is_gedi_l1b",
    "iter_gedi_l1b",
    "read_gedi_l1b",
    "read_gedi_l2a",
    "read_gedi_l2b",
]
