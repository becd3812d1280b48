"""Shared parts of the canopyblocks algorithms: naming, help, the core call wrapper."""

from __future__ import annotations

import os
import re
from typing import Any

from qgis.core import (
    QgsProcessingAlgorithm,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingFeedback,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterFile,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
)
from qgis.PyQt.QtCore import QCoreApplication
from qgis.PyQt.QtGui import QIcon

from ..core_bridge import core_errors, feedback_logging, progress_for

__all__ = ["CanopyBlocksAlgorithm", "SEED_001", "SEED_002", "parse_lengths",
           "optional_number", "las_files", "input_label", "table_choices"]

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


def las_files(alg: Any, parameters: dict[str, Any], name: str,
              context: QgsProcessingContext) -> list[str]:
    """The LAS/LAZ paths of a multiple-file parameter; QGIS's error when none is given."""
    files = [str(f) for f in alg.parameterAsFileList(parameters, name, context)]
    if not files:
        raise QgsProcessingException("no LAS/LAZ file given")
    return files


def input_label(paths: Any, *extra: str) -> str:
    """What a layer was made from, for its name: the first input's file name without its
    extension ("+ N more" for several), then ``extra`` parts (beam, block lengths), e.g.
    ``"ATL03_2019 gt1r 25 m"``."""
    from pathlib import Path

    items = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    names = [Path(str(p)).name for p in items if str(p)]
    stem = names[0] if names else ""
    for suffix in (".zip", ".laz", ".las", ".h5", ".hdf5", ".he5", ".gpkg", ".csv",
                   ".parquet", ".json", ".tif"):
        if stem.lower().endswith(suffix):
            stem = stem[: -len(suffix)]
            break
    if len(names) > 1:
        stem += f" + {len(names) - 1} more"
    return " ".join(p for p in (stem, *extra) if p)


def table_choices(name: str) -> tuple[tuple[str, ...], int]:
    """(choices, index of the default) of the core's option ``name`` (``"--preset"``), from
    the one vocabulary (``canopyblocks.options``; plain Python). Without an importable core
    the list is empty: the dialog then says what to install instead of running."""
    import importlib

    try:
        spec = importlib.import_module("canopyblocks.options").OPTIONS[name]
    except ImportError:
        return (), 0
    choices = tuple(spec.choices or ())
    return choices, (choices.index(spec.default) if spec.default in choices else 0)


def optional_number(alg: Any, parameters: dict[str, Any], name: str,
                    context: QgsProcessingContext) -> float | None:
    """An optional number parameter: None when left empty."""
    value = parameters.get(name)
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    return float(alg.parameterAsDouble(parameters, name, context))


HELP_URL = "https://github.com/canopyblocks/canopyblocks#qgis"
"""The README's QGIS section (the Help button of every algorithm)."""

_COMMON_TAGS = ("lidar", "canopy height", "forest", "canopyblocks")
#: Words the toolbox search finds each algorithm by (besides its name).
TAGS: dict[str, tuple[str, ...]] = {
    "blockheights": ("ICESat-2", "ATL03", "ATL08", "MABEL", "photon", "ground", "Hmax",
                     "H90", "block", "profile"),
    "corridor": ("ICESat-2", "ATL03", "footprint", "corridor", "polygon", "block"),
    "referencerasters": ("LAS", "LAZ", "airborne", "ALS", "PDAL", "DTM", "DSM", "raster",
                         "point cloud"),
    "validate": ("ICESat-2", "ATL03", "MABEL", "validation", "residual", "RMSE", "bias",
                 "DTM", "DSM"),
    "aspecterrors": ("aspect", "slope", "terrain", "validation", "RMSE", "statistics"),
    "calibrate": ("ICESat-2", "ATL03", "MABEL", "calibration", "cut-off", "bias"),
    "simulate": ("ICESat-2", "ATL03", "MABEL", "GEDI", "simulation", "LAS", "LAZ",
                 "photon", "waveform"),
    "coregister": ("ICESat-2", "ATL03", "GEDI", "geolocation", "offset", "co-registration",
                   "DTM", "alignment"),
    "gedifootprints": ("GEDI", "L1B", "L2A", "waveform", "full-waveform", "RH98", "RH",
                       "ground", "cover", "footprint"),
    "flashdualfootprints": ("ESFL", "flash", "flash lidar", "dual-wavelength", "waveform",
                            "full-waveform", "ground", "terrain", "footprint"),
    "footprintvalidation": ("GEDI", "footprint", "validation", "LAS", "LAZ", "ALS", "RH98",
                            "residual"),
    "waveformplot": ("GEDI", "L1B", "waveform", "plot", "RH", "shot"),
    "simulatewaveforms": ("GEDI", "ESFL", "flash", "dual-wavelength", "waveform", "L1B",
                          "simulation", "LAS", "LAZ"),
}


