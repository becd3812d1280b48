"""One default for a concept across every front end: the recommended estimators (``atl08``)
and the corridor width of the photons' sensor (ICESat-2 13 m, MABEL 2 m).

Walks every click command, the Python API's signatures and the batch configuration; the
QGIS algorithms are walked by tests/qgis/test_qgis_defaults_walk.py.
"""

from __future__ import annotations

import inspect

import click
import numpy as np
import pytest

import canopyblocks
from canopyblocks.blocks import BlockParams
from canopyblocks.blocks.estimators import (
    PRESET_NAMES,
    PRESETS,
    RECOMMENDED_PRESET,
    Estimators,
    default_estimators,
    estimate_blocks,
    preset,
)
from canopyblocks.cli import cli
from canopyblocks.cli.common import PRESET_CHOICES, WIDTH_HELP
from canopyblocks.errors import InputError
from canopyblocks.photons import PhotonTrack, sensor_of_track
from canopyblocks.reference.sensor_width import SENSOR_WIDTHS, corridor_width

ATL08_LABEL = "noise=atl08,ground=atl08,top=atl08"


def _commands(group: click.Group, prefix: str = "") -> list[tuple[str, click.Command]]:
    out = []
    for name, cmd in group.commands.items():
        out.append((f"{prefix}{name}", cmd))
        if isinstance(cmd, click.Group):
            out += _commands(cmd, f"{prefix}{name} ")
    return out


def _estimator_options(cmd: click.Command) -> list[click.Option]:
    """The visible options whose choices are block-estimator presets."""
    return [p for p in cmd.params if isinstance(p, click.Option) and not p.hidden
            and isinstance(p.type, click.Choice) and "paper" in p.type.choices
            and "atl08" in p.type.choices]


def test_the_recommended_preset_is_atl08_and_the_paper_stays():
    assert RECOMMENDED_PRESET == "atl08"
    assert set(PRESET_CHOICES) == set(PRESET_NAMES) == set(PRESETS)
    assert PRESET_CHOICES[0] == "atl08"
    assert preset("paper").is_paper and preset("paper").name == "paper"
    assert preset().label() == Estimators().label() == ATL08_LABEL
    assert default_estimators().label() == ATL08_LABEL  # MABEL and ICESat-2 alike


def test_every_command_with_estimators_defaults_to_atl08():
    seen = {}
    for name, cmd in _commands(cli):
        for opt in _estimator_options(cmd):
            seen[name] = opt
            assert opt.default == "atl08", (name, opt.opts, opt.default)
            # the same presets everywhere, the default first
            assert tuple(opt.type.choices[:len(PRESET_CHOICES)]) == PRESET_CHOICES, name
            assert "the paper's method" in (opt.help or ""), name
    assert {"blocks", "calibrate", "batch", "run"} <= set(seen), sorted(seen)


def test_every_width_option_defaults_to_the_sensor():
    seen = []
    for name, cmd in _commands(cli):
        for p in cmd.params:
            if isinstance(p, click.Option) and "--width" in p.opts and not p.hidden:
                seen.append(name)
                assert p.default is None, (name, p.default)
                assert "ICESat-2 13" in (p.help or "") and "MABEL 2" in (p.help or ""), name
    assert {"validate", "calibrate", "run", "batch"} <= set(seen), seen
    for sensor, width in SENSOR_WIDTHS.items():
        assert f"{sensor} {width:g}" in WIDTH_HELP


