"""Click options built from the one vocabulary (:mod:`canopyblocks.options`).

``option("--photon-rate")`` is the table's option as a ``click.option``: its name, kind,
choices, default and help; a command may give its parameter name (``dest``), another
default (listed with its reason in tests/test_option_vocabulary.py) or add a sentence of
help about its own use (``extra_help``), never another meaning.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import click

from ..options import option_spec

__all__ = ["option", "click_type"]

F = TypeVar("F", bound=Callable[..., Any])

_UNSET: Any = object()


def click_type(name: str) -> Any:
    """The click type of the table's option ``name``."""
    spec = option_spec(name)
    if spec.kind == "file":
        return click.Path(dir_okay=False)
    if spec.kind == "folder":
        return click.Path(file_okay=False)
    if spec.kind == "number":
        return float
    if spec.kind == "choice":
        assert spec.choices is not None
        return click.Choice(list(spec.choices))
    return None  # text, crs: strings


def option(name: str, dest: str | None = None, *, default: Any = _UNSET, help: str | None = None,
           extra_help: str = "", type: Any = None, **kwargs: Any) -> Callable[[F], F]:
    """The ``click.option`` of the table's option ``name``.

    ``dest`` (default the table's keyword), ``default`` (default the table's), ``help``
    (replaces the table's sentence: the same meaning, said for this command), ``extra_help``
    (appended), ``type`` (a narrower type of the same kind, e.g. ``click.IntRange``); other
    keywords go to ``click.option``.
    """
    spec = option_spec(name)
    text = f"{help or spec.help} {extra_help}".strip()
    if spec.kind == "switch":
        return click.option(name, dest or spec.keyword, is_flag=True, help=text, **kwargs)
    value = spec.default if default is _UNSET else default
    if spec.multiple:
        kwargs.setdefault("multiple", True)
    if value is not None and not kwargs.get("multiple"):
        kwargs.setdefault("show_default", True)
        kwargs["default"] = value
    elif not kwargs.get("multiple"):
        kwargs["default"] = None
    t = type if type is not None else click_type(name)
    if t is not None:
        kwargs["type"] = t
    return click.option(name, dest or spec.keyword, help=text, **kwargs)
