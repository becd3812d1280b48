"""One vocabulary across the commands: renamed options keep their old name for one release
as a hidden, deprecated alias that says which name replaces it.

:data:`DEPRECATED_OPTIONS` lists every such alias (command, old name -> new name); the
option walk test (tests/test_option_vocabulary.py) checks that every hidden option is
listed here and that its new name exists on the same command.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import click

__all__ = ["DEPRECATED_OPTIONS", "DEPRECATED_VALUES", "DEPRECATED_COMMANDS", "deprecated_option", "take_alias", "ChoiceWithOld",
           "deprecated_value", "say_deprecated"]

F = TypeVar("F", bound=Callable[..., Any])

#: (command, old option) -> the option that replaces it.
DEPRECATED_OPTIONS: dict[tuple[str, str], str] = {
    ("simulate", "--preset"): "--photon-rate",
    ("simulate", "--beam"): "--beam-strength",
    ("simulate", "--noise-rate"): "--background-rate",
    ("simulate", "--photons"): "--photon-table",
    ("simulate", "--crs"): "--points-crs",
    ("validate", "--crs"): "--table-crs",
    ("blocks", "--k"): "--k-sigma",
    ("blocks", "--atl08"): "--atl08-classes",
    ("blocks", "--profile"): "--plot",
    ("waveforms", "--noise-threshold"): "--k-sigma",
    ("run", "--estimators"): "--preset",
    ("blocks", "--photons"): "--photon-layer",
    ("segments", "--photons"): "--photon-layer",
    ("coregister", "--range"): "--search-range",
    ("validate", "--coregister-range"): "--search-range",
}

#: Old command -> the command that replaces it (hidden, warns when run).
DEPRECATED_COMMANDS: dict[str, str] = {
    "validate-footprints": "validate",
}

#: (command, option, old value) -> the value that replaces it.
DEPRECATED_VALUES: dict[tuple[str, str, str], str] = {
    ("validate", "--reference", "rasters"): "corridor",
    ("run", "--preset", "boreal"): "--photon-rate boreal",
    ("run", "--preset", "temperate"): "--photon-rate temperate",
    ("run", "--preset", "tropical"): "--photon-rate tropical",
}


def _say(text: str) -> None:
    click.echo(f"canopyblocks: warning: {text}", err=True)


def say_deprecated(old: str, new: str) -> None:
    """The one warning line for a deprecated spelling ``old`` replaced by ``new``."""
    _say(f"{old} is deprecated and will be removed; use {new}")


def deprecated_option(old: str, dest: str, **kwargs: Any) -> Callable[[F], F]:
    """A hidden option ``old`` whose value arrives in parameter ``dest`` (None when not
    given); pass it to :func:`take_alias` with the new option's value."""
    kwargs.setdefault("default", None)
    return click.option(old, dest, hidden=True, **kwargs)


def take_alias(new_value: Any, old_value: Any, *, old: str, new: str,
               default: Any = None) -> Any:
    """The value to use: the new option's, or the deprecated alias's (with a warning).

    Both given (whatever their values) is a usage error naming both: which one was
    meant cannot be told.
    """
    if old_value is None or old_value is False or old_value == ():
        return new_value
    if _given(new) or (new_value not in (None, default, False, ())
                       and new_value != old_value):
        raise click.UsageError(f"give {new} only, not also the deprecated {old} (its old "
                               "spelling)")
    _say(f"{old} is deprecated and will be removed; use {new}")
    return old_value


def _given(name: str) -> bool:
    """True when option ``name`` of the running command was given (not its default)."""
    from click.core import ParameterSource

    ctx = click.get_current_context(silent=True)
    if ctx is None:
        return False
    for param in ctx.command.params:
        if name in param.opts and param.name is not None:
            source = ctx.get_parameter_source(param.name)
            return source not in (None, ParameterSource.DEFAULT, ParameterSource.DEFAULT_MAP)
    return False


def deprecated_value(value: Any, *, option: str, old: str, new: str) -> Any:
    """``new`` when ``value`` is the deprecated ``old`` (with a warning), else ``value``."""
    if value == old:
        _say(f"{option} {old} is deprecated and will be removed; use {option} {new}")
        return new
    return value


class ChoiceWithOld(click.Choice):
    """A choice that also takes deprecated values (``old``), not shown in ``--help``;
    the command maps them with :func:`deprecated_value`."""

    def __init__(self, choices: Any, old: Any = ()) -> None:
        super().__init__(list(choices))
        self.old = tuple(old)

    def convert(self, value: Any, param: Any, ctx: Any) -> Any:
        if value in self.old:
            return value
        return super().convert(value, param, ctx)
