"""A short, self-contained HTML report of a run: inputs, parameters, statistics, plots."""

from __future__ import annotations

import html
import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from ..atomic import atomic_output, atomic_outputs, will_exist
from ..progress import Progress

__all__ = ["ReportSection", "write_report", "report_stats_table", "footprint_stats_table",
           "format_number", "group_words",
           "calibration_table", "STATS_HEADERS", "CALIBRATION_HEADERS"]

log = logging.getLogger(__name__)


@dataclass
class ReportSection:
    """One section: a heading, paragraphs, tables and images (paths relative to the report)."""

    heading: str
    paragraphs: Sequence[str] = ()
    tables: Mapping[str, pd.DataFrame] = field(default_factory=dict)
    images: Sequence[str | os.PathLike[str]] = ()


_CSS = """
body{font-family:system-ui,sans-serif;max-width:70rem;margin:2rem auto;padding:0 1rem;color:#222}
h1{font-size:1.6rem}h2{font-size:1.25rem;border-bottom:1px solid #ccc;padding-bottom:.2rem}
table{border-collapse:collapse;font-size:.8rem;margin:.5rem 0 1rem;display:block;
overflow-x:auto;max-width:100%}th{white-space:normal;vertical-align:bottom;font-weight:600}
td,th{border:1px solid #ccc;padding:.15rem .4rem;text-align:right}th{background:#f3f3f3}
td:first-child,th:first-child{text-align:left}img{max-width:100%;border:1px solid #ddd;margin:.5rem 0}
.cap{font-size:.85rem;color:#555}
"""


#: Report headers of the statistics columns, with units (metres unless stated).
STATS_HEADERS: dict[str, str] = {
    "length": "length (m)", "metric": "metric", "group": "group", "n": "n (blocks)",
    "bias": "bias (m)", "rmse": "RMSE (m)", "mae": "MAE (m)", "slope": "slope (m/m)",
    "r2": "R²",
}


def group_words(group: str) -> str:
    """A statistics group as the report names it, with its unit: ``slope:0-5`` ->
    ``slope 0-5 degrees``, ``aspect:flat`` -> ``aspect flat (slope below 2 degrees)``,
    ``cover:0.25-0.5`` -> ``cover 0.25-0.5 (fraction)``, ``all`` -> ``all``."""
    kind, _, cls = str(group).partition(":")
    if not cls:
        return str(group)
    if kind == "slope":
        return f"slope {cls} degrees" if cls != "unknown" else "slope unknown"
    if kind == "aspect":
        return ("aspect flat (slope below 2 degrees)" if cls == "flat"
                else f"aspect {cls}")
    if kind == "cover":
        return f"cover {cls} (fraction)" if cls != "unknown" else "cover unknown"
    return f"{kind} {cls}"


#: Report headers of the calibration tables (cut-offs and bias), with units.
CALIBRATION_HEADERS: dict[str, str] = {
    "length": "length (m)", "metric": "metric", "strength": "beam strength",
    "top_cutoff": "top cut-off, fitted", "ground_cutoff": "ground cut-off, fitted",
    "default_top_cutoff": "top cut-off, default",
    "default_ground_cutoff": "ground cut-off, default",
    "n": "n (blocks)", "n_holdout": "n held out (blocks)",
    **{f"rmse_{m}_{k}": f"{m} RMSE, {'fitted' if k == 'calibrated' else k} cut-offs (m)"
       for m in ("top", "ground", "hmax") for k in ("default", "calibrated")},
    "slope": "slope (m/m)", "intercept": "correction added (m)",
    "rmse_before": "RMSE before (m)", "rmse_after": "RMSE after (m)",
    "holdout_rmse_before": "held-out RMSE before (m)",
    "holdout_rmse_after": "held-out RMSE after (m)",
}


def calibration_table(table: pd.DataFrame) -> pd.DataFrame:
    """A calibration table (cut-offs or bias) as the report shows it: lengths and counts
    as integers, headers in words with units (so they wrap on a narrow page).  A bias
    calibration's intercept is its correction and is kept."""
    df = pd.DataFrame(table).drop(columns=["geometry"], errors="ignore").copy()
    for c in ("length", "n", "n_holdout"):
        if c in df.columns:
            df[c] = pd.to_numeric(df[c], errors="coerce").round().astype("Int64")
    for c in ("top_cutoff", "ground_cutoff", "default_top_cutoff", "default_ground_cutoff"):
        if c in df.columns:  # fractions down to 0.001: three significant digits
            df[c] = [f"{v:.3g}" if v == v else "" for v in pd.to_numeric(df[c], errors="coerce")]
    return df.rename(columns=CALIBRATION_HEADERS)


def report_stats_table(stats: pd.DataFrame) -> pd.DataFrame:
    """A statistics table as the report shows it: lengths and counts as integers, units
    in the headers, no intercept (an intercept fitted on absolute elevations says
    nothing; bias and slope do)."""
    df = pd.DataFrame(stats).drop(columns=["intercept", "geometry"], errors="ignore").copy()
    for c in ("length", "n"):
        if c in df.columns:
            df[c] = pd.to_numeric(df[c], errors="coerce").round().astype("Int64")
    if "group" in df.columns:
        df["group"] = df["group"].map(group_words)
    return df.rename(columns=STATS_HEADERS)


def footprint_stats_table(stats: pd.DataFrame) -> pd.DataFrame:
    """A footprint statistics table as the report shows it: as :func:`report_stats_table`,
    its ``length`` column named for what it is, the footprint diameter."""
    return report_stats_table(stats).rename(columns={"length (m)": "footprint diameter (m)"})


def format_number(v: float) -> str:
    """A number as the report prints it: whole numbers without decimals (13, not
    13.000), others with two decimals (metres to the centimetre; fractions such as the
    cut-offs are formatted by their table, :func:`calibration_table`)."""
    if v != v:  # NaN
        return ""
    if float(v).is_integer() and abs(v) < 1e15:
        return f"{v:.0f}"
    return f"{v:.2f}"


def _table_html(df: pd.DataFrame) -> str:
    return df.to_html(index=False, na_rep="", float_format=format_number, border=0,
                      escape=True)


def write_report(path: str | os.PathLike[str], title: str, sections: Sequence[ReportSection],
                 *, progress: Progress | None = None) -> Path:
    """Write an HTML report atomically; images are linked relative to the report's folder.

    An image that does not exist (and is not being written in the same
    :func:`~canopyblocks.atomic.atomic_outputs` block) is left out with a logged
    warning rather than linked broken.  Called inside such a block, the report appears
    together with the block's other outputs, or not at all; ``progress`` is checked
    before anything is written.
    """
    out = Path(path)
    if progress is not None:
        progress.check()
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
             f"</title><style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"]
    for sec in sections:
        parts.append(f"<h2>{html.escape(sec.heading)}</h2>")
        parts.extend(f"<p>{html.escape(p)}</p>" for p in sec.paragraphs)
        for caption, df in sec.tables.items():
            parts.append(f"<p class='cap'>{html.escape(caption)}</p>{_table_html(df)}")
        for img in sec.images:
            if not will_exist(img):
                log.warning("report %s: image %s was not written; left out", out, img)
                continue
            rel = os.path.relpath(Path(img), out.parent)
            parts.append(f"<img src='{html.escape(rel)}' alt='{html.escape(Path(img).stem)}'>")
    parts.append("</body></html>")
    with atomic_outputs(progress=progress), atomic_output(out) as tmp:
        tmp.write_text("\n".join(parts), encoding="utf-8")
    return out
