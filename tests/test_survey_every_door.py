"""What one door of a survey refuses, every door refuses: the checks live in the resolver.

A tile whose header misplaces its points, a `.vpc` naming a missing tile, an output CRS whose
metre is not a ground metre, and the calibration tiles given under another name.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest

from canopyblocks.errors import CRSError, FileFormatError

sys.path.insert(0, str(Path(__file__).parent))
from badinputs.survey_corpus import in_feet, move_header  # noqa: E402

ALS = Path(__file__).parent / "data" / "als"


def test_a_misplaced_header_is_refused_by_the_resolver(tmp_path: Path) -> None:
    """`validate --points` and `calibrate --points` resolve their survey with survey_tiles,
    as `run`, `batch` and `rasters` do: a tile moved 5 km by its header is refused there."""
    from canopyblocks.workflows.rasters import survey_tiles

    folder = tmp_path / "survey"
    folder.mkdir()
    shutil.copy(ALS / "lasR_bcts_1.laz", folder / "a.laz")
    moved = Path(shutil.copy(ALS / "lasR_bcts_2.laz", folder / "b.laz"))
    assert [p.name for p in survey_tiles(folder)] == ["a.laz", "b.laz"]
    move_header(moved, 5000.0, 0.0)
    with pytest.raises(FileFormatError) as exc:
        survey_tiles(folder)
    assert str(moved) in str(exc.value) and "its header says" in str(exc.value)
    assert "256 of its first 256 points lie outside" in str(exc.value)


def test_a_tile_in_feet_is_refused_before_any_word_of_a_working_crs(tmp_path: Path) -> None:
    """rasters and run refuse a survey in feet first: no warning that the rasters would be
    made in UTM (which its refusal then contradicts)."""
    import warnings

    from canopyblocks.workflows.rasters import make_survey_rasters
    from canopyblocks.workflows.survey import working_crs

    feet = in_feet(ALS / "lasR_bcts_1.laz", tmp_path / "feet.laz")
    for call in (lambda: make_survey_rasters([feet], tmp_path / "out", backend="serial"),
                 lambda: working_crs([feet])):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with pytest.raises(CRSError) as exc:
                call()
        msg = str(exc.value)
        assert msg.startswith(f"{feet}: ") and "feet are not supported" in msg, msg
        assert "convert the tile to metres" in msg
        assert [str(w.message) for w in caught] == []
    assert not (tmp_path / "out").exists()


def test_a_vpc_naming_a_missing_tile_names_the_vpc(tmp_path: Path) -> None:
    from canopyblocks.workflows.rasters import survey_tiles

    shutil.copy(ALS / "lasR_bcts_1.laz", tmp_path / "one.laz")
    feature = {"type": "Feature", "assets": {"data": {"href": "./one.laz"}}}
    missing = {"type": "Feature", "assets": {"data": {"href": "./two.laz"}}}
    vpc = tmp_path / "survey.vpc"
    vpc.write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    assert [p.name for p in survey_tiles(vpc)] == ["one.laz"]
    vpc.write_text(json.dumps({"type": "FeatureCollection", "features": [feature, missing]}))
    with pytest.raises(FileFormatError) as exc:
        survey_tiles(vpc)
    msg = str(exc.value)
    assert str(vpc) in msg and "./two.laz" in msg and "does not exist" in msg


@pytest.mark.parametrize("crs", ["EPSG:3857", "EPSG:3395"])
def test_an_output_crs_in_mercator_is_refused(tmp_path: Path, crs: str) -> None:
    """1 m of Web Mercator at 50.7 N is 0.63 m on the ground: refused, not used as metres."""
    from canopyblocks.reference.rasters import make_reference_rasters

    with pytest.raises(CRSError) as exc:
        make_reference_rasters([ALS / "lasR_bcts_1.laz"], tmp_path / "out", crs=crs)
    assert "Mercator" in str(exc.value) and "UTM" in str(exc.value)
    assert not (tmp_path / "out" / "dtm.tif").exists()


def test_the_calibration_tiles_are_recognised_by_their_points(tmp_path: Path) -> None:
    """The 'fitted on these tiles' caveat follows the points, not the names: a renamed copy
    is named, innocent names are not."""
    from canopyblocks.workflows.chain.glossary import training_caveat

    copy = Path(shutil.copy(ALS / "lasR_bcts_2.laz", tmp_path / "bcts_2.laz"))
    assert "bcts_2 (= lasR_bcts_2)" in training_caveat([copy])
    for name in ("a.laz", "tracks.laz", "night.laz", "survey/1.laz"):
        assert training_caveat([tmp_path / name]) == "", name
    other = Path(shutil.copy(ALS / "lidR_MixedConifer.laz", tmp_path / "lasR_x.laz"))
    assert training_caveat([other]) == ""