def plain_help(html: str) -> str:
    """Help text for ``shortHelpString``: ``<br>`` as newlines and no other markup, so the
    dialog and ``qgis_process help`` both show clean text."""
    text = re.sub(r"<br\s*/?>", "\n", html)
    return re.sub(r"<[^>]+>", "", text)


_OPTIONAL_WORDS = re.compile(r"\s*\((?:optional|optional, ([^)]*)|([^)]*?);\s*optional)\)",
                             re.IGNORECASE)


def _label_without_optional(text: str) -> str:
    """``"Track line (optional)"`` -> ``"Track line"``; ``"X (what; optional)"`` ->
    ``"X (what)"``: QGIS adds "[optional]" to optional parameters itself."""
    def keep(m: re.Match[str]) -> str:
        inner = m.group(1) or m.group(2)
        return f" ({inner})" if inner else ""

    return _OPTIONAL_WORDS.sub(keep, text)


def plain_decimals(value: float | None) -> int:
    """Decimals that show ``value`` without trailing zeros (at least 1, at most 6; 3 when
    there is no default, e.g. a fraction such as 0.075)."""
    if value is None:
        return 3
    text = f"{float(value):.6f}".rstrip("0")
    return max(1, min(6, len(text.split(".")[1]) if "." in text else 1))


