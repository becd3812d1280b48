"""One name, one meaning, one default: a walk over every command's options.

Fails on a concept spelled two ways (a synonym group with more than one visible
spelling), on a name with two meanings (kinds differ: a switch in one command, a file
or a number in another; choices from disjoint vocabularies), on one name with two
defaults unless the difference is listed below with its reason, and on a hidden option
that is not a listed deprecated alias of a visible option of the same command.
"""

from __future__ import annotations

from collections import defaultdict

import click
import pytest
from click.testing import CliRunner

from canopyblocks.blocks.estimators import PRESETS
from canopyblocks.cli import cli
from canopyblocks.cli.vocabulary import DEPRECATED_OPTIONS, DEPRECATED_VALUES

#: Concepts and their spellings: at most one spelling may be visible across the CLI.
SYNONYMS: dict[str, tuple[str, ...]] = {
    "estimator preset": ("--preset", "--estimators", "--estimator-preset"),
    "photon rate of a simulation": ("--photon-rate", "--rate-preset"),
    "co-registration search range": ("--search-range", "--range", "--coregister-range"),
    "write the photon layer": ("--photon-layer", "--with-photons"),
    "beam strength of a simulation": ("--beam-strength", "--strength"),
    "corridor width": ("--width", "--corridor-width"),
    "block length": ("--length", "--lengths", "--block-length"),
    "vertical CRS of the photons": ("--photon-vcrs", "--photon-vertical-crs"),
    "footprint diameter": ("--diameter", "--footprint-diameter"),
}

#: Values of one option that name one thing: at most one may be offered (not deprecated).
VALUE_SYNONYMS: dict[str, tuple[str, ...]] = {
    "--reference": ("corridor", "rasters", "dsm"),
}

#: Names whose default differs by command, and why (each entry is debt or physics).
DEFAULT_DIFFERS: dict[str, str] = {
    "--width": "the corridor: 2 m (seed corridor) in validate, the footprint (13 m) in batch, "
               "by the photons' source in run and calibrate -- still to be made one default",
    "--diameter": "a sensor's footprint: 13 m ICESat-2 in run, 22 m GEDI in "
                  "validate-footprints, by --sensor in simulate",
    "--length": "blocks take several lengths (default 10/25/50 or 25 by command); segments "
                "takes ATL08's 100 m segment",
    "--azimuth": "simulate derives the track from the survey when not given; run's 0 is north",
    "--photon-vcrs": "calibrate reads the photon file's own datum when not given",
}


def _kind(p: click.Option) -> str:
    if p.is_flag:
        return "switch"
    t = p.type
    if isinstance(t, click.Path):
        return "path"
    if isinstance(t, click.Choice):
        return "choice"
    if isinstance(t, (click.types.FloatParamType, click.types.IntParamType,
                      click.FloatRange, click.IntRange)):
        return "number"
    return "text"


def _default(p: click.Option) -> object:
    d = p.default
    if d is None or repr(d).startswith("Sentinel") or d == () or d is False:
        return None
    return d


def _walk():
    """(command, option name, click.Option) for every option of every command."""
    for name, cmd in sorted(cli.commands.items()):
        for p in cmd.params:
            if isinstance(p, click.Option):
                for o in p.opts + p.secondary_opts:
                    if o.startswith("--"):
                        yield name, o, p


def test_the_walk_sees_every_command() -> None:
    names = {c for c, _, _ in _walk()}
    assert {"blocks", "run", "simulate", "validate", "calibrate", "batch"} <= names


def test_one_spelling_per_concept() -> None:
    visible = defaultdict(set)
    for cmd, o, p in _walk():
        if not p.hidden:
            visible[o].add(cmd)
    bad = {concept: [f"{s} ({', '.join(sorted(visible[s]))})" for s in spellings
                     if s in visible]
           for concept, spellings in SYNONYMS.items()}
    bad = {k: v for k, v in bad.items() if len(v) > 1}
    assert not bad, f"a concept spelled two ways: {bad}"


