"""Bridge to the canopyblocks core: lazy import, progress/cancel, errors, logging.

The plugin imports nothing of the core at load time, so QGIS starts even when the
core is not installed in QGIS's Python; the algorithms then fail with a message
saying how to install it.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import Any

from qgis.core import Qgis, QgsMessageLog, QgsProcessingException, QgsProcessingFeedback

from .dependencies import install_hint

__all__ = [
    "MESSAGE_TAG",
    "qgis_words",
    "LIBRARY_CLASH_SIGNS",
    "feedback_logging",
    "install_hint",
    "core",
    "core_available",
    "import_core",
    "progress_for",
    "core_errors",
    "QgsLogHandler",
    "attach_log_handler",
    "detach_log_handler",
]

MESSAGE_TAG = "canopyblocks"


#: Messages of PyPI wheels that bundle GEOS/HDF5/GDAL and meet QGIS's own copies in the
#: QGIS process (the executable's libraries take precedence over the wheel's).
LIBRARY_CLASH_SIGNS = ("Not a datatype", "WKB output dimension", "undefined symbol",
                       "GEOS_", "H5T", "free(): invalid")


def import_core(name: str = "canopyblocks") -> ModuleType:
    """Import ``name`` (a core module) or raise QgsProcessingException with the install hint."""
    import importlib

    from .venv_guard import venv_problem
    from .wheel_guard import wheel_problem

    problem = venv_problem()
    if problem is not None:
        raise QgsProcessingException(problem)
    problem = wheel_problem()
    if problem is not None:
        raise QgsProcessingException(f"{problem}; {install_hint()}")
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        missing = getattr(exc, "name", None) or str(exc)
        if name != "canopyblocks" and core_available():
            top = str(missing).split(".")[0]
            if top != "canopyblocks":  # a third-party package the core needs
                from .dependencies import install_command

                raise QgsProcessingException(
                    f"the Python package {top} is missing in the Python that runs QGIS "
                    f"(canopyblocks needs it for {name}); install it: "
                    f"{install_command([top])}; then restart QGIS") from exc
            raise QgsProcessingException(
                f"canopyblocks is installed but {name} could not be imported ({exc}); "
                f"this plugin needs a matching canopyblocks version; " + install_hint()
            ) from exc
        raise QgsProcessingException(
            f"the canopyblocks core library is not importable (missing: {missing}); "
            + install_hint()
        ) from exc


def core() -> ModuleType:
    """The ``canopyblocks`` package (see :func:`import_core`)."""
    return import_core("canopyblocks")


def core_available() -> bool:
    """True when ``import canopyblocks`` works in this Python."""
    try:
        import canopyblocks  # noqa: F401
    except ImportError:
        return False
    return True


def progress_for(feedback: QgsProcessingFeedback | None) -> Any:
    """A core ``Progress`` that drives ``feedback`` (percent, text) and sees its cancel flag."""
    progress_mod = import_core("canopyblocks.progress")
    if feedback is None:
        return progress_mod.Progress()
    last = [""]

    def callback(fraction: float, message: str) -> None:
        feedback.setProgress(100.0 * fraction)
        if message and message != last[0]:
            last[0] = message
            feedback.setProgressText(message)

    return progress_mod.Progress(callback=callback, cancelled=feedback.isCanceled)


#: Command-line options named in the core's messages -> the parameters of the algorithms.
QGIS_NAMES = {
    "geoid": "Geoid undulation raster", "offset": "Vertical offset",
    "atl08": "Matching ATL08 file", "dtm": "DTM", "dsm-max": "DSM (maximum)",
    "dsm-p90": "DSM (90th percentile)", "crs": "CRS", "smrf": "Ground points: SMRF",
    "min-signal-conf": "ATL03: minimum land signal_conf_ph", "beam": "Beam",
    "width": "Corridor width", "length": "Block lengths", "preset": "Preset",
    "photon-vcrs": "Photons' vertical CRS", "diameter": "Footprint diameter",
    "points": "Airborne LAS/LAZ tiles", "seed": "Random seed", "resolution": "Cell size",
    "top-cutoff": "Canopy-top cut-off", "ground-cutoff": "Ground cut-off",
}
_OPTION = re.compile(r"--([a-z][a-z0-9-]*)")
_COMMAND = re.compile(r"`?canopyblocks (rasters|validate|blocks|simulate|calibrate|waveforms|"
                      r"coregister)`?")
_COMMAND_NAMES = {"rasters": "Reference rasters from airborne lidar", "validate":
                  "Validate blocks against reference rasters", "blocks":
                  "Block canopy heights from photons", "simulate":
                  "Simulate ICESat-2 photons from airborne lidar", "calibrate":
                  "Calibrate cut-offs against reference rasters", "waveforms":
                  "GEDI footprints from L1B waveforms", "coregister":
                  "Co-register a track with airborne lidar"}


def qgis_words(message: str) -> str:
    """The core's message in QGIS terms: command-line options become the parameters of
    the algorithms (``--geoid`` -> 'Geoid undulation raster'), commands become algorithm
    names; "(CLI: ...)" asides go."""
    text = re.sub(r"\s*\(CLI: [^)]*\)", "", message)
    text = _COMMAND.sub(lambda m: f"the '{_COMMAND_NAMES[m.group(1)]}' algorithm", text)
    return _OPTION.sub(lambda m: f"'{QGIS_NAMES.get(m.group(1), m.group(1).replace('-', ' '))}'",
                       text)


@contextmanager
def core_errors() -> Iterator[None]:
    """Turn the core's errors into QgsProcessingException carrying the core's message."""
    errors = import_core("canopyblocks.errors")
    try:
        yield
    except QgsProcessingException:
        raise
    except errors.CancelledError as exc:
        raise QgsProcessingException(f"canopyblocks: {qgis_words(str(exc))}") from exc
    except errors.CanopyBlocksError as exc:
        raise QgsProcessingException(f"canopyblocks: {qgis_words(str(exc))}") from exc
    except Exception as exc:
        text = f"{type(exc).__name__}: {exc}"
        if any(sign in text for sign in LIBRARY_CLASH_SIGNS):
            raise QgsProcessingException(
                f"canopyblocks: a compiled library clashed with QGIS's own ({text}); the "
                "Python packages seen by QGIS must be built on QGIS's GEOS/PROJ/GDAL/HDF5; "
                + install_hint()
            ) from exc
        raise


class QgsLogHandler(logging.Handler):
    """Route ``logging`` records of the core to the QGIS message log (tab 'canopyblocks').

    When a processing feedback is set (during an algorithm run), INFO and above also go to
    the algorithm's log panel.
    """

    def __init__(self, level: int = logging.INFO) -> None:
        super().__init__(level)
        self.setFormatter(logging.Formatter("%(name)s: %(message)s"))
        self.feedback: QgsProcessingFeedback | None = None

    def emit(self, record: logging.LogRecord) -> None:
        try:
            msg = self.format(record)
            if record.levelno >= logging.ERROR:
                level = Qgis.Critical
            elif record.levelno >= logging.WARNING:
                level = Qgis.Warning
            else:
                level = Qgis.Info
            QgsMessageLog.logMessage(msg, MESSAGE_TAG, level, False)
            fb = self.feedback
            if fb is not None:
                if record.levelno >= logging.WARNING:
                    fb.pushWarning(msg)
                else:
                    fb.pushInfo(msg)
        except Exception:  # noqa: BLE001 - a log handler must never raise
            self.handleError(record)


_HANDLER: QgsLogHandler | None = None


def attach_log_handler() -> QgsLogHandler:
    """Add (once) the QGIS log handler to the ``canopyblocks`` logger."""
    global _HANDLER
    if _HANDLER is None:
        _HANDLER = QgsLogHandler()
        logger = logging.getLogger("canopyblocks")
        logger.addHandler(_HANDLER)
        if logger.level == logging.NOTSET or logger.level > logging.INFO:
            logger.setLevel(logging.INFO)
    return _HANDLER


def detach_log_handler() -> None:
    """Remove the handler added by :func:`attach_log_handler` (plugin unload)."""
    global _HANDLER
    if _HANDLER is not None:
        logging.getLogger("canopyblocks").removeHandler(_HANDLER)
        _HANDLER = None


@contextmanager
def feedback_logging(feedback: QgsProcessingFeedback | None) -> Iterator[None]:
    """During an algorithm run, also echo core log records and warnings to ``feedback``."""
    import warnings

    handler = attach_log_handler()
    previous = handler.feedback
    handler.feedback = feedback
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield
        for w in caught:
            text = f"{w.category.__name__}: {w.message}"
            QgsMessageLog.logMessage(text, MESSAGE_TAG, Qgis.Warning, False)
            if feedback is not None:
                feedback.pushWarning(text)
    finally:
        handler.feedback = previous
