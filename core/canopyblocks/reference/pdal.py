"""Find and run the ``pdal`` command line; read a tile's summary.

PDAL always runs in a subprocess, through the wrapper that ``scripts/install_pdal.sh``
writes (it sets PDAL's own library paths for that process only).  Nothing of PDAL's
environment ever enters this Python process: with it, GDAL/PROJ in Python (rasterio,
pyproj) and QGIS break.

Pipelines are data: the JSON files in :mod:`canopyblocks.pdal_pipelines` run as they
are with ``pdal pipeline FILE.json --readers.las.filename=IN --writers.gdal.filename=OUT``;
the core changes them only by overriding stage options on the command line
(:func:`run_pipeline`) or, for several tiles, by editing the parsed stage list
(:func:`expand_readers`, :func:`insert_after_readers`), never by string templating.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import subprocess
import time
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

from ..errors import DependencyError, FileFormatError, InputError, PdalError
from ..progress import Progress
from ..readers.las_header import check_las_file

__all__ = [
    "DEFAULT_PDAL",
    "PIPELINES",
    "TileInfo",
    "find_pdal",
    "pdal_version",
    "pipeline_path",
    "load_pipeline",
    "write_pipeline",
    "expand_readers",
    "insert_after_readers",
    "run_pipeline",
    "tile_info",
]

log = logging.getLogger(__name__)

DEFAULT_PDAL = Path("/opt/canopyblocks-pdal/bin/pdal")
"""Where ``scripts/install_pdal.sh`` puts the wrapper by default."""

PIPELINES = ("dtm", "dtm_smrf", "dsm_max", "crop_corridor")
"""Names of the pipelines shipped in :mod:`canopyblocks.pdal_pipelines`."""

_INSTALL_HINT = "install it with: bash scripts/install_pdal.sh (or put pdal on PATH)"
_MAX_MESSAGE = 600


def _usable(path: Path) -> bool:
    return path.is_file() and os.access(path, os.X_OK)


def find_pdal(setting: str | os.PathLike[str] | None = None) -> Path:
    """Locate the ``pdal`` executable.

    Order: ``setting`` (a path, e.g. a plugin setting or ``--pdal``), the environment
    variable ``CANOPYBLOCKS_PDAL``, ``pdal`` on ``PATH``, then :data:`DEFAULT_PDAL`.

    Raises
    ------
    DependencyError
        When an explicit setting or ``CANOPYBLOCKS_PDAL`` names no executable file, or
        when nothing is found; the message says how to install PDAL.
    """
    from ..arguments import check_path
    None if setting is None else check_path(
        setting, "find_pdal: setting", "the path of a pdal executable or None"
    )
    for value, what in ((setting, "the pdal setting"),
                        (os.environ.get("CANOPYBLOCKS_PDAL") or None, "CANOPYBLOCKS_PDAL")):
        if value is None:
            continue
        p = Path(value).expanduser()
        if _usable(p):
            return p
        found = shutil.which(str(value))
        if found:
            return Path(found)
        raise DependencyError(f"{what} is {str(value)!r}, which is not an executable file; "
                              f"{_INSTALL_HINT}")
    on_path = shutil.which("pdal")
    if on_path:
        return Path(on_path)
    if _usable(DEFAULT_PDAL):
        return DEFAULT_PDAL
    raise DependencyError(f"the pdal command line was not found (CANOPYBLOCKS_PDAL, PATH, "
                          f"{DEFAULT_PDAL}); {_INSTALL_HINT}")


@lru_cache(maxsize=8)
def _version_of(exe: str) -> str:
    try:
        out = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise DependencyError(f"{exe} --version failed: {exc}; {_INSTALL_HINT}") from None
    for token in out.stdout.split():
        if token[:1].isdigit() and token.count(".") >= 1:
            return token
    raise DependencyError(f"{exe} --version printed no version (exit {out.returncode}): "
                          f"{_trim(out.stderr or out.stdout)}; {_INSTALL_HINT}")


def pdal_version(pdal: str | os.PathLike[str] | None = None) -> str:
    """PDAL's version string, e.g. ``"2.2.0"`` (cached per executable)."""
    return _version_of(str(find_pdal(pdal)))


