"""What the front doors ask of an input or an output before a workflow runs: a file's
description (``canopyblocks info``), whether a source is a URL, the beams of an ATL03
granule (the QGIS beam list), the CRS of LAS/LAZ tiles, whether an output path can be
written. Each is the function of the room that owns it, loaded on first use."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..outputs.tables import check_output_path
    from ..readers import file_info, format_info
    from ..readers.atl03 import atl03_beams
    from ..readers.flash_dual import waveform_product
    from ..readers.las import las_crs
    from ..readers.remote import is_url

__all__ = ["file_info", "format_info", "is_url", "atl03_beams", "las_crs",
           "check_output_path", "waveform_product"]

_OWNER = {
    "file_info": "..readers",
    "format_info": "..readers",
    "is_url": "..readers.remote",
    "atl03_beams": "..readers.atl03",
    "las_crs": "..readers.las",
    "check_output_path": "..outputs.tables",
    "waveform_product": "..readers.flash_dual",
}


def __getattr__(name: str) -> Any:
    if name in _OWNER:
        return getattr(importlib.import_module(_OWNER[name], __package__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
