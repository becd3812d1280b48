"""What the whole chain returns (:class:`ChainResult`), photons or waveforms alike."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd


@dataclass
class ChainResult:
    """Files and tables of one :func:`run_chain` run (all paths inside ``out_dir``)."""

    out_dir: Path
    photons: Path | str  # a granule's URL (without its query string) when read from storage
    blocks: Path
    rasters: dict[str, Path]
    validation: Path
    report: Path
    plots: list[Path] = field(default_factory=list)
    stats: pd.DataFrame | None = None
    simulated: bool = False
    summary: list[str] = field(default_factory=list)
    """The report summary's lines (the estimators it leads with, against its reference)."""