def pipeline_path(name_or_path: str | os.PathLike[str]) -> Path:
    """The JSON file for a shipped pipeline name (``"dtm"``) or an existing path.

    Raises
    ------
    InputError
        Neither a shipped pipeline name nor an existing file.
    """
    p = Path(name_or_path)
    if p.suffix == ".json" and p.is_file():
        return p
    name = p.name[:-5] if p.name.endswith(".json") else p.name
    if name in PIPELINES:
        return _shipped_pipeline(name)
    raise InputError(f"pipeline {str(name_or_path)!r} is neither an existing .json file nor "
                     f"one of the shipped pipelines {', '.join(PIPELINES)}")


def _shipped_pipeline(name: str) -> Path:
    """A shipped pipeline, in either layout: installed (package data
    ``canopyblocks.pdal_pipelines``) or a checkout on ``PYTHONPATH=<checkout>/core``, where
    the JSON files live in ``<checkout>/pdal_pipelines`` beside ``core/``."""
    try:
        ref = resources.files("canopyblocks.pdal_pipelines").joinpath(f"{name}.json")
        with resources.as_file(ref) as real:
            if Path(real).is_file():
                return Path(real)
    except ModuleNotFoundError:
        pass
    checkout = Path(__file__).resolve().parents[3] / "pdal_pipelines" / f"{name}.json"
    if checkout.is_file():
        return checkout
    raise DependencyError(
        f"the PDAL pipeline {name}.json is not installed with canopyblocks (looked in the "
        f"package and in {checkout.parent}); reinstall canopyblocks or use a full checkout")


