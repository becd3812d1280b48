"""The plugin object QGIS loads: registers the Processing provider (also under qgis_process)."""

from __future__ import annotations

from typing import Any

from qgis.core import QgsApplication

from .core_bridge import attach_log_handler, detach_log_handler
from .provider import CanopyBlocksProvider

__all__ = ["CanopyBlocksPlugin"]


class CanopyBlocksPlugin:
    """Adds the ``canopyblocks`` Processing provider; no GUI of its own."""

    def __init__(self, iface: Any) -> None:
        self.iface = iface
        self.provider: CanopyBlocksProvider | None = None

    def initProcessing(self) -> None:  # noqa: N802 - QGIS API
        """Called by QGIS (also by qgis_process, which has no GUI) to add the provider."""
        if self.provider is None:
            attach_log_handler()
            self.provider = CanopyBlocksProvider()
            QgsApplication.processingRegistry().addProvider(self.provider)

    def initGui(self) -> None:  # noqa: N802 - QGIS API
        self.initProcessing()

    def unload(self) -> None:
        if self.provider is not None:
            QgsApplication.processingRegistry().removeProvider(self.provider)
            self.provider = None
        detach_log_handler()
