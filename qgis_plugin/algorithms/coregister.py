"""``canopyblocks:coregister``: a track's geolocation offset against the DTM (DESIGN 2.8)."""

from __future__ import annotations

from typing import Any

from qgis.core import (
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingFeedback,
    QgsProcessingParameterCrs,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFile,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
)

from ..core_bridge import import_core
from ..layers import write_frame
from .base import CanopyBlocksAlgorithm, optional_number
from .validate import raster_path

__all__ = ["CoregisterAlgorithm", "offsets_table"]

_TABLE_FIELDS = ("east", "north", "along_track", "cross_track", "vertical", "east_sd",
                 "north_sd", "along_track_sd", "cross_track_sd", "vertical_sd", "rmse_before",
                 "rmse_after", "bias_before", "bias_after", "n_ground", "n_top", "reason")


def offsets_table(result: Any) -> Any:
    """One row per track (and 'all'): the offsets (m to ADD), their uncertainties, the
    ground RMSE before/after and the status ('ok' or 'undetermined')."""
    import pandas as pd

    rows = []
    for name, o in result.offsets.items():
        row: dict[str, Any] = {"track": name,
                               "status": "ok" if o.determined else "undetermined"}
        row.update({f: getattr(o, f) for f in _TABLE_FIELDS})
        rows.append(row)
    return pd.DataFrame(rows)


class CoregisterAlgorithm(CanopyBlocksAlgorithm):
    """Along-track, cross-track and vertical offsets aligning a track with airborne lidar."""

    ALG_ID = "coregister"
    DISPLAY = "Co-register a track with airborne lidar"
    GROUP = "Validation"
    GROUP_ID = "validation"
    HELP = (
        "Searches the horizontal shift (along and across the track, +- the search range, "
        "1 m then 0.25 m steps) that best aligns the track's ground (and, with a DSM, its "
        "canopy top) with the airborne DTM/DSM; the vertical offset is the robust mean "
        "residual at each shift. Works on photons (ATL03/MABEL/tables: their ground- and "
        "top-window photons), block tables or GEDI footprint tables. Writes offsets.json: "
        "one entry per track and 'all' (one offset for every track together), each with "
        "east, north, along_track, cross_track and vertical (metres to ADD to the reported "
        "positions and heights), their uncertainties and the ground RMSE before and "
        "after. An offset is 'ok' only when, fitted on some stretches of the track, it "
        "also improves the held-out stretches significantly; otherwise it is "
        "'undetermined' (a warning says why, with the smallest offset this terrain can "
        "reveal) and must not be applied. Rasters that cover too little of the track are "
        "refused."
    )

    INPUT = "INPUT"
    DTM = "DTM"
    DSM_MAX = "DSM_MAX"
    OFFSET = "OFFSET"
    CRS = "CRS"
    RANGE = "RANGE"
    OUTPUT = "OUTPUT"
    PLOT = "PLOT"
    OFFSETS = "OFFSETS"
    ADVANCED = (CRS, RANGE)

    def initAlgorithm(self, config: dict[str, Any] | None = None) -> None:  # noqa: N802
        self.addParameter(QgsProcessingParameterFile(
            self.INPUT, "Photons, blocks or footprints",
            behavior=QgsProcessingParameterFile.File,
            fileFilter="Tracks (*.h5 *.hdf5 *.gpkg *.parquet *.csv);;All files (*.*)"))
        self.addParameter(QgsProcessingParameterRasterLayer(self.DTM, "DTM"))
        self.addParameter(QgsProcessingParameterRasterLayer(
            self.DSM_MAX, "DSM (maximum; also aligns the canopy top)",
            optional=True))
        self.addParameter(QgsProcessingParameterNumber(
            self.OFFSET, "Vertical offset N = h_track - H_reference (m; empty = none)",
            type=QgsProcessingParameterNumber.Double, optional=True))
        self.addParameter(QgsProcessingParameterCrs(
            self.CRS, "Metric CRS of the photons / of a CSV table (optional)", optional=True))
        self.addParameter(QgsProcessingParameterNumber(
            self.RANGE, "Search range (m)", type=QgsProcessingParameterNumber.Double,
            defaultValue=15.0, minValue=1.0, maxValue=200.0))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.OUTPUT, "Offsets (JSON)", fileFilter="JSON (*.json)"))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.PLOT, "Cost surface (PNG)", fileFilter="PNG (*.png)", optional=True,
            createByDefault=False))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OFFSETS, "Offsets per track", type=QgsProcessing.TypeVector, optional=True))

    def execute(self, parameters: dict[str, Any], context: QgsProcessingContext,
                feedback: QgsProcessingFeedback, progress: Any) -> dict[str, Any]:
        files = import_core("canopyblocks.workflows.coregister")
        params = import_core("canopyblocks.workflows.params")
        kwargs: dict[str, Any] = {}
        offset = optional_number(self, parameters, self.OFFSET, context)
        if offset is not None:
            kwargs["offset"] = offset
        crs = self.parameterAsCrs(parameters, self.CRS, context)
        if crs.isValid():
            kwargs["crs"] = crs.toWkt()
        dsm = (raster_path(self, parameters, self.DSM_MAX, context)
               if parameters.get(self.DSM_MAX) not in (None, "") else None)
        result = files.coregister_file(
            self.parameterAsFile(parameters, self.INPUT, context),
            raster_path(self, parameters, self.DTM, context), dsm,
            params=params.CoregParams(
                search_range=self.parameterAsDouble(parameters, self.RANGE, context)),
            progress=progress.sub(0.0, 0.9), **kwargs)
        out = self.parameterAsFileOutput(parameters, self.OUTPUT, context)
        files.write_offsets(result, out)
        results: dict[str, Any] = {self.OUTPUT: out}
        if parameters.get(self.OFFSETS) is not None:
            results[self.OFFSETS] = write_frame(self, parameters, self.OFFSETS, context,
                                                offsets_table(result), feedback)
        plot = self.parameterAsFileOutput(parameters, self.PLOT, context)
        if plot:
            files.write_cost_surfaces(result, plot)
            results[self.PLOT] = plot
        # the one rule of every command: an undetermined offset is a warning, not applied
        files.offset_to_apply(result, self.parameterAsFile(parameters, self.INPUT, context),
                              applying=False)
        for name, o in result.offsets.items():
            feedback.pushInfo(f"{name}: along {o.along_track:+.2f} m, cross "
                              f"{o.cross_track:+.2f} m (+-{o.along_track_sd:.2f}/"
                              f"{o.cross_track_sd:.2f}), vertical {o.vertical:+.2f} m; ground "
                              f"RMSE {o.rmse_before:.2f} -> {o.rmse_after:.2f} m; {o.status}")
        return results
