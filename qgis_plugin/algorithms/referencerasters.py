"""``canopyblocks:referencerasters``: LAS/LAZ -> DTM, DSM (max) and DSM (90th percentile)."""

from __future__ import annotations

import os
import shutil
from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
    QgsProcessingOutputRasterLayer,
    QgsProcessingParameterCrs,
    QgsProcessingParameterEnum,
    QgsProcessingParameterExtent,
    QgsProcessingParameterFile,
    QgsProcessingParameterFolderDestination,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
)

from ..core_bridge import import_core
from ..layers import pyproj_crs
from ..styles import load_raster_on_completion
from .base import SEED_001, CanopyBlocksAlgorithm, input_label

__all__ = ["ReferenceRastersAlgorithm", "pdal_status"]

GROUND_OPTIONS = (("class 2 of the files", "class2"), ("classified by PDAL's SMRF", "smrf"))
PDAL_HINT = ("run scripts/install_pdal.sh, or set the pdal executable in Settings > Options > "
             "Processing > Providers > canopyblocks (or CANOPYBLOCKS_PDAL)")


def pdal_status() -> tuple[bool, str]:
    """(available, message): is the ``pdal`` command line usable from this process?
    The provider's settings page (PDAL executable) comes first."""
    from ..dependencies import apply_pdal_setting, pdal_setting

    apply_pdal_setting()
    chosen = pdal_setting()
    if chosen and not os.path.isfile(chosen):
        return False, (f"the pdal executable set in Settings > Options > Processing > "
                       f"Providers > canopyblocks does not exist: {chosen}; correct it or "
                       "clear it to use the pdal found on PATH")
    try:
        pdal = import_core("canopyblocks.reference.pdal")
    except QgsProcessingException:
        pdal = None
    if pdal is not None and hasattr(pdal, "find_pdal"):
        try:
            exe = pdal.find_pdal()
        except Exception as exc:  # noqa: BLE001 - the core's DependencyError or similar
            return False, f"PDAL is missing: {exc}; {PDAL_HINT}"
        return True, str(exe)
    env = os.environ.get("CANOPYBLOCKS_PDAL")
    exe = env if env and os.path.exists(env) else shutil.which("pdal")
    if exe is None:
        return False, f"PDAL is missing (no 'pdal' command found); {PDAL_HINT}"
    return True, exe


