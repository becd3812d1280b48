"""The Python API's door, the calls of the third corpus that raised foreign exceptions
(TypeError, AttributeError, KeyError, ValueError from deep inside): each is answered with
the project's own one-line error naming what was received, or -- where the misuse is a
valid call in another form (a list for an array) -- gives the right result."""

from __future__ import annotations

import dataclasses
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_api_door import _batch, _refused, _track  # noqa: E402

CLIP = "tests/data/icesat2/vegr_atl03_clip.h5"
LAZ = "tests/data/als/lasR_bcts_1.laz"


def test_gedi_reader_door(gedi_l1b: Path) -> None:
    from canopyblocks.readers import read_gedi_l1b
    assert "None" in _refused(read_gedi_l1b, None, "BEAM0101")
    assert "lon_min" in _refused(read_gedi_l1b, gedi_l1b, "BEAM0101",
                                      bbox=("a", "b", "c", "d"))


def test_waveform_batch_from_lists_is_the_same_batch() -> None:
    from canopyblocks import process_waveforms
    from canopyblocks.waveforms.batch import WaveformBatch
    b = _batch()
    kw = {f.name: getattr(b, f.name) for f in dataclasses.fields(b)}
    as_lists = WaveformBatch(**{k: v.tolist() if isinstance(v, np.ndarray) else v
                                for k, v in kw.items()})
    assert as_lists.shot_number.dtype == np.uint64 and as_lists.waveforms.dtype == np.float32
    a, c = process_waveforms(b), process_waveforms(as_lists)
    np.testing.assert_array_equal(a["ground"].to_numpy(), c["ground"].to_numpy())
    assert "waveforms" in _refused(WaveformBatch, **{**kw, "waveforms": "abc"})
    assert "progress" in _refused(process_waveforms, b, progress="x")


def test_footprint_validation_door() -> None:
    from canopyblocks import footprint_reference, process_waveforms, read_las, validate_footprints
    fp = process_waveforms(_batch())
    assert "points" in _refused(validate_footprints, fp, None)
    assert "params" in _refused(validate_footprints, fp, LAZ, params={"cut": 1})
    las = read_las(LAZ)
    # lon/lat of the tile (BC, EPSG:3005) given as x/y in metres
    assert "degrees" in _refused(footprint_reference, las, np.array([-127.62, -127.61]),
                                 np.array([50.661, 50.662]))


def test_calibration_and_batch_door(tmp_path: Path) -> None:
    from canopyblocks import fit_bias_calibration, run_batch
    res = pd.DataFrame({"track": ["gt1r"] * 8, "length": [100.0] * 8, "block": range(8),
                        "hmax": [20.0] * 8, "h90": [15.0] * 8, "ref_hmax": [19.0] * 8,
                        "ref_h90": [14.0] * 8, "use": [True] * 8})
    assert "strengths" in _refused(fit_bias_calibration, res, strengths="strong")
    assert "BatchConfig" in _refused(run_batch, [CLIP], [LAZ], tmp_path / "b", {"offset": 0})
    assert not (tmp_path / "b").exists()


def test_blocks_doors(tmp_path: Path) -> None:
    from canopyblocks import blocks_from_file, classify_photons, preset
    from canopyblocks.readers.utc_time import utc_from_delta_time
    from canopyblocks.workflows.blocks_granules import blocks_from_granules
    t = _track()
    t.background = "x"  # type: ignore[assignment]
    assert "BackgroundRate" in _refused(classify_photons, t)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = blocks_from_file(CLIP, None, estimators=preset("atl08"))  # None: the defaults
    assert len(r.blocks) > 0
    assert "(start, end)" in _refused(blocks_from_granules, [CLIP], None,
                                      output=tmp_path / "g.csv", time_range=("2022-04-01",))
    assert "seconds" in _refused(utc_from_delta_time, ["a"])


def test_waveform_elevations_in_feet_are_refused() -> None:
    from canopyblocks import process_waveforms
    from canopyblocks.waveforms.batch import WaveformBatch
    b = _batch()
    kw = {f.name: getattr(b, f.name) for f in dataclasses.fields(b)}
    ok = process_waveforms(b)
    assert np.isfinite(ok["ground"]).all()  # the metric batch: processed
    feet = WaveformBatch(**{**kw, "elev_bin0": b.elev_bin0 / 0.3048,
                            "elev_lastbin": b.elev_lastbin / 0.3048})
    assert "feet" in _refused(process_waveforms, feet)
    far = WaveformBatch(**{**kw, "elev_bin0": b.elev_bin0 + 1e6,
                           "elev_lastbin": b.elev_lastbin + 1e6})
    assert "outside any Earth surface" in _refused(process_waveforms, far)