def load_pipeline(name_or_path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The stage list of a pipeline (``{"pipeline": [...]}`` or a bare list)."""
    path = pipeline_path(name_or_path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise FileFormatError(f"cannot read the PDAL pipeline {path}: {exc}") from None
    stages = doc.get("pipeline") if isinstance(doc, dict) else doc
    if not isinstance(stages, list) or not all(isinstance(s, dict) for s in stages):
        raise FileFormatError(f"{path} is not a PDAL pipeline (a list of stage objects)")
    return [dict(s) for s in stages]


def write_pipeline(stages: list[dict[str, Any]], path: str | os.PathLike[str]) -> Path:
    """Write a stage list as ``{"pipeline": [...]}`` JSON; return the path."""
    out = Path(path)
    out.write_text(json.dumps({"pipeline": stages}, indent=2) + "\n", encoding="utf-8")
    return out


def _is_reader(stage: dict[str, Any]) -> bool:
    return str(stage.get("type", "")).startswith("readers.")


def expand_readers(stages: list[dict[str, Any]],
                   tiles: list[tuple[str | os.PathLike[str], str | None]]) -> list[dict[str, Any]]:
    """Replace the pipeline's single reader by one reader per tile.

    Parameters
    ----------
    stages : list of dict
        A pipeline with exactly one ``readers.*`` stage, first.
    tiles : list of (path, srs)
        Each tile's file and, when not None, a ``spatialreference`` to assign (WKT or
        ``EPSG:n``) for a file whose own CRS is missing or unreadable by PDAL.

    Notes
    -----
    PDAL feeds every reader listed before the first filter into that filter; the GDAL
    writer accumulates all of them into one grid (checked against numpy in the tests).
    """
    readers = [i for i, s in enumerate(stages) if _is_reader(s)]
    if readers != [0]:
        raise InputError("expand_readers needs a pipeline whose only reader is its first stage")
    if not tiles:
        raise InputError("no tiles given")
    template = {k: v for k, v in stages[0].items() if k != "tag"}
    new = []
    for path, srs in tiles:
        st = dict(template, filename=str(path))
        if srs is not None:
            st["spatialreference"] = srs
        new.append(st)
    return new + [dict(s) for s in stages[1:]]


def insert_after_readers(stages: list[dict[str, Any]], stage: dict[str, Any]) -> list[dict[str, Any]]:
    """A copy of ``stages`` with ``stage`` placed right after the last reader."""
    last = max((i for i, s in enumerate(stages) if _is_reader(s)), default=-1)
    return [dict(s) for s in stages[: last + 1]] + [dict(stage)] + [
        dict(s) for s in stages[last + 1:]]


def _format_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if not math.isfinite(value):
            raise InputError(f"PDAL option value {value!r} is not finite")
        return repr(value)
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return str(value)


def _trim(text: str) -> str:
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    errors = [ln for ln in lines if "Warning)" not in ln]
    lines = errors or lines
    # PDAL prefixes its errors with "PDAL:"; keep the last few meaningful lines.
    msg = " | ".join(ln.removeprefix("PDAL: ") for ln in lines[-4:])
    return msg if len(msg) <= _MAX_MESSAGE else "..." + msg[-_MAX_MESSAGE:]


def run_pipeline(
    name_or_path: str | os.PathLike[str],
    options: dict[str, object] | None = None,
    *,
    pdal: str | os.PathLike[str] | None = None,
    progress: Progress | None = None,
    timeout: float | None = None,
) -> subprocess.CompletedProcess[str]:
    """Run ``pdal pipeline FILE --stage.option=value ...`` in a subprocess.

    Parameters
    ----------
    name_or_path : str or path
        A shipped pipeline name (see :data:`PIPELINES`) or a JSON file.
    options : dict
        Stage option overrides, keyed ``"stage.type.option"`` (e.g.
        ``{"readers.las.filename": path, "writers.gdal.resolution": 2.0}``).  PDAL applies
        an override to every stage of that type; overriding a stage the pipeline lacks is
        an error in PDAL.
    pdal : path, optional
        The executable (default: :func:`find_pdal`).
    progress : Progress, optional
        Polled for cancellation while PDAL runs; PDAL reports no progress itself, so the
        fraction only moves from 0 to 1.
    timeout : float, optional
        Seconds before PDAL is stopped and :class:`PdalError` raised.

    Returns
    -------
    subprocess.CompletedProcess
        With PDAL's stdout and stderr as text.

    Raises
    ------
    PdalError
        PDAL exited with an error (or timed out); the message holds PDAL's own message
        (trimmed) and the pipeline file.
    CancelledError
        ``progress`` reported a cancellation; PDAL was stopped.
    DependencyError
        No pdal executable.
    """
    from ..arguments import check_optional, check_path
    check_path(name_or_path, "run_pipeline: name_or_path", "a pipeline name or JSON path")
    check_optional(
        options, dict, "run_pipeline: options", "a dict of stage.option -> value or None"
    )
    exe = find_pdal(pdal)
    path = pipeline_path(name_or_path)
    args = [str(exe), "pipeline", str(path)]
    for key, value in (options or {}).items():
        if key.count(".") < 2:
            raise InputError(f"PDAL option {key!r} must be 'stage.type.option', "
                             "e.g. 'writers.gdal.resolution'")
        args.append(f"--{key}={_format_value(value)}")
    log.debug("running %s", " ".join(args))
    if progress is not None:
        progress.update(0.0, f"PDAL {path.stem}")
    start = time.monotonic()
    try:
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                stdin=subprocess.DEVNULL, preexec_fn=_death_signal())
    except OSError as exc:
        raise DependencyError(f"cannot start {exe}: {exc}; {_INSTALL_HINT}") from None
    try:
        while True:
            try:
                out, err = proc.communicate(timeout=0.2)
                break
            except subprocess.TimeoutExpired:
                if progress is not None:
                    progress.check()
                if timeout is not None and time.monotonic() - start > timeout:
                    raise PdalError(f"PDAL did not finish {path} within {timeout:g} s; "
                                    "crop to smaller bounds or raise the timeout") from None
    except BaseException:  # cancelled, timed out, Ctrl-C, a worker's SIGTERM (SystemExit)
        proc.kill()
        proc.communicate()
        raise
    elapsed = time.monotonic() - start
    if proc.returncode != 0:
        raise PdalError(f"PDAL failed on pipeline {path} (exit {proc.returncode}): "
                        f"{_trim(err or out) or 'no message'}")
    log.info("PDAL %s finished in %.1f s", path.stem, elapsed)
    if progress is not None:
        progress.update(1.0, f"PDAL {path.stem} done")
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


def _death_signal() -> Any:
    """A ``preexec_fn`` that has Linux kill PDAL when the process that started it dies.

    A batch worker (a Dask worker above all) can be killed without running its clean-up;
    PDAL would then go on writing into a folder that is being removed, and outlive the
    command.  None where ``prctl`` is not available (PDAL then lives until it ends).
    """
    import ctypes
    import signal
    import sys

    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL("libc.so.6", use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    pr_set_pdeathsig = 1

    def set_death_signal() -> None:  # runs in the child between fork and exec
        prctl(pr_set_pdeathsig, int(signal.SIGKILL), 0, 0, 0)
    return set_death_signal


@dataclass(frozen=True)
class TileInfo:
    """What ``pdal info --summary`` says about one point-cloud file.

    Attributes
    ----------
    path : Path
    n_points : int
    bounds : tuple of float
        ``(minx, miny, maxx, maxy)`` in the file's CRS units.
    z_range : tuple of float
        ``(minz, maxz)``.
    crs_wkt : str or None
        The full CRS as PDAL read it (compound WKT when the file has a vertical CRS),
        None when the file has none (or PDAL could not read it).
    horizontal_wkt : str or None
        The horizontal part alone.
    dimensions : tuple of str
    pdal_version : str
    """

    path: Path
    n_points: int
    bounds: tuple[float, float, float, float]
    z_range: tuple[float, float]
    crs_wkt: str | None
    horizontal_wkt: str | None
    dimensions: tuple[str, ...]
    pdal_version: str


def tile_info(path: str | os.PathLike[str], *, pdal: str | os.PathLike[str] | None = None,
              timeout: float | None = 120.0) -> TileInfo:
    """Bounds, CRS and point count of a LAS/LAZ file via ``pdal info --summary``.

    Raises
    ------
    FileFormatError
        The file is missing, or PDAL cannot read it (its message is included).
    """
    p = Path(path)
    if not p.is_file():
        raise FileFormatError(f"point-cloud file {p} does not exist")
    check_las_file(p)
    exe = find_pdal(pdal)
    try:
        out = subprocess.run([str(exe), "info", "--summary", str(p)], capture_output=True,
                             text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        raise PdalError(f"pdal info did not finish on {p} within {timeout} s") from None
    if out.returncode != 0:
        raise FileFormatError(f"PDAL cannot read {p}: {_trim(out.stderr or out.stdout)}")
    try:
        doc = json.loads(out.stdout)
        summ = doc["summary"]
        n = int(summ.get("num_points", 0))
        b = summ.get("bounds") or {}
        srs = summ.get("srs") or {}
    except (ValueError, KeyError, TypeError) as exc:
        raise PdalError(f"pdal info printed unexpected output for {p}: {exc}") from None
    if n > 0 and b:
        bounds = (float(b["minx"]), float(b["miny"]), float(b["maxx"]), float(b["maxy"]))
        z_range = (float(b["minz"]), float(b["maxz"]))
    else:
        bounds = (math.nan,) * 4
        z_range = (math.nan, math.nan)
    wkt = (srs.get("compoundwkt") or srs.get("wkt") or "").strip() or None
    horiz = (srs.get("horizontal") or srs.get("wkt") or "").strip() or None
    dims = tuple(d.strip() for d in str(summ.get("dimensions", "")).split(",") if d.strip())
    return TileInfo(path=p, n_points=n, bounds=bounds, z_range=z_range, crs_wkt=wkt,
                    horizontal_wkt=horiz, dimensions=dims,
                    pdal_version=str(doc.get("pdal_version", "")).split(" ")[0])
