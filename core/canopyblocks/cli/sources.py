"""Granule arguments of the command line: a local path, or an ``s3://`` / ``https://`` URL."""

from __future__ import annotations

from typing import Any

import click

__all__ = ["GranuleSource"]


class GranuleSource(click.Path):
    """``click.Path(exists=...)`` that lets URLs through untouched (the reader fetches them)."""

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> Any:
        from ..workflows.inputs import is_url

        if is_url(value):
            return str(value).strip()
        return super().convert(value, param, ctx)
