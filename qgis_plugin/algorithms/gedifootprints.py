"""``canopyblocks:gedifootprints``: GEDI L1B waveforms -> footprints layer (DESIGN 4)."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingFeedback,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFile,
    QgsProcessingParameterString,
)

from ..core_bridge import import_core
from ..layers import write_frame
from ..styles import style_on_load
from .base import CanopyBlocksAlgorithm, input_label

__all__ = ["GediFootprintsAlgorithm", "SETTINGS", "GEDI_FILTER", "add_l1b_parameters",
           "gedi_file"]

SETTINGS = ("a1", "a2", "a3", "a4", "a5", "a6")
GEDI_FILTER = "GEDI HDF5 or zip (*.h5 *.hdf5 *.zip);;All files (*.*)"


def add_l1b_parameters(alg: Any, file_name: str, setting_name: str) -> None:
    """The GEDI L1B file and L2A setting-group parameters (shared by the algorithms)."""
    alg.addParameter(QgsProcessingParameterFile(
        file_name, "GEDI L1B file", behavior=QgsProcessingParameterFile.File,
        fileFilter=GEDI_FILTER))
    alg.addParameter(QgsProcessingParameterEnum(
        setting_name, "L2A setting group", options=list(SETTINGS), defaultValue=0))


def gedi_file(path: str) -> str:
    """A GEDI HDF5 path; a zip holding one (as LP DAAC and the bundled data ship them) is
    unpacked once into QGIS's processing temporary folder and its HDF5 file returned."""
    if not path.lower().endswith(".zip"):
        return path
    import zipfile
    from pathlib import Path

    from qgis.core import QgsProcessingException, QgsProcessingUtils

    try:
        with zipfile.ZipFile(path) as zf:
            members = [m for m in zf.namelist() if m.lower().endswith((".h5", ".hdf5"))]
            if len(members) != 1:
                raise QgsProcessingException(
                    f"{path}: a GEDI zip must hold one HDF5 file, it holds {len(members)}; "
                    "unzip it and choose the .h5 file")
            folder = Path(QgsProcessingUtils.tempFolder()) / Path(path).stem
            target = folder / Path(members[0]).name
            if not target.exists():
                folder.mkdir(parents=True, exist_ok=True)
                with zf.open(members[0]) as src, open(target, "wb") as dst:
                    while chunk := src.read(1 << 22):
                        dst.write(chunk)
    except zipfile.BadZipFile:
        raise QgsProcessingException(f"{path}: not a readable zip file; download it "
                                     "again or choose the .h5 file") from None
    return str(target)


class GediFootprintsAlgorithm(CanopyBlocksAlgorithm):
    """Ground, canopy top, RH metrics and cover per GEDI footprint from L1B waveforms."""

    ALG_ID = "gedifootprints"
    DISPLAY = "GEDI footprints from L1B waveforms"
    GROUP = "Full-waveform lidar"
    GROUP_ID = "waveforms"
    HELP = (
        "Reads the received waveforms of a GEDI L1B file (every beam, or the beams named) "
        "and processes them with GEDI L2A's algorithm (setting group a1-a6): signal top and "
        "bottom, modes, ground = lowest mode, RH25-RH100 from the cumulative energy, canopy "
        "cover and penetration, and a terrain filter. On the bundled real shots "
        "it reproduces L2A a1 ground and RH98 to about 0.01 m RMSE. Elevations are heights "
        "above the WGS84 ellipsoid; the layer is PointZ at the ground in the UTM zone of "
        "the footprints, styled by RH98. With an L2A file of the same shots, its values and "
        "the differences are added (joined by shot number)."
    )

    INPUT = "INPUT"
    BEAMS = "BEAMS"
    ADVANCED = ("DECOMPOSE", "L2A")
    SETTING = "SETTING"
    DECOMPOSE = "DECOMPOSE"
    L2A = "L2A"
    OUTPUT = "OUTPUT"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        add_l1b_parameters(self, self.INPUT, self.SETTING)
        self.addParameter(QgsProcessingParameterString(
            self.BEAMS, "Beams (e.g. BEAM0101, BEAM0110; empty = all)", defaultValue="",
            optional=True))
        self.addParameter(QgsProcessingParameterBoolean(
            self.DECOMPOSE, "Also fit Gaussians (ground_gauss; much slower)",
            defaultValue=False))
        self.addParameter(QgsProcessingParameterFile(
            self.L2A, "GEDI L2A of the same shots (for comparison)",
            behavior=QgsProcessingParameterFile.File, fileFilter=GEDI_FILTER, optional=True))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "GEDI footprints", type=QgsProcessing.TypeVectorPoint))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        wf = import_core("canopyblocks.workflows.waveforms")
        settings = import_core("canopyblocks.workflows.params")
        path = gedi_file(self.parameterAsFile(parameters, self.INPUT, context))
        text = self.parameterAsString(parameters, self.BEAMS, context)
        beams = [b.strip() for b in text.replace(";", ",").split(",") if b.strip()] or None
        setting = SETTINGS[self.parameterAsEnum(parameters, self.SETTING, context)]
        params = settings.WaveformParams(
            setting=setting, decompose=self.parameterAsBool(parameters, self.DECOMPOSE,
                                                            context))
        footprints, _ = wf.footprints_from_l1b(path, beams=beams, params=params,
                                               progress=progress.sub(0.0, 0.9))
        l2a = self.parameterAsFile(parameters, self.L2A, context)
        l2a = gedi_file(l2a) if l2a else l2a
        if l2a:
            footprints, comparison = wf.compare_with_l2a(footprints, l2a, setting=setting)
            for row in comparison[comparison["beam"] == "all"].itertuples():
                feedback.pushInfo(f"vs L2A {row.metric}: n={row.n} bias={row.bias:+.3f} m "
                                  f"RMSE={row.rmse:.3f} m")
        dest = write_frame(self, parameters, self.OUTPUT, context, footprints, feedback)
        style_on_load(context, dest, "height", "rh98",
                      name=f"GEDI footprints - {input_label(path, setting)}")
        return {self.OUTPUT: dest}
