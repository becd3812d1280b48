"""Granule and survey arguments of the command line: a local path, or an ``s3://`` /
``https://`` URL; a survey also a folder, a glob pattern, a ``.vpc`` or an ``ept.json``."""

from __future__ import annotations

from typing import Any

import click

__all__ = ["GranuleSource", "SurveySource"]


class GranuleSource(click.Path):
    """``click.Path(exists=...)`` that lets URLs through untouched (the reader fetches them)."""

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> Any:
        from ..workflows.inputs import is_url

        if is_url(value):
            return str(value).strip()
        return super().convert(value, param, ctx)


class SurveySource(click.ParamType):
    """One survey source, passed on as given: the workflows' one resolver
    (:func:`~canopyblocks.workflows.rasters.survey_tiles`) expands folders, patterns and
    ``.vpc`` catalogs and refuses what is missing with the project's own message."""

    name = "survey"

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> Any:
        return str(value).strip()
