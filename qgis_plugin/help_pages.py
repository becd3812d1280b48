"""One help page per algorithm (``docs/qgis/<id>.md``), made from the algorithm itself.

The Help button of each algorithm opens its page (:func:`help_url`); the page holds the
algorithm's help text and a table of its parameters and outputs (label, key for
``qgis_process``/``processing.run``, default, and whether it is under "Advanced
Parameters"), so the page cannot drift from the dialog: ``tests/qgis/test_qgis_dialogs.py``
regenerates every page and compares.  Regenerate with
``python -m qgis_plugin.help_pages docs/qgis`` in a Python that has QGIS.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from .resources import DOCS_URL, help_url

__all__ = ["help_url", "help_page", "write_help_pages", "DOCS_URL"]


def _default(param: Any) -> str:
    value = param.defaultValue()
    if value is None or value == "":
        return ""
    options = param.options() if hasattr(param, "options") else None
    if options and isinstance(value, int) and 0 <= value < len(options):
        return options[value]
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def help_page(alg: Any) -> str:
    """The Markdown help page of an initialised algorithm."""
    from qgis.core import QgsProcessingParameterDefinition

    from .algorithms.base import plain_help

    advanced_flag = QgsProcessingParameterDefinition.FlagAdvanced
    optional_flag = QgsProcessingParameterDefinition.FlagOptional
    lines = [f"# {alg.displayName()}", "",
             f"Processing algorithm `canopyblocks:{alg.name()}` (group: {alg.group()}).", "",
             plain_help(alg.HELP).strip().replace("\n", "  \n"), "", "## Parameters", "",
             "| Label | Key | Default | Optional | Advanced |",
             "|---|---|---|---|---|"]
    for p in alg.parameterDefinitions():
        if p.isDestination():
            continue
        lines.append(f"| {p.description()} | `{p.name()}` | {_default(p)} | "
                     f"{'yes' if p.flags() & optional_flag else ''} | "
                     f"{'yes' if p.flags() & advanced_flag else ''} |")
    lines += ["", "## Outputs", "", "| Label | Key |", "|---|---|"]
    seen = set()
    for p in alg.destinationParameterDefinitions():
        seen.add(p.name())
        lines.append(f"| {p.description()} | `{p.name()}` |")
    for o in alg.outputDefinitions():
        if o.name() not in seen:
            lines.append(f"| {o.description()} | `{o.name()}` |")
    return "\n".join(lines).replace("\n\n\n", "\n\n") + "\n"


def write_help_pages(folder: str | Path) -> list[Path]:
    """Write every algorithm's page into ``folder``; returns the files written."""
    from .provider import ALGORITHMS

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for cls in ALGORITHMS:
        alg = cls()
        alg.initAlgorithm()
        path = out / f"{alg.name()}.md"
        path.write_text(help_page(alg), encoding="utf-8")
        written.append(path)
    return written


if __name__ == "__main__":  # pragma: no cover - a maintainer's command
    from qgis.core import QgsApplication

    app = QgsApplication([], False)
    app.initQgis()
    for p in write_help_pages(sys.argv[1] if len(sys.argv) > 1 else "docs/qgis"):
        print(p)
    app.exitQgis()
