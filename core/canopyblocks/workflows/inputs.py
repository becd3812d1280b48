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

#: The room that owns each name (module, names).
_OWNERS = (("..readers", ("file_info", "format_info")), ("..readers.remote", ("is_url",)),
           ("..readers.atl03", ("atl03_beams",)), ("..readers.las", ("las_crs",)),
           ("..outputs.tables", ("check_output_path",)),
           ("..readers.flash_dual", ("waveform_product",)))


def __getattr__(name: str) -> Any:
    owner = next((m for m, names in _OWNERS if name in names), None)
    if owner is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(owner, __package__), name)
