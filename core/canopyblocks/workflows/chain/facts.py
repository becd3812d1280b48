"""The run's one terrain per block and its one table of facts (``facts.csv``).

:func:`one_terrain` gives every validation layer of a photon run the slope, aspect and
classes of the user's blocks against the DTM (their corridor's cells, DESIGN 2.5) and
recomputes the statistics layers with them, so a block is in one terrain class in every
layer, table and figure.  :func:`photon_facts` computes the facts (counts by reason, n,
bias and RMSE with their 95 % intervals, R², the sigma's observed coverage) of every
estimator set against every reference it was validated on: the report's text, the
terminal summary and ``facts.csv`` are written from them.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pandas as pd

from ...outputs.tables import write_table
from ...validation.facts import fact_rows, facts_table, share_terrain
from ...validation.residuals import RESIDUAL_PAIRS
from ...validation.stats import block_stats
from .figures import EstimatorSet

__all__ = ["one_terrain", "photon_facts", "lead_facts", "FACTS_FILE", "shared_terrain",
           "pooled_facts_part"]

#: The file holding every number of a report.
FACTS_FILE = "facts.csv"

_METRICS = ("ground", "top", "hmax", "h90")


def shared_terrain(residuals: pd.DataFrame, terrain: pd.DataFrame
                   ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A residuals layer with the run's terrain, and its statistics recomputed."""
    r = share_terrain(residuals, terrain)
    return r, block_stats(r)


def one_terrain(sets: dict[str, EstimatorSet], terrain: pd.DataFrame
                ) -> dict[str, EstimatorSet]:
    """Every set's layers with the one terrain (see the module notes)."""
    out = {}
    for name, s in sets.items():
        cr, cs = shared_terrain(s.corridor_residuals, terrain)
        s = replace(s, corridor_residuals=cr, corridor_stats=cs)
        if s.fp_residuals is not None:
            fr, fs = shared_terrain(s.fp_residuals, terrain)
            s = replace(s, fp_residuals=fr, fp_stats=fs)
        out[name] = s
    return out


def photon_facts(sets: dict[str, EstimatorSet], out: Path | None = None,
                 extra: dict[str, tuple[str, str, pd.DataFrame]] | None = None
                 ) -> pd.DataFrame:
    """The facts of every set against every reference (and of ``extra`` layers:
    ``{layer: (estimators, reference, residuals)}``); written to ``facts.csv`` in
    ``out`` when given."""
    rows: list[dict[str, object]] = []
    for s in sets.values():
        rows += fact_rows(s.corridor_residuals, estimators=s.name, reference="corridor",
                          layer=s.corridor_layer, pairs=RESIDUAL_PAIRS, metrics=_METRICS)
        if s.fp_residuals is not None:
            rows += fact_rows(s.fp_residuals, estimators=s.name, reference="footprint",
                              layer=s.lead_layer, pairs=RESIDUAL_PAIRS, metrics=_METRICS)
    for layer, (est, ref, res) in (extra or {}).items():
        rows += fact_rows(res, estimators=est, reference=ref, layer=layer,
                          pairs=RESIDUAL_PAIRS, metrics=_METRICS)
    table = facts_table(rows)
    if out is not None:
        write_table(table, out / FACTS_FILE, layer="facts")
    return table


def lead_facts(facts: pd.DataFrame, s: EstimatorSet, reference: str | None = None
               ) -> pd.DataFrame:
    """The facts rows of set ``s`` against ``reference`` (default its lead reference)."""
    ref = reference or ("footprint" if s.fp_stats is not None else "corridor")
    return facts[(facts["estimators"] == s.name) & (facts["reference"] == ref)]


def pooled_facts_part(residuals: pd.DataFrame, *, name: str, reference: str, layer: str,
                      out: Path) -> tuple[list[str], dict[str, pd.DataFrame]]:
    """The facts of pooled residuals (``batch``): written to ``facts.csv`` in ``out``;
    the report's words (counts by reason, interval method) and its table."""
    from .report import BLOCK_BOOTSTRAP_WORDS, counts_sentence, lead_numbers, numbers_table

    facts = facts_table(fact_rows(residuals, estimators=name, reference=reference,
                                  layer=layer, pairs=RESIDUAL_PAIRS, metrics=_METRICS))
    write_table(facts, out / FACTS_FILE, layer="facts")
    table = lead_numbers(facts)
    words = [counts_sentence(table),
             f"95 % intervals: {BLOCK_BOOTSTRAP_WORDS}. facts.csv holds these numbers."]
    return [w for w in words if w], {"ground and canopy height (Hmax), all units pooled, "
                                     "with 95 % intervals": numbers_table(table)}