class ReferenceRastersAlgorithm(CanopyBlocksAlgorithm):
    """Reference rasters from airborne discrete-return lidar through the pdal command line."""

    ALG_ID = "referencerasters"
    DISPLAY = "Reference rasters from airborne lidar (PDAL)"
    GROUP = "Validation"
    GROUP_ID = "validation"
    HELP = (
        "Grids LAS/LAZ point clouds into a DTM (ground points: class 2, or SMRF), a DSM of the "
        "maximum and a DSM of the 90th percentile of point elevations per cell, on one "
        "aligned grid, through the pdal command line (PDAL is run in a subprocess; the 90th "
        "percentile is computed by canopyblocks).<br><br>"
        "DTM cells with points but no ground point (under dense canopy) are filled by smooth "
        "(harmonic) interpolation from the measured cells around them; the <b>DTM fill mask</b> "
        "marks them (1 = filled, 0 = measured).<br>"
        "Method: " + SEED_001 + ", section 2.3 (2 m rasters).<br>"
        "Needs the <b>pdal</b> command: " + PDAL_HINT + ".<br>"
        "Heights stay in the point cloud's vertical datum."
    )

    INPUT = "INPUT"
    SURVEY = "SURVEY"
    RESOLUTION = "RESOLUTION"
    GROUND = "GROUND"
    CRS = "CRS"
    EXTENT = "EXTENT"
    OUTPUT_DIR = "OUTPUT_DIR"
    DTM = "DTM"
    DSM_MAX = "DSM_MAX"
    DSM_P90 = "DSM_P90"
    DTM_FILL_MASK = "DTM_FILL_MASK"

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.INPUT, "LAS/LAZ files", QgsProcessing.TypeFile, optional=True))
        self.addParameter(QgsProcessingParameterFile(
            self.SURVEY, "Folder of LAS/LAZ tiles (a survey; read tile by tile)",
            behavior=QgsProcessingParameterFile.Folder, optional=True))
        self.addParameter(QgsProcessingParameterNumber(
            self.RESOLUTION, "Cell size (m)", type=QgsProcessingParameterNumber.Double,
            defaultValue=2.0, minValue=0.01))
        self.addParameter(QgsProcessingParameterEnum(
            self.GROUND, "Ground points", options=[label for label, _ in GROUND_OPTIONS],
            defaultValue=0))
        self.addParameter(QgsProcessingParameterCrs(
            self.CRS, "Output CRS (metric; empty = the tiles' CRS)", optional=True))
        self.addParameter(QgsProcessingParameterExtent(
            self.EXTENT, "Area to grid (empty = all tiles)", optional=True))
        self.addParameter(QgsProcessingParameterFolderDestination(
            self.OUTPUT_DIR,
            "Output folder (dtm.tif, dsm_max.tif, dsm_p90.tif, dtm_fill_mask.tif)"))
        self.addOutput(QgsProcessingOutputRasterLayer(self.DTM, "DTM"))
        self.addOutput(QgsProcessingOutputRasterLayer(self.DSM_MAX, "DSM (maximum)"))
        self.addOutput(QgsProcessingOutputRasterLayer(self.DSM_P90, "DSM (90th percentile)"))
        self.addOutput(QgsProcessingOutputRasterLayer(self.DTM_FILL_MASK, "DTM fill mask"))

    def canExecute(self) -> tuple[bool, str]:  # noqa: N802 - QGIS API
        ok, msg = super().canExecute()
        return pdal_status() if ok else (ok, msg)

    def checkParameterValues(self, parameters: dict[str, Any],  # noqa: N802 - QGIS API
                             context: QgsProcessingContext) -> tuple[bool, str]:
        ok, msg = pdal_status()
        if not ok:
            return False, msg
        return super().checkParameterValues(parameters, context)

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        rasters = import_core("canopyblocks.workflows.rasters")
        folder = (self.parameterAsFile(parameters, self.SURVEY, context) or "").strip()
        folder = folder if parameters.get(self.SURVEY) not in (None, "") else ""
        files = [str(f) for f in self.parameterAsFileList(parameters, self.INPUT, context)
                 if str(f).strip()]
        if folder:
            files.append(folder)
        if not files:
            raise QgsProcessingException("no LAS/LAZ file or folder of tiles given")
        out_dir = self.parameterAsString(parameters, self.OUTPUT_DIR, context)
        qcrs = self.parameterAsCrs(parameters, self.CRS, context)
        crs = pyproj_crs(qcrs) if qcrs.isValid() else None
        bounds = None
        if parameters.get(self.EXTENT) not in (None, ""):
            target = qcrs if qcrs.isValid() else None
            ext = (self.parameterAsExtent(parameters, self.EXTENT, context, target)
                   if target is not None else
                   self.parameterAsExtent(parameters, self.EXTENT, context))
            if not ext.isNull():
                bounds = (ext.xMinimum(), ext.yMinimum(), ext.xMaximum(), ext.yMaximum())
        # tiles one after the other: QGIS's interpreter cannot start worker processes
        made = rasters.make_survey_rasters(
            files, out_dir, backend="serial",
            resolution=self.parameterAsDouble(parameters, self.RESOLUTION, context),
            crs=crs, bounds=bounds,
            ground=GROUND_OPTIONS[self.parameterAsEnum(parameters, self.GROUND, context)][1],
            progress=progress)
        filled, cells = made.stats.get("dtm_filled", 0), made.stats.get("cells", 0)
        feedback.pushInfo(f"{made.stats.get('tiles_read', 0)} of {len(made.tiles)} tiles read: "
                          f"{made.grid.width} x {made.grid.height} "
                          f"cells of {made.grid.resolution:g} m; DTM cells filled by "
                          f"interpolation: {filled} of {cells}")
        source = input_label(files)
        outputs = ((self.DTM, "DTM", "raster_dtm", made.dtm),
                   (self.DSM_MAX, "DSM (maximum)", "raster_dsm", made.dsm_max),
                   (self.DSM_P90, "DSM (90th percentile)", "raster_dsm", made.dsm_p90),
                   (self.DTM_FILL_MASK, "DTM fill mask", "raster_mask", made.dtm_fill_mask))
        results: dict[str, Any] = {self.OUTPUT_DIR: out_dir}
        for out, name, kind, path in outputs:
            load_raster_on_completion(context, str(path), f"{name} - {source}", out, kind)
            results[out] = str(path)
        return results
