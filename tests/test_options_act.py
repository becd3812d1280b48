"""Options act or are refused, never accepted and ignored: the estimator options of
``blocks`` walked over every preset, an old and a new spelling of one option given together,
the ``blocks`` command ``calibrate`` prints, ``validate --diameter`` on GEDI footprints,
``waveforms`` naming the option it refuses as the user spells it.

The independent check of "acts": a block table computed with the option differs from the
one computed without it; of "refused": exit status 2 and one line naming the option.
"""

from __future__ import annotations

import re
import shlex
import warnings
from pathlib import Path

import geopandas as gpd
import numpy as np
import pytest

from canopyblocks.cli import main
from canopyblocks.options import ESTIMATOR_PRESETS

ATL03 = "icesat2/vegr_atl03_clip.h5"

#: The estimator options of ``blocks`` and a value other than the default.
ESTIMATOR_OPTIONS = {"--k-sigma": "1.5", "--top-cutoff": "0.4", "--ground-cutoff": "0.3"}


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
    code = main(["-q", *args])
    return code, capsys.readouterr().err


def error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("canopyblocks: error:")]
    assert len(lines) == 1, err
    return lines[0]


def heights(path: Path) -> np.ndarray:
    b = gpd.read_file(path, layer="blocks")
    return b[["top", "ground", "hmax"]].to_numpy(float)


def uses(preset: str, option: str) -> bool:
    """Which part of a block an option sets, read from the preset's parts."""
    from canopyblocks.blocks.estimators import preset as named

    est = named(preset)
    return {"--k-sigma": est.noise == "sigma", "--top-cutoff": est.top == "paper",
            "--ground-cutoff": est.ground == "paper"}[option]


@pytest.fixture(scope="module")
def baselines(tmp_path_factory: pytest.TempPathFactory, sample) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("baselines")
    out = {}
    for preset in ESTIMATOR_PRESETS:
        if any(uses(preset, o) for o in ESTIMATOR_OPTIONS):
            p = folder / f"{preset}.gpkg"
            assert main(["-q", "blocks", str(sample(ATL03)), "--beam", "gt1r", "--length", "25",
                         "--preset", preset, "-o", str(p)]) == 0
            out[preset] = p
    return out


@pytest.mark.parametrize("preset", ESTIMATOR_PRESETS)
@pytest.mark.parametrize("option", sorted(ESTIMATOR_OPTIONS))
def test_an_estimator_option_acts_or_is_refused(preset, option, baselines, sample, tmp_path,
                                                capsys) -> None:
    out = tmp_path / "b.gpkg"
    code, err = run(capsys, "blocks", str(sample(ATL03)), "--beam", "gt1r", "--length", "25",
                    "--preset", preset, option, ESTIMATOR_OPTIONS[option], "-o", str(out))
    if not uses(preset, option):
        assert code == 2, err
        line = error_line(err)
        assert option in line and "--preset paper" in line, line
        assert not out.exists()
        return
    assert code == 0, err
    before, after = heights(baselines[preset]), heights(out)
    assert before.shape == after.shape
    changed = ~np.isclose(before, after, equal_nan=True)
    assert changed.any(), f"{option} {ESTIMATOR_OPTIONS[option]} accepted but changed nothing"


def test_the_default_estimators_refuse_the_cut_offs_by_name(sample, tmp_path, capsys) -> None:
    """What a new user tries first: the cut-offs without a preset (the atl08 default)."""
    code, err = run(capsys, "blocks", str(sample(ATL03)), "--length", "25", "--top-cutoff",
                    "0.2", "--ground-cutoff", "0.3", "-o", str(tmp_path / "b.csv"))
    assert code == 2
    line = error_line(err)
    assert "--top-cutoff and --ground-cutoff set the paper's top and ground windows" in line
    assert "--preset atl08 (the default) replaces them: use --preset paper" in line
    assert "vegr_atl03_clip.h5" in line


@pytest.mark.parametrize("args, fix", [
    (["--noise", "conf", "--k-sigma", "3"],
     "--noise conf replaces it: drop --noise conf for --k-sigma to act, or drop it"),
    (["--top-estimator", "p98", "--top-cutoff", "0.9"],
     "--top-estimator p98 replaces it: drop --top-estimator p98 for --top-cutoff to act"),
    (["--ground-estimator", "surface", "--ground-cutoff", "0.2"],
     "--ground-estimator surface replaces it: drop --ground-estimator surface for "
     "--ground-cutoff to act"),
])
def test_with_preset_paper_the_refusal_names_the_option_that_replaced_the_part(
        args, fix, sample, tmp_path, capsys) -> None:
    """--preset paper is given: the advice names the part's option, not the preset, and
    no name the help does not show (such as 'paper+')."""
    out = tmp_path / "b.csv"
    code, err = run(capsys, "blocks", str(sample(ATL03)), "--beam", "gt1r", "--preset",
                    "paper", *args, "-o", str(out))
    assert code == 2, err
    line = error_line(err)
    assert fix in line, line
    assert "paper+" not in line and "--preset paper" not in line and "Invalid value" not in line
    assert "Traceback" not in err and not out.exists()


