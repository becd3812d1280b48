"""The plugin's icon and the addresses of its help pages (used by every algorithm)."""

from __future__ import annotations

from pathlib import Path

ICON = Path(__file__).resolve().parent / "icons" / "canopyblocks.svg"


DOCS_URL = "https://github.com/canopyblocks/canopyblocks/blob/main/docs/qgis"


def help_url(alg_id: str) -> str:
    """The web address of algorithm ``alg_id``'s help page."""
    return f"{DOCS_URL}/{alg_id}.md"