def tidy_parameter(parameter: Any, advanced: bool) -> None:
    """The dialog rules of :meth:`CanopyBlocksAlgorithm.addParameter` for one parameter."""
    if advanced:
        parameter.setFlags(parameter.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
    if parameter.flags() & QgsProcessingParameterDefinition.FlagOptional:
        parameter.setDescription(_label_without_optional(parameter.description()))
    if isinstance(parameter, QgsProcessingParameterNumber) and \
            parameter.dataType() == QgsProcessingParameterNumber.Double:
        meta = dict(parameter.metadata() or {})
        wrapper = dict(meta.get("widget_wrapper") or {})
        default = parameter.defaultValue()
        wrapper.setdefault("decimals", plain_decimals(default if isinstance(
            default, (int, float)) else None))
        meta["widget_wrapper"] = wrapper
        parameter.setMetadata(meta)


class CanopyBlocksAlgorithm(QgsProcessingAlgorithm):
    """Base: subclasses set ``ALG_ID``, ``DISPLAY``, ``HELP`` and implement :meth:`execute`."""

    ALG_ID = ""
    DISPLAY = ""
    HELP = ""
    GROUP = "Photon-counting lidar"
    GROUP_ID = "photons"

    #: Parameter names shown under the dialog's "Advanced Parameters" group.
    ADVANCED: tuple[str, ...] = ()

    def name(self) -> str:
        return self.ALG_ID

    def addParameter(self, parameter: Any, createOutput: bool = True) -> bool:  # noqa: N802,N803
        """QGIS's addParameter, after the plugin's dialog rules: parameters named in
        :attr:`ADVANCED` flagged advanced; numbers shown plain ("2.5", not "2.500000");
        no "optional" wording in a label (QGIS marks optional parameters itself)."""
        tidy_parameter(parameter, parameter.name() in self.ADVANCED)
        return super().addParameter(parameter, createOutput)

    @staticmethod
    def tr(text: str) -> str:
        """Translatable text (context ``canopyblocks``)."""
        return QCoreApplication.translate("canopyblocks", text)

    def displayName(self) -> str:  # noqa: N802 - QGIS API
        return self.tr(self.DISPLAY)

    def group(self) -> str:
        return self.tr(self.GROUP)

    def groupId(self) -> str:  # noqa: N802 - QGIS API
        return self.GROUP_ID

    def tags(self) -> list[str]:
        return [self.tr(t) for t in (*TAGS.get(self.ALG_ID, ()), *_COMMON_TAGS)]

    def shortHelpString(self) -> str:  # noqa: N802 - QGIS API
        return self.tr(plain_help(self.HELP))

    def helpString(self) -> str:  # noqa: N802 - QGIS API
        return self.tr(plain_help(self.HELP))

    def helpUrl(self) -> str:  # noqa: N802 - QGIS API
        from ..resources import help_url

        return help_url(self.ALG_ID) if self.ALG_ID else HELP_URL

    def icon(self) -> QIcon:
        from ..resources import ICON

        return QIcon(str(ICON))

    def canExecute(self) -> tuple[bool, str]:  # noqa: N802 - QGIS API
        """False, with what to install, when a package this algorithm needs is missing
        (the dialog shows the message instead of failing on Run)."""
        from ..dependencies import dependency_problem

        problem = dependency_problem(self.ALG_ID, self.displayName())
        return (False, problem) if problem is not None else (True, "")

    def createInstance(self) -> CanopyBlocksAlgorithm:  # noqa: N802 - QGIS API
        return type(self)()

    def processAlgorithm(  # noqa: N802 - QGIS API
        self,
        parameters: dict[str, Any],
        context: QgsProcessingContext,
        feedback: QgsProcessingFeedback,
    ) -> dict[str, Any]:
        """Check the packages this algorithm needs, route logging/warnings to ``feedback``,
        map core errors, call :meth:`execute`."""
        from ..dependencies import apply_pdal_setting, dependency_problem

        problem = dependency_problem(self.ALG_ID, self.displayName())
        if problem is not None:
            raise QgsProcessingException(problem)
        apply_pdal_setting()
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

    def source_name(self, parameters: dict[str, Any], name: str,
                    context: QgsProcessingContext) -> str:
        """The name of the layer or file given to feature-source parameter ``name``."""
        layer = self.parameterAsVectorLayer(parameters, name, context)
        if layer is not None and layer.name():
            return layer.name()
        source = self.parameterAsSource(parameters, name, context)
        return input_label(source.sourceName()) if source is not None else ""

    # ---- parameter groups shared by several algorithms (names are the class constants)
    def add_photon_parameters(self, default_lengths: str) -> None:
        """INPUT (photon file), TRACK (beam/channel) and LENGTHS (block lengths, m)."""
        self.addParameter(QgsProcessingParameterFile(
            "INPUT", "Photon file (ATL03 / MABEL HDF5, CSV, Parquet)",
            behavior=QgsProcessingParameterFile.File,
            fileFilter="Photon files (*.h5 *.hdf5 *.he5 *.csv *.parquet);;All files (*.*)"))
        from ..beam_widget import track_widget_metadata

        track = QgsProcessingParameterString(
            "TRACK", "Beam (gt1l..gt3r) or MABEL channel (number or 'most')",
            defaultValue="", optional=True)
        track.setMetadata(track_widget_metadata())  # the dialog lists the file's beams
        self.addParameter(track)
        self.addParameter(QgsProcessingParameterString(
            "LENGTHS", "Block lengths (m, comma separated)", defaultValue=default_lengths))

    def add_signal_conf_parameter(self) -> None:
        """MIN_SIGNAL_CONF: ATL03 land confidence threshold (optional)."""
        self.addParameter(QgsProcessingParameterNumber(
            "MIN_SIGNAL_CONF", "ATL03: minimum land signal_conf_ph (-2..4; empty = no filter)",
            type=QgsProcessingParameterNumber.Integer, optional=True, minValue=-2, maxValue=4))

    def min_signal_conf(self, parameters: dict[str, Any],
                        context: QgsProcessingContext) -> int | None:
        """The MIN_SIGNAL_CONF value, None when empty."""
        value = optional_number(self, parameters, "MIN_SIGNAL_CONF", context)
        return None if value is None else int(value)

    def add_reference_parameters(self, optional: bool = False) -> None:
        """DTM, DSM_MAX, DSM_P90 rasters, corridor WIDTH (m) and vertical OFFSET (m)."""
        self.addParameter(QgsProcessingParameterRasterLayer("DTM", "DTM", optional=optional))
        self.addParameter(QgsProcessingParameterRasterLayer("DSM_MAX", "DSM (maximum)",
                                                            optional=optional))
        self.addParameter(QgsProcessingParameterRasterLayer("DSM_P90", "DSM (90th percentile)",
                                                            optional=optional))
        self.addParameter(QgsProcessingParameterNumber(
            "WIDTH", "Corridor width (m; empty = the footprint of the photons' sensor: "
            "ICESat-2 13, MABEL 2)", type=QgsProcessingParameterNumber.Double,
            optional=True, minValue=0.001))
        self.addParameter(QgsProcessingParameterNumber(
            "OFFSET", "Vertical offset N = h_photon - H_reference (m; empty = none)",
            type=QgsProcessingParameterNumber.Double, optional=True))
