"""The beams of one GEDI L1B file read and processed in a pool of worker processes,
and what one beam's job needs: invalid shots flagged, its waveform plots drawn.

One unit of work is one beam: its shots are read in chunks, processed
(:func:`~canopyblocks.waveforms.process.process_waveforms`) and flagged inside a worker,
and only its footprint tables (and the paths of the waveform plots it drew) come back.
h5py serialises every HDF5 call inside one process, so reading and inflating beams in
parallel needs processes. The tables are those of the one-process loop of
:func:`~canopyblocks.workflows.waveforms.footprints_from_l1b`, value for value, in the
same beam order; warnings raised in the workers are raised again here, in beam order.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..progress import Progress, as_progress
from .backends import default_workers, run_items

__all__ = ["BeamJob", "BeamOutcome", "beams_for_workers", "beams_in_workers"]


@dataclass(frozen=True)
class BeamJob:
    """One beam to read and process in a worker (every field picklable)."""

    path: str
    beam: str
    params: Any                      # WaveformParams without the terrain filter
    plot_params: Any                 # WaveformParams of the plots
    bbox: tuple[float, float, float, float] | None = None
    quality: bool = False
    chunk_shots: int = 4096
    plot_shots: tuple[int, ...] | None = None
    plots_dir: str | None = None


@dataclass
class BeamOutcome:
    """What a worker sends back for one :class:`BeamJob`."""

    job: BeamJob
    tables: list[pd.DataFrame] = field(default_factory=list)
    problems: int = 0
    plots: list[Path] = field(default_factory=list)
    warnings: tuple[tuple[str, type[Warning]], ...] = ()


def run_beam_job(job: BeamJob) -> BeamOutcome:
    """Read, process and flag the shots of one beam (runs in a worker)."""
    from ..readers.gedi import iter_gedi_l1b
    from ..waveforms.process import _footprint_table, shot_details

    out = BeamOutcome(job)
    wanted = None if job.plot_shots is None else set(job.plot_shots)
    plotted: dict[str, int] = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for batch in iter_gedi_l1b(job.path, [job.beam], bbox=job.bbox, quality=job.quality,
                                   chunk_shots=job.chunk_shots):
            table = flag_invalid_shots(_footprint_table(batch, job.params), batch)
            out.problems |= int(np.bitwise_or.reduce(batch.extra.get("invalid_shot", [0]),
                                                     initial=0))
            out.tables.append(table)
            if job.plots_dir is not None:
                out.plots += _plot(batch, table, wanted, plotted, Path(job.plots_dir),
                                   job.plot_params, shot_details)
    out.warnings = tuple((str(w.message), w.category) for w in caught)
    return out


def beams_for_workers(path: str | os.PathLike[str], beams: Sequence[str] | str | None,
                      workers: int | None) -> list[str]:
    """The beams to hand to worker processes, or ``[]`` when one process is the plan:
    ``workers`` (default the machine's cores) is 1, there is one beam, or a beam of the
    file is left out by the reader (it warns about it: the one-process path says so)."""
    n = workers if workers is not None else default_workers()
    if n <= 1:
        return []
    from ..readers._h5 import open_h5
    from ..readers.gedi import gedi_beams

    if beams:
        wanted = [beams] if isinstance(beams, str) else list(beams)
    else:
        present = gedi_beams(path)
        with open_h5(path) as f:
            wanted = [b for b in present if f.is_dataset(f"{b}/rxwaveform")]
        if len(wanted) < len(present):
            return []
    return wanted if len(wanted) > 1 else []


def beams_in_workers(jobs: Sequence[BeamJob], workers: int | None, *,
                     progress: Progress | None = None,
                     check: Callable[[], None] | None = None
                     ) -> tuple[dict[str, list[pd.DataFrame]], int, list[Path]]:
    """Run ``jobs`` in ``workers`` processes (default the machine's cores).

    Returns
    -------
    per_beam : dict
        Footprint tables of each beam with shots, in the order of ``jobs``.
    problems : int
        The reader's problem bits of every shot, or-ed.
    plots : list of Path
        The waveform plots drawn, in beam order.
    """
    prog = as_progress(progress)
    finished = [0]

    def done(out: BeamOutcome) -> None:   # raises CancelledError when asked to stop
        finished[0] += 1
        prog.update(finished[0] / max(1, len(jobs)), f"{out.job.beam}: processed")
        if check is not None:
            check()

    n = workers if workers is not None else default_workers()
    outcomes: list[BeamOutcome] = run_items(run_beam_job, list(jobs), backend="processes",
                                            workers=min(n, len(jobs)), done=done,
                                            start="fork")
    per_beam: dict[str, list[pd.DataFrame]] = {}
    problems = 0
    plots: list[Path] = []
    for out in outcomes:
        for message, category in out.warnings:
            warnings.warn(message, category, stacklevel=3)
        if out.tables:
            per_beam[out.job.beam] = out.tables
        problems |= out.problems
        plots += out.plots
    return per_beam, problems, plots


_PLOT_DEFAULT = 3      # waveform plots per beam when no shots are named


#: Columns of an ``invalid_shot`` footprint that are not given (NaN).
_NOT_GIVEN = ("lon", "lat", "ground", "top", "cover", "penetration", "ground_gauss")


def flag_invalid_shots(table: pd.DataFrame, batch: Any) -> pd.DataFrame:
    """Flag ``invalid_shot`` the shots whose L1B values are impossible (the reader's
    ``extra["invalid_shot"]`` bits) and the shots processing called ``ok`` whose ground,
    top or position came out non-finite; their heights and position are set to NaN."""
    from ..readers.gedi_geometry import INVALID_SHOT

    bits = batch.extra.get(INVALID_SHOT) if hasattr(batch, "extra") else None
    bad = np.zeros(len(table), dtype=bool) if bits is None else np.asarray(bits) != 0
    flag = table["flag"].to_numpy(object).copy()
    vals = table[["ground", "top", "lon", "lat"]].to_numpy(float)
    bad |= (flag == "ok") & ~np.isfinite(vals).all(axis=1)
    if not bad.any():
        return table
    flag[bad] = INVALID_SHOT
    out = table.assign(flag=flag)
    cols = [c for c in out.columns if c in _NOT_GIVEN or (c.startswith("rh") and
                                                          c[2:].isdigit())]
    out.loc[bad, cols] = np.nan
    return out


def _plot(batch: Any, table: pd.DataFrame, wanted: set[int] | None, plotted: dict[str, int],
          folder: Path, params: Any, shot_details: Any) -> list[Path]:
    from ..outputs.waveform_plot import elevation_datum, plot_waveform

    sn = table["shot_number"].to_numpy(np.int64)
    if wanted is not None:
        idx = np.flatnonzero(np.isin(sn, list(wanted)))
    else:
        done = plotted.get(batch.beam, 0)
        ok = np.flatnonzero(table["flag"].to_numpy(object) == "ok")
        idx = ok[:max(0, _PLOT_DEFAULT - done)]
        plotted[batch.beam] = done + len(idx)
    out = []
    datum = elevation_datum(batch.source) if len(idx) else ""
    for i in idx:
        details = shot_details(batch, int(i), params)
        out.append(plot_waveform(details, folder / f"waveform_{batch.beam}_{sn[i]}.png",
                                 vertical_datum=datum))
    return out
