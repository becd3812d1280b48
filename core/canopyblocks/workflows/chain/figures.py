"""The estimator sets of :func:`~canopyblocks.workflows.chain.run_chain` and their figures.

A run computes the blocks with the user's estimators and, beside them, the recommended
ones (or, when the user's are the recommended ones, the paper's method for its own
section).  Each set keeps its blocks, photon labels and validations (corridor maximum,
and footprint-matched when computed).  The figures name the estimators and the
reference they show: the lead (recommended) estimators against their like-with-like
reference in the plain file names (``validation_<L>m.png``, ``aspect_rmse_<L>m.png``,
``residual_map.png``, ``profile.png``), the paper's method against the corridor maximum
in ``paper_corridor_validation_<L>m.png`` and ``paper_corridor_aspect_rmse_<L>m.png``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pandas as pd

from ...schema import LAYER_RESIDUALS, LAYER_STATS

__all__ = ["EstimatorSet", "BiasOffer", "Figures", "chain_figures", "reference_short",
           "estimator_words"]

#: Short names of the references, for titles and captions.
REFERENCE_SHORT = {"footprint": "footprint-matched reference (block percentiles and ground)",
                   "corridor": "corridor maximum"}


def reference_short(kind: str) -> str:
    """``footprint`` / ``corridor`` -> the words figure titles use."""
    return REFERENCE_SHORT.get(kind, kind)


def estimator_words(name: str) -> str:
    """How the report and the figures name a set of estimators."""
    return "the paper's method" if name == "paper" else f"the '{name}' estimator"


@dataclass(frozen=True)
class EstimatorSet:
    """Blocks of one set of estimators and their validations.

    ``suffix`` is appended to the validation.gpkg layer names (``""`` for the user's
    estimators, ``_<preset>`` for the set computed beside them).
    """

    name: str
    blocks: pd.DataFrame
    labels: dict[str, dict[float, Any]]
    suffix: str
    corridor_residuals: pd.DataFrame
    corridor_stats: pd.DataFrame
    fp_residuals: pd.DataFrame | None = None
    fp_stats: pd.DataFrame | None = None
    estimators: Any = None

    def with_footprint(self, residuals: pd.DataFrame, stats: pd.DataFrame) -> EstimatorSet:
        return replace(self, fp_residuals=residuals, fp_stats=stats)

    def layers(self) -> dict[str, pd.DataFrame]:
        """The validation.gpkg layers of this set."""
        out = {f"{LAYER_RESIDUALS}{self.suffix}": self.corridor_residuals,
               f"{LAYER_STATS}{self.suffix}": self.corridor_stats}
        if self.fp_residuals is not None and self.fp_stats is not None:
            out[f"{LAYER_RESIDUALS}_footprint{self.suffix}"] = self.fp_residuals
            out[f"{LAYER_STATS}_footprint{self.suffix}"] = self.fp_stats
        return out

    @property
    def lead_residuals(self) -> pd.DataFrame:
        """Residuals against the like-with-like reference (footprint when computed)."""
        return self.fp_residuals if self.fp_residuals is not None else self.corridor_residuals

    @property
    def lead_stats(self) -> pd.DataFrame:
        return self.fp_stats if self.fp_stats is not None else self.corridor_stats

    @property
    def lead_layer(self) -> str:
        """The stats layer of :attr:`lead_stats`."""
        return (f"{LAYER_STATS}_footprint{self.suffix}" if self.fp_stats is not None
                else f"{LAYER_STATS}{self.suffix}")

    @property
    def corridor_layer(self) -> str:
        return f"{LAYER_STATS}{self.suffix}"

    def est(self) -> Any:
        """The :class:`Estimators` object (the paper's when none was given)."""
        from ...blocks.estimators import Estimators, preset

        if self.estimators is not None:
            return self.estimators
        return preset(self.name) if self.name in ("paper", "atl08", "icesat2", "mabel") \
            else Estimators(name="paper")


@dataclass(frozen=True)
class BiasOffer:
    """A bias calibration of the lead estimators, fitted against ``reference``
    (``footprint``/``corridor``); ``offered`` only when it improves every held-out error
    (else ``why`` says why not)."""

    name: str
    reference: str
    table: pd.DataFrame
    offered: bool
    why: str


@dataclass
class Figures:
    """The chain's figures, by role (paths; empty lists when not drawn)."""

    profile: Path | None = None
    lead_scatter: list[Path] = field(default_factory=list)
    lead_aspect: list[Path] = field(default_factory=list)
    residual_map: Path | None = None
    paper_scatter: list[Path] = field(default_factory=list)
    paper_aspect: list[Path] = field(default_factory=list)

    def all(self) -> list[Path]:
        return [p for p in (self.profile, *self.lead_scatter, *self.lead_aspect,
                            self.residual_map, *self.paper_scatter, *self.paper_aspect)
                if p is not None]


def _length_for_map(residuals: pd.DataFrame) -> float:
    lengths = sorted(float(v) for v in residuals["length"].unique())
    return 25.0 if 25.0 in lengths else lengths[len(lengths) // 2]


def chain_figures(lead: EstimatorSet, paper: EstimatorSet | None, track: Any, folder: Path,
                  *, dtm: Path, datum: str | None, lead_reference: str) -> Figures:
    """Draw the profile (the lead estimators, the paper's method overlaid), the lead's
    scatter and aspect figures and residual map against its reference, and the paper's
    method against the corridor maximum (when computed)."""
    from ...outputs.footprint_maps import plot_footprint_map
    from ...outputs.profile_plot import plot_profile
    from ...outputs.validation_plots import write_validation_plots

    figs = Figures()
    overlay = paper.blocks if paper is not None and paper is not lead else None
    figs.profile = plot_profile(
        track, lead.blocks, folder / "profile.png", labels=lead.labels.get(track.track),
        name=lead.name, overlay=overlay, overlay_name="the paper's method",
        title=f"{track.track}: {estimator_words(lead.name)}"
              + (" (the paper's method dashed)" if overlay is not None else ""))
    who = estimator_words(lead.name)
    ref = reference_short(lead_reference)
    paths = write_validation_plots(lead.lead_residuals, lead.lead_stats, folder, datum=datum,
                                   estimator=lead.name, reference=ref)
    figs.lead_scatter = [p for p in paths if p.name.startswith("validation_")]
    figs.lead_aspect = [p for p in paths if p.name.startswith("aspect_")]
    res = lead.lead_residuals
    length = _length_for_map(res)
    figs.residual_map = plot_footprint_map(
        res[res["length"] == length], "res_hmax", folder / "residual_map.png", dtm=dtm,
        title=f"Hmax residual of {who} against the {ref}, {length:g} m blocks")
    if paper is not None:
        pp = write_validation_plots(paper.corridor_residuals, paper.corridor_stats, folder,
                                    datum=datum, estimator="paper",
                                    reference=reference_short("corridor"),
                                    prefix="paper_corridor_")
        figs.paper_scatter = [p for p in pp if "validation_" in p.name]
        figs.paper_aspect = [p for p in pp if "aspect_" in p.name]
    return figs