def test_python_api_defaults():
    """Every public function taking ``estimators`` defaults to None (= the recommended),
    and every ``width`` defaults to None (= the sensor's footprint)."""
    from canopyblocks.reference.corridor import block_corridors
    from canopyblocks.validation.block_validation import validate_atl08, validate_blocks
    from canopyblocks.workflows.batch import BatchConfig
    from canopyblocks.workflows.blocks import blocks_from_file, run_blocks
    from canopyblocks.workflows.blocks_granules import blocks_from_granules
    from canopyblocks.workflows.calibrate import (
        calibrate_bias_file,
        calibrate_reference_rasters,
    )
    from canopyblocks.workflows.chain import run_chain
    from canopyblocks.workflows.validate import validate_file

    funcs = {name: getattr(canopyblocks, name) for name in canopyblocks.__all__}
    funcs.update({f.__name__: f for f in (blocks_from_file, run_blocks, calibrate_bias_file,
                                          run_chain, estimate_blocks, validate_blocks,
                                          validate_atl08, validate_file, block_corridors,
                                          calibrate_reference_rasters)})
    n_est = n_width = 0
    for name, f in funcs.items():
        if not callable(f) or inspect.isclass(f):
            continue
        try:
            sig = inspect.signature(f)
        except (TypeError, ValueError):
            continue
        if "estimators" in sig.parameters:
            n_est += 1
            assert sig.parameters["estimators"].default is None, name
        if "width" in sig.parameters and name not in ("simulate_photons",):
            n_width += 1
            assert sig.parameters["width"].default is None, name
    assert n_est >= 5 and n_width >= 5, (n_est, n_width)
    # blocks_from_granules passes its keywords on to blocks_from_file
    assert "estimators" in inspect.signature(blocks_from_file).parameters
    assert callable(blocks_from_granules)
    cfg = BatchConfig()
    assert cfg.preset == "atl08" and cfg.width == 13.0


def _track(track: str = "gt1r") -> PhotonTrack:
    rng = np.random.default_rng(4)
    n = 6000
    s = np.sort(rng.uniform(0, 300, n))
    ground = 100 + 0.01 * s
    canopy = rng.random(n) < 0.5
    h = ground + np.where(canopy, rng.uniform(0, 15, n), rng.normal(0, 0.2, n))
    lat = 45 + s / 111_000
    lon = np.full(n, -100.0)
    return PhotonTrack.from_lonlat(np.arange(n) * 1e-4, lat, lon, h, track=track, s=s)


def test_estimate_and_run_blocks_default_to_atl08():
    from canopyblocks.workflows.blocks import run_blocks

    t = _track()
    params = BlockParams(lengths=(25.0,))
    assert set(estimate_blocks(t, params)["estimators"]) == {ATL08_LABEL}
    blocks, _ = run_blocks([t], params)
    assert set(blocks["estimators"]) == {ATL08_LABEL}
    # the paper's method one option away, its values those of its own engine
    from canopyblocks.blocks import compute_blocks

    paper = estimate_blocks(t, params, preset("paper"))
    engine = compute_blocks(t, params)
    np.testing.assert_array_equal(paper["hmax"].to_numpy(), engine["hmax"].to_numpy())


def test_the_width_rule():
    assert sensor_of_track("gt2l") == "ICESat-2" and sensor_of_track("channel049") == "MABEL"
    assert sensor_of_track("photons") is None
    assert corridor_width(None, ["gt1l", "gt1r"]) == 13.0
    assert corridor_width(None, ["channel001"]) == 2.0
    assert corridor_width(5.0, ["photons"]) == 5.0   # a given width wins
    with pytest.raises(InputError, match="no known sensor.*--width"):
        corridor_width(None, ["photons"], source="t.csv")
    with pytest.raises(InputError, match="footprints differ"):
        corridor_width(None, ["gt1l", "channel001"])
    with pytest.raises(InputError, match="positive"):
        corridor_width(-1.0, ["gt1l"])


def test_corridors_are_as_wide_as_the_footprint():
    """A straight track: each 25 m corridor's area is 25 m x the sensor's footprint."""
    from canopyblocks.reference.corridor import block_corridors

    for track, width in (("gt1r", 13.0), ("channel010", 2.0)):
        blocks = estimate_blocks(_track(track), BlockParams(lengths=(25.0,)),
                                 preset("paper"))
        inner = block_corridors(blocks).geometry.area.to_numpy()[1:-1]
        np.testing.assert_allclose(inner, 25.0 * width, rtol=1e-3)
    unknown = estimate_blocks(_track("photons"), BlockParams(lengths=(25.0,)),
                              preset("paper"))
    with pytest.raises(InputError, match="no known sensor"):
        block_corridors(unknown)