def test_one_meaning_per_name() -> None:
    kinds = defaultdict(dict)
    choices = defaultdict(dict)
    for cmd, o, p in _walk():
        if p.hidden:
            continue
        kinds[o][cmd] = _kind(p)
        if isinstance(p.type, click.Choice):
            old = {v for (c, opt, v) in DEPRECATED_VALUES if c == cmd and opt == o}
            choices[o][cmd] = set(p.type.choices) - old
    two = {o: k for o, k in kinds.items() if len(set(k.values())) > 1}
    assert not two, f"one name, two kinds (a switch here, a value there): {two}"
    for o, by_cmd in choices.items():  # one vocabulary: commands may offer fewer values
        if len(by_cmd) > 1:
            assert set.intersection(*by_cmd.values()), f"{o}: disjoint vocabularies {by_cmd}"
    for o, spellings in VALUE_SYNONYMS.items():
        offered = set().union(*choices[o].values()) if choices[o] else set()
        assert len(offered & set(spellings)) <= 1, f"{o}: one value spelled two ways {offered}"
    assert choices["--preset"], "--preset (the estimator preset) is gone"
    for cmd, values in choices["--preset"].items():
        assert values <= set(PRESETS), (cmd, values - set(PRESETS))


def test_one_default_per_name() -> None:
    defaults = defaultdict(dict)
    for cmd, o, p in _walk():
        if not p.hidden and not p.is_flag:
            defaults[o][cmd] = _default(p)
    # no default (None) means "decided by the input" and agrees with any stated one
    differ = {o: d for o, d in defaults.items()
              if len({repr(v) for v in d.values() if v is not None}) > 1}
    unexplained = {o: d for o, d in differ.items() if o not in DEFAULT_DIFFERS}
    assert not unexplained, f"one name, several defaults: {unexplained}"


def test_hidden_options_are_listed_deprecated_aliases() -> None:
    visible = defaultdict(set)
    for cmd, o, p in _walk():
        if not p.hidden:
            visible[cmd].add(o)
    for cmd, o, p in _walk():
        if p.hidden:
            new = DEPRECATED_OPTIONS.get((cmd, o))
            assert new is not None, f"{cmd} {o}: hidden but not a listed deprecated alias"
            assert new in visible[cmd], f"{cmd} {o}: replaced by {new}, which {cmd} lacks"
    for cmd, o in DEPRECATED_OPTIONS:
        assert o in {x for c, x, _ in _walk() if c == cmd}, (cmd, o)


@pytest.mark.parametrize(("cmd", "old"), sorted(DEPRECATED_OPTIONS))
def test_help_shows_only_the_new_names(cmd: str, old: str) -> None:
    r = CliRunner().invoke(cli, [cmd, "--help"])
    assert r.exit_code == 0, r.output
    assert DEPRECATED_OPTIONS[(cmd, old)] in r.output
    assert f"{old} " not in r.output.replace(DEPRECATED_OPTIONS[(cmd, old)], "")


