"""The ``canopyblocks`` Processing provider; algorithms are listed explicitly."""

from __future__ import annotations

from qgis.core import QgsProcessingProvider
from qgis.PyQt.QtGui import QIcon

from .algorithms.aspecterrors import AspectErrorsAlgorithm
from .algorithms.blockheights import BlockHeightsAlgorithm
from .algorithms.calibrate import CalibrateAlgorithm
from .algorithms.coregister import CoregisterAlgorithm
from .algorithms.corridor import CorridorAlgorithm
from .algorithms.flashdualfootprints import FlashDualFootprintsAlgorithm
from .algorithms.footprintvalidation import FootprintValidationAlgorithm
from .algorithms.gedifootprints import GediFootprintsAlgorithm
from .algorithms.referencerasters import ReferenceRastersAlgorithm
from .algorithms.simulate import SimulateAlgorithm
from .algorithms.simulatewaveforms import SimulateWaveformsAlgorithm
from .algorithms.validate import ValidateAlgorithm
from .algorithms.waveformplot import WaveformPlotAlgorithm
from .resources import ICON

__all__ = ["CanopyBlocksProvider", "ALGORITHMS", "ICON"]


#: Every algorithm of the provider, in menu order.  Their ids are stable.
ALGORITHMS = (
    BlockHeightsAlgorithm,
    CorridorAlgorithm,
    ReferenceRastersAlgorithm,
    ValidateAlgorithm,
    AspectErrorsAlgorithm,
    CalibrateAlgorithm,
    CoregisterAlgorithm,
    SimulateAlgorithm,
    SimulateWaveformsAlgorithm,
    GediFootprintsAlgorithm,
    FlashDualFootprintsAlgorithm,
    FootprintValidationAlgorithm,
    WaveformPlotAlgorithm,
)


class CanopyBlocksProvider(QgsProcessingProvider):
    """Provider id ``canopyblocks``: ``processing.run("canopyblocks:blockheights", ...)``."""

    def id(self) -> str:
        return "canopyblocks"

    def name(self) -> str:
        return "canopyblocks"

    def longName(self) -> str:  # noqa: N802 - QGIS API
        return "canopyblocks: canopy height per along-track lidar block"

    def icon(self) -> QIcon:
        return QIcon(str(ICON))

    def svgIconPath(self) -> str:  # noqa: N802 - QGIS API
        return str(ICON)

    def load(self) -> bool:
        """Add the provider's settings page (Settings > Options > Processing > Providers >
        canopyblocks: the pdal executable), as the LAStools and WhiteboxTools providers
        do, then load the algorithms."""
        try:
            from processing.core.ProcessingConfig import ProcessingConfig, Setting
        except ImportError:  # pragma: no cover - Processing ships with QGIS
            return super().load()
        from .dependencies import PDAL_SETTING

        ProcessingConfig.settingIcons[self.name()] = self.icon()
        ProcessingConfig.addSetting(Setting(
            self.name(), PDAL_SETTING,
            "pdal executable (empty: $CANOPYBLOCKS_PDAL, PATH, /opt/canopyblocks-pdal/bin/pdal)",
            "", valuetype=Setting.FILE))
        ProcessingConfig.readSettings()
        self.refreshAlgorithms()
        return True

    def unload(self) -> None:
        try:
            from processing.core.ProcessingConfig import ProcessingConfig
        except ImportError:  # pragma: no cover
            return
        from .dependencies import PDAL_SETTING

        if PDAL_SETTING in ProcessingConfig.settings:  # absent when load() did not finish
            ProcessingConfig.removeSetting(PDAL_SETTING)

    def loadAlgorithms(self) -> None:  # noqa: N802 - QGIS API
        for cls in ALGORITHMS:
            self.addAlgorithm(cls())
