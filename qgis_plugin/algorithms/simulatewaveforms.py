"""``canopyblocks:simulatewaveforms``: GEDI, ESFL flash or dual-wavelength waveforms
simulated from airborne lidar (seeds 003 and 004, DESIGN 4.5-4.9)."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessingContext,
    QgsProcessingFeedback,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterFolderDestination,
)

from ..core_bridge import import_core
from .base import CanopyBlocksAlgorithm, las_files
from .simulate import add_tiles_and_track_parameters, track_vertices

__all__ = ["SimulateWaveformsAlgorithm"]

#: (menu label, sensor name of canopyblocks.simulate.sensor_files)
SENSORS = (
    ("GEDI (L1B layout: any GEDI reader, and the GEDI footprints algorithm, open it)",
     "gedi"),
    ("ESFL flash focal-plane array data cubes", "esfl"),
    ("dual-wavelength visible / near-infrared waveform pairs", "dual"),
)


class SimulateWaveformsAlgorithm(CanopyBlocksAlgorithm):
    """Waveforms along a track over airborne LAS/LAZ tiles, with their truth, as HDF5."""

    ALG_ID = "simulatewaveforms"
    DISPLAY = "Simulate waveforms (GEDI, flash, dual-wavelength) from airborne lidar"
    GROUP = "Simulation"
    GROUP_ID = "simulation"
    HELP = (
        "Simulates full-waveform lidar along a track over airborne LAS/LAZ tiles (one metric "
        "CRS): Gaussian footprints and pulses over the points, ground and canopy kept apart "
        "for truth.<br>"
        "GEDI: written in the GEDI L1B layout (BEAMxxxx/rxwaveform, shot_number, geolocation, "
        "noise) with the truth per footprint in BEAMxxxx/canopyblocks_truth; run 'GEDI "
        "footprints from L1B waveforms' on it to see what GEDI processing recovers.<br>"
        "ESFL: flash data cubes (8.4 m footprints on 12 x 12 pixels, 0.75 m bins) and the "
        "energy-threshold study of the flash-lidar method in the report folder.<br>"
        "dual: visible/NIR waveform pairs and the ratio-method ground of the dual-wavelength method against "
        "cover in the report folder.<br>"
        "Heights stay in the tiles' vertical datum. The same seed gives the same file."
    )

    INPUT = "INPUT"
    SENSOR = "SENSOR"
    TRACK_LINE = "TRACK_LINE"
    AZIMUTH = "AZIMUTH"
    SEED = "SEED"
    OUTPUT = "OUTPUT"
    REPORT = "REPORT"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        add_tiles_and_track_parameters(self)
        self.addParameter(QgsProcessingParameterEnum(
            self.SENSOR, "Sensor", options=[label for label, _ in SENSORS], defaultValue=0))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.OUTPUT, "Simulated waveforms (HDF5)", fileFilter="HDF5 (*.h5)"))
        self.addParameter(QgsProcessingParameterFolderDestination(
            self.REPORT, "Report folder (the method's study)", optional=True,
            createByDefault=False))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        workflow = import_core("canopyblocks.workflows.simulate")
        inputs = import_core("canopyblocks.workflows.inputs")
        files = las_files(self, parameters, self.INPUT, context)
        sensor = SENSORS[self.parameterAsEnum(parameters, self.SENSOR, context)][1]
        line = track_vertices(self, parameters, self.TRACK_LINE, context,
                              inputs.las_crs(files[0]))
        report = (self.parameterAsString(parameters, self.REPORT, context)
                  if parameters.get(self.REPORT) not in (None, "") else None)
        out = self.parameterAsFileOutput(parameters, self.OUTPUT, context)
        track, summary = workflow.simulate_sensor_over_tiles(
            files, sensor, out, vertices=line,
            azimuth=self.parameterAsDouble(parameters, self.AZIMUTH, context),
            seed=self.parameterAsInt(parameters, self.SEED, context), report_dir=report,
            progress=progress)
        feedback.pushInfo(f"{summary['footprints']} {sensor} footprints over "
                          f"{track.length:.0f} m -> {out}")
        results: dict[str, Any] = {self.OUTPUT: out}
        if report:
            results[self.REPORT] = report
        return results