def test_an_old_name_still_works_and_says_its_new_name(sample, tmp_path) -> None:
    """``blocks --photons`` (now --photon-layer) writes the photon layer, with one warning."""
    import pyogrio

    out = tmp_path / "b.gpkg"
    r = CliRunner().invoke(cli, ["blocks", str(sample("icesat2/vegr_atl03_clip.h5")),
                                 "--beam", "gt1r", "--length", "25", "--photons",
                                 "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert {n for n, _ in pyogrio.list_layers(out)} == {"blocks", "photons"}
    assert r.output.count("--photons is deprecated and will be removed; use --photon-layer") == 1


def test_old_and_new_name_given_differently_is_a_usage_error(tmp_path) -> None:
    r = CliRunner().invoke(cli, ["coregister", str(tmp_path / "p.h5"), "--dtm",
                                 str(tmp_path / "d.tif"), "--range", "5", "--search-range",
                                 "10", "-o", str(tmp_path / "o.json")])
    assert r.exit_code == 2
    assert "give --search-range only, not also the deprecated --range" in r.output


def test_a_deprecated_value_is_mapped_to_its_new_name() -> None:
    from canopyblocks.cli.vocabulary import deprecated_value

    for (cmd, option, old), new in DEPRECATED_VALUES.items():
        if cmd == "validate":
            assert deprecated_value(old, option=option, old=old, new=new) == new
    r = CliRunner().invoke(cli, ["validate", "--help"])
    assert "[corridor|atl08|footprint]" in r.output and "|rasters" not in r.output


def test_hidden_commands_are_listed_deprecated_ones() -> None:
    from canopyblocks.cli.vocabulary import DEPRECATED_COMMANDS

    hidden = {n for n, c in cli.commands.items() if c.hidden}
    assert hidden == set(DEPRECATED_COMMANDS)
    for new in DEPRECATED_COMMANDS.values():
        assert new in cli.commands and not cli.commands[new].hidden
    assert "validate-footprints" not in CliRunner().invoke(cli, ["--help"]).output


# ---- the one table (canopyblocks.options): every front end reads its names from it ---------

_CLICK_KIND = {"file": "path", "folder": "path", "number": "number", "choice": "choice",
               "switch": "switch", "crs": "text", "text": "text"}

#: The names the vocabulary was made for: each is declared once, in the table.
NAMED = ("--photons", "--photon-table", "--photon-layer", "--crs", "--points-crs",
         "--table-crs", "--preset", "--photon-rate", "--atl08", "--atl08-classes", "--plot",
         "--plots", "--k-sigma", "--length", "--width")


def test_the_named_options_are_declared_once_in_the_table() -> None:
    from canopyblocks.options import OPTIONS

    assert set(NAMED) <= set(OPTIONS), set(NAMED) - set(OPTIONS)
    keywords = [o.keyword for o in OPTIONS.values()]
    assert len(keywords) == len(set(keywords)), "one Python keyword, two options"
    qgis = [o.qgis_name for o in OPTIONS.values()]
    assert len(qgis) == len(set(qgis)), "one QGIS parameter name, two options"
    for o in OPTIONS.values():
        assert o.meaning and o.help, o.name
        if o.kind == "choice":
            assert o.choices and (o.default is None or o.default in o.choices), o.name


def test_every_command_option_of_a_table_name_has_its_meaning() -> None:
    """The same kind and (a subset of) the same choices as the table says, in every
    command; ``--help`` then shows one meaning per name."""
    from canopyblocks.options import OPTIONS

    seen = defaultdict(set)
    for cmd, o, p in _walk():
        if p.hidden or o not in OPTIONS:
            continue
        spec = OPTIONS[o]
        seen[o].add(cmd)
        assert _kind(p) == _CLICK_KIND[spec.kind], (cmd, o, _kind(p), spec.kind)
        if spec.kind == "choice":
            assert set(p.type.choices) <= set(spec.choices), (cmd, o, p.type.choices)
    assert {"run", "simulate", "validate", "blocks"} <= set().union(*seen.values())
    assert seen["--photons"] == {"run"}, "--photons is the input photon file of run only"
    assert "simulate" in seen["--photon-table"] and "simulate" in seen["--points-crs"]
    assert seen["--atl08-classes"] == {"blocks"} and "blocks" not in seen["--atl08"]


def test_the_preset_list_and_default_are_declared_once() -> None:
    from canopyblocks.blocks.estimators import PRESET_NAMES, PRESETS, RECOMMENDED_PRESET
    from canopyblocks.options import ESTIMATOR_PRESETS, OPTIONS
    from canopyblocks.options import RECOMMENDED_PRESET as TABLE_DEFAULT

    assert PRESET_NAMES is ESTIMATOR_PRESETS and set(PRESETS) == set(ESTIMATOR_PRESETS)
    assert RECOMMENDED_PRESET == TABLE_DEFAULT == OPTIONS["--preset"].default == "atl08"
    for cmd, o, p in _walk():
        if o == "--preset" and not p.hidden:
            assert tuple(p.type.choices) == ESTIMATOR_PRESETS, cmd
            assert p.default == "atl08", cmd


def test_run_preset_is_the_estimator_set_and_the_old_rate_still_works(tmp_path) -> None:
    r = CliRunner().invoke(cli, ["run", "--help"])
    assert "boreal" not in r.output.split("--preset")[1].split("--calibration")[0]
    from canopyblocks.cli.vocabulary import ChoiceWithOld

    run = cli.commands["run"]
    p = next(p for p in run.params if p.name == "estimator_preset")
    assert isinstance(p.type, ChoiceWithOld) and p.type.convert("boreal", p, None) == "boreal"


def test_the_python_keyword_of_a_table_name_means_the_same() -> None:
    """A keyword named like a table option takes its values: ``photon_rate`` the ecosystem
    rates (SimParams, run_chain), ``preset`` the estimator sets (no more a photon rate)."""
    import dataclasses
    import inspect

    from canopyblocks.options import OPTIONS
    from canopyblocks.simulate.params import SimParams
    from canopyblocks.workflows import chain, validate
    from canopyblocks.workflows.batch import runner

    fields = {f.name: f for f in dataclasses.fields(SimParams)}
    assert fields["photon_rate"].default == OPTIONS["--photon-rate"].default
    assert fields["preset"].default is None  # the deprecated spelling only
    by_keyword = {o.keyword: o for o in OPTIONS.values()}
    checked = 0
    for fn in (chain.run_chain, validate.validate_file, *(
            v for v in vars(runner).values() if inspect.isfunction(v))):
        for name, par in inspect.signature(fn).parameters.items():
            spec = by_keyword.get(name)
            if spec is None or spec.kind != "choice" or not isinstance(par.default, str):
                continue
            assert par.default in spec.choices, (fn.__name__, name, par.default)
            checked += 1
    assert checked >= 1
    assert "photon_rate" in inspect.signature(chain.run_chain).parameters


RENAMED = {("simulate", "--photons"), ("simulate", "--crs"), ("validate", "--crs"),
           ("blocks", "--k"), ("blocks", "--atl08"), ("blocks", "--profile"),
           ("waveforms", "--noise-threshold")}


def test_a_renamed_option_is_listed_deprecated_and_in_the_changelog() -> None:
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "CHANGELOG.md").read_text(encoding="utf-8")
    for cmd, old in RENAMED:
        new = DEPRECATED_OPTIONS[(cmd, old)]
        assert f"{cmd} {old}" in text and new in text, f"CHANGELOG: {cmd} {old} -> {new}"


@pytest.mark.parametrize(("cmd", "old"), sorted(RENAMED))
def test_a_renamed_option_still_works_with_one_warning(cmd: str, old: str, tmp_path) -> None:
    """The old spelling reaches the command (it fails later, on the missing input file,
    not on the option) and says its new name once."""
    value = [] if old in ("--photon-layer",) else [str(tmp_path / "x.png") if old ==
                                                   "--profile" else "3"]
    args = {"simulate": [str(tmp_path / "no.laz"), "--azimuth", "0", "-o",
                         str(tmp_path / "o.h5")],
            "validate": [str(tmp_path / "no.csv"), "-o", str(tmp_path / "o.gpkg")],
            "blocks": [str(tmp_path / "no.h5"), "-o", str(tmp_path / "o.gpkg")],
            "waveforms": [str(tmp_path / "no.h5"), "-o", str(tmp_path / "o.gpkg")]}[cmd]
    r = CliRunner().invoke(cli, [cmd, *args, old, *value])
    new = DEPRECATED_OPTIONS[(cmd, old)]
    assert f"{old} is deprecated and will be removed; use {new}" in r.output, r.output
    assert "no such option" not in r.output.lower()


def test_the_workflow_parameter_sets_are_the_rooms_classes() -> None:
    from canopyblocks.blocks import BlockParams
    from canopyblocks.simulate.params import SimParams
    from canopyblocks.workflows import params

    assert params.BlockParams is BlockParams and params.SimParams is SimParams
    for name in params.__all__:
        assert getattr(params, name) is not None, name
