"""Shared parts of the canopyblocks algorithms: naming, help, the core call wrapper."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessingAlgorithm,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
)
from qgis.PyQt.QtGui import QIcon

from ..core_bridge import core_errors, feedback_logging, progress_for

__all__ = ["CanopyBlocksAlgorithm", "SEED_001", "SEED_002", "parse_lengths"]

SEED_001 = (
    "Gwenzi, D. & Lefsky, M.A.: Prospects of photon counting lidar for savanna ecosystem "
    "structural studies (MABEL; the block/expansion-window method and its validation)"
)
SEED_002 = (
    "Neuenschwander, A.L. & Magruder, L.A. (University of Texas at Austin): the ICESat-2 "
    "photon simulation from airborne lidar (footprints, Poisson photon counts, canopy truth)"
)


def parse_lengths(text: str) -> tuple[float, ...]:
    """``"25, 10"`` -> ``(25.0, 10.0)``; raises QgsProcessingException on bad text."""
    parts = [p.strip() for p in str(text).replace(";", ",").split(",") if p.strip()]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise QgsProcessingException(
            f"block lengths must be numbers in metres separated by commas (e.g. '25, 10'), "
            f"got {text!r}"
        ) from None
    if not values or any(not (v > 0) for v in values):
        raise QgsProcessingException(
            f"block lengths must be positive metres (e.g. '25, 10'), got {text!r}"
        )
    return values


class CanopyBlocksAlgorithm(QgsProcessingAlgorithm):
    """Base: subclasses set ``ALG_ID``, ``DISPLAY``, ``HELP`` and implement :meth:`execute`."""

    ALG_ID = ""
    DISPLAY = ""
    HELP = ""
    GROUP = "Photon-counting lidar"
    GROUP_ID = "photons"

    def name(self) -> str:
        return self.ALG_ID

    def displayName(self) -> str:  # noqa: N802 - QGIS API
        return self.DISPLAY

    def group(self) -> str:
        return self.GROUP

    def groupId(self) -> str:  # noqa: N802 - QGIS API
        return self.GROUP_ID

    def shortHelpString(self) -> str:  # noqa: N802 - QGIS API
        return self.HELP

    def helpString(self) -> str:  # noqa: N802 - QGIS API
        return self.HELP

    def icon(self) -> QIcon:
        from ..provider import ICON

        return QIcon(str(ICON))

    def createInstance(self) -> CanopyBlocksAlgorithm:  # noqa: N802 - QGIS API
        return type(self)()

    def processAlgorithm(  # noqa: N802 - QGIS API
        self,
        parameters: dict[str, Any],
        context: QgsProcessingContext,
        feedback: QgsProcessingFeedback,
    ) -> dict[str, Any]:
        """Route logging/warnings to ``feedback``, map core errors, call :meth:`execute`."""
        with feedback_logging(feedback), core_errors():
            return self.execute(parameters, context, feedback, progress_for(feedback))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        raise NotImplementedError

    def source_frame(self, parameters: dict[str, Any], name: str,
                     context: QgsProcessingContext, feedback: QgsProcessingFeedback) -> Any:
        """The feature source parameter ``name`` as a GeoDataFrame (QGIS's error if unset)."""
        from ..layers import source_to_frame

        source = self.parameterAsSource(parameters, name, context)
        if source is None:
            raise QgsProcessingException(self.invalidSourceError(parameters, name))
        return source_to_frame(source, feedback)