@pytest.mark.parametrize("args, new, old", [
    (["blocks", "{atl03}", "--preset", "paper", "--k", "1.5", "--k-sigma", "2.5"],
     "--k-sigma", "--k"),
    (["blocks", "{atl03}", "--preset", "paper", "--k", "2.5", "--k-sigma", "2.5"],
     "--k-sigma", "--k"),
    (["run", "{tile}", "--simulate", "--preset", "boreal", "--photon-rate", "tropical"],
     "--photon-rate", "--preset boreal"),
    (["run", "{tile}", "--simulate", "--preset", "boreal", "--photon-rate", "temperate"],
     "--photon-rate", "--preset boreal"),
])
def test_old_and_new_spelling_together_are_refused(args, new, old, sample, tmp_path,
                                                   capsys) -> None:
    """Even when the new one equals its default (which used to let the old one win)."""
    filled = [a.format(atl03=sample(ATL03), tile=sample("als/lidR_Topography.laz"))
              for a in args]
    code, err = run(capsys, *filled, "-o", str(tmp_path / "out"))
    assert code == 2, err
    line = error_line(err)
    assert f"give {new} only, not also the deprecated {old}" in line, line
    assert not (tmp_path / "out").exists()


def test_the_old_spelling_alone_still_works_with_a_warning(sample, tmp_path, capsys) -> None:
    a, b = tmp_path / "old.gpkg", tmp_path / "new.gpkg"
    code, err = run(capsys, "blocks", str(sample(ATL03)), "--beam", "gt1r", "--length", "25",
                    "--preset", "paper", "--k", "1.5", "-o", str(a))
    assert code == 0 and "--k is deprecated" in err
    assert main(["-q", "blocks", str(sample(ATL03)), "--beam", "gt1r", "--length", "25",
                 "--preset", "paper", "--k-sigma", "1.5", "-o", str(b)]) == 0
    np.testing.assert_array_equal(heights(a), heights(b))


def test_waveforms_names_the_option_as_the_user_spelled_it(sample, tmp_path, capsys) -> None:
    import zipfile

    with zipfile.ZipFile(sample("gedi/GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.zip")
                         ) as z:
        name = z.namelist()[0]
        z.extract(name, tmp_path)
    code, err = run(capsys, "waveforms", str(tmp_path / name), "--k-sigma", "4",
                    "-o", str(tmp_path / "f.gpkg"))
    assert code == 2
    line = error_line(err)
    assert "--k-sigma applies to flash-lidar (ESFL) and dual-wavelength files only" in line
    assert "--noise-threshold" not in line and name in line


def test_waveforms_on_a_missing_file_says_it_is_missing(tmp_path, capsys) -> None:
    code, err = run(capsys, "waveforms", str(tmp_path / "x.h5"), "--k-sigma", "4",
                    "-o", str(tmp_path / "f.gpkg"))
    assert code == 2
    line = error_line(err)
    assert "does not exist" in line and "GEDI" not in line, line


def test_calibrate_prints_the_blocks_command_that_gives_the_calibrated_blocks(
        sample, tmp_path, capsys, monkeypatch) -> None:
    """Following the printed command gives the blocks of the calibrated cut-offs (the paper's
    method with them: computed here through the API), not the default estimators' blocks."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from badinputs.base import _make_blocks, _make_rasters
    from canopyblocks import BlockParams
    from canopyblocks.blocks.estimators import preset
    from canopyblocks.workflows.blocks import read_tracks, run_blocks
    from canopyblocks.workflows.calibrate import calibrate_reference_rasters

    tile = sample("als/lidR_Topography.laz")
    r = _make_rasters(tile, tmp_path / "rasters")["paths"]
    _make_blocks(tile, tmp_path / "sim")
    photons = tmp_path / "sim" / "sim_atl03.h5"
    monkeypatch.chdir(tmp_path)
    assert main(["calibrate", str(photons), "--dtm", str(r["dtm"]), "--dsm-max",
                 str(r["dsm_max"]), "--dsm-p90", str(r["dsm_p90"]), "--offset", "0", "--width",
                 "13", "--length", "25"]) == 0
    err = capsys.readouterr().err
    lines = [ln.strip() for ln in err.splitlines() if ln.strip().startswith("canopyblocks blocks")]
    assert len(lines) == 1, err
    words = shlex.split(lines[0])
    assert "--preset" in words and words[words.index("--preset") + 1] == "paper"
    assert main(["-q", *words[1:]]) == 0
    got = gpd.read_file(tmp_path / "blocks_25m.gpkg", layer="blocks")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a cut-off on the grid's edge: said, not wrong
        cal = calibrate_reference_rasters(
            str(photons), BlockParams(lengths=(25.0,)), dtm=r["dtm"], dsm_max=r["dsm_max"],
            dsm_p90=r["dsm_p90"], width=13.0, offset=0.0)
    tracks = read_tracks(str(photons))
    want, _ = run_blocks(tracks, cal.params, estimators=preset("paper"))
    np.testing.assert_allclose(got[["top", "ground", "hmax"]].to_numpy(float),
                               want[["top", "ground", "hmax"]].to_numpy(float), equal_nan=True)
    top = float(re.search(r"--top-cutoff (\S+)", lines[0]).group(1))
    assert top == pytest.approx(float(cal.table["top_cutoff"].iloc[0]))


@pytest.mark.parametrize("setting, option", [({"k_sigma": 3.0}, "--k-sigma"),
                                             ({"top_cutoff": 0.3}, "--top-cutoff"),
                                             ({"ground_cutoff": 0.3}, "--ground-cutoff")])
def test_the_python_api_refuses_what_the_default_estimators_ignore(setting, option,
                                                                   sample) -> None:
    """The same rule at the Python door (and so for QGIS): the paper's settings with the
    recommended estimators are refused, never ignored."""
    from canopyblocks import BlockParams
    from canopyblocks.blocks.estimators import estimate_blocks
    from canopyblocks.errors import InputError
    from canopyblocks.readers import read_atl03

    track = read_atl03(sample(ATL03), "gt1r")
    with pytest.raises(InputError) as info:
        estimate_blocks(track, BlockParams(lengths=(25.0,), **setting))
    msg = str(info.value)
    assert option in msg and "--preset atl08 (the default)" in msg and "--preset paper" in msg, msg
