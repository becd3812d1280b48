"""Messages that name the real cause, and inputs no longer taken without a word (the third
corpus): time ranges, a footprint too small to hold points, an all-noise track, simulate's
background and telemetry options, a granule given twice, beam strength from the file,
batch tiles in several CRSs."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from canopyblocks.errors import CanopyBlocksWarning, InputError, NoUsableDataError

sys.path.insert(0, str(Path(__file__).resolve().parent))

CLIP = Path("tests/data/icesat2/vegr_atl03_clip.h5")
LAZ = Path("tests/data/als/lasR_bcts_1.laz")


def test_time_range_end_of_day_and_overflowed_year() -> None:
    from canopyblocks.workflows.blocks_granules import parse_utc
    start = parse_utc("2022-04-01", "--time START")
    end = parse_utc("2022-04-01", "--time END", end=True)
    assert start == np.datetime64("2022-04-01T00:00:00", "ns")
    # a granule taken that day at 22:23 lies inside
    assert end == np.datetime64("2022-04-01T23:59:59.999999999", "ns")
    assert parse_utc("2022-04-01T22:00", "--time END", end=True) == \
        np.datetime64("2022-04-01T22:00", "ns")
    with pytest.raises(InputError, match="year 99999 is outside"):
        parse_utc("99999-01-01", "--time END", end=True)


def test_granule_given_twice_is_blocked_once(tmp_path: Path) -> None:
    from canopyblocks.workflows.blocks_granules import blocks_from_granules
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        once = blocks_from_granules([CLIP], None, output=tmp_path / "a.csv")
    with pytest.warns(CanopyBlocksWarning, match="given more than once"):
        twice = blocks_from_granules([CLIP, str(CLIP.resolve())], None,
                                     output=tmp_path / "b.csv")
    assert len(twice) == len(once) > 0


@pytest.mark.parametrize("kw", [{"diameter": 0.001}, {"cut": 0.01}])
def test_a_footprint_too_small_holds_no_points(kw: dict) -> None:
    from canopyblocks.reference import FootprintReferenceParams
    with pytest.raises(InputError, match="holds no airborne points"):
        FootprintReferenceParams(**kw)


def test_all_noise_track_says_so_with_the_count() -> None:
    from canopyblocks.blocks import BlockParams
    from canopyblocks.blocks.estimators import Estimators, estimate_blocks
    from test_atl08_classifier import synthetic
    track, _ = synthetic(3e6, lambda s: 100.0 + 0 * s, per_shot=0.0, seed=9, length=600.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CanopyBlocksWarning)
        with pytest.raises(NoUsableDataError,
                           match=rf"all {len(track):,} photons were classed noise"):
            estimate_blocks(track, BlockParams(),
                            Estimators(noise="atl08", ground="paper", top="paper"))


def test_simulate_background_and_window_options(tmp_path: Path) -> None:
    from canopyblocks.cli import main
    from canopyblocks.simulate import SimParams
    with pytest.raises(InputError, match=r"--background-rate\) 1000 MHz"):
        SimParams(background_rate_mhz=1000.0)
    SimParams(background_rate_mhz=100.0)  # 100 MHz: taken (and named when classified)
    with pytest.raises(InputError, match=r"--telemetry-window\) 100000 m"):
        SimParams(telemetry_window=1e5)
    rc = main(["simulate", str(LAZ), "--azimuth", "0", "--day", "--night",
               "-o", str(tmp_path / "s.h5")])
    assert rc != 0 and not (tmp_path / "s.h5").exists()


def test_the_bundled_clip_is_a_weak_beam() -> None:
    import h5py

    from canopyblocks.readers import atl03_beams
    from canopyblocks.workflows.blocks import track_strengths
    with h5py.File(CLIP) as f:  # what the file says, read independently
        assert f["gt1r"].attrs["atlas_beam_type"] in (b"weak", "weak")
        assert int(f["orbit_info/sc_orient"][0]) == 0  # backward: the left beams strong
    assert atl03_beams(CLIP)[0].strength == "weak"
    assert track_strengths(CLIP, ["gt1r"]) == {"gt1r": "weak"}


def test_batch_takes_tiles_in_several_crs(tmp_path: Path, caplog) -> None:  # noqa: ANN001
    import laspy
    import pyproj

    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import SimParams, SimTrack, simulate_photons
    from canopyblocks.simulate.writers import write_simulation_atl03
    from canopyblocks.workflows.batch.units import find_units, tile_index
    pts = read_las(LAZ)
    sim = simulate_photons(pts, SimTrack.line(885120.0, 629170.0, 885120.0, 629690.0),
                           SimParams(), seed=3)
    granule = write_simulation_atl03(sim, tmp_path / "g.h5")
    # the same tile in UTM 9N: a second CRS
    src = laspy.read(LAZ)
    x, y = pyproj.Transformer.from_crs(pts.crs, "EPSG:32609", always_xy=True).transform(
        np.asarray(src.x), np.asarray(src.y))
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = [0.01, 0.01, 0.01]
    hdr.offsets = [float(x.min()), float(y.min()), 0.0]
    hdr.add_crs(pyproj.CRS("EPSG:32609"))
    out = laspy.LasData(hdr)
    out.x, out.y, out.z = x, y, np.asarray(src.z)
    out.classification = np.asarray(src.classification)
    utm = tmp_path / "utm.las"
    out.write(utm)
    tiles = tile_index([LAZ, utm])
    assert len({t.crs_wkt for t in tiles}) == 2
    with caplog.at_level("WARNING"):
        units = find_units([str(granule)], tiles)
    assert len(units) == 1 and len(units[0].tiles) == 1
    assert "crosses tiles in 2 CRSs" in caplog.text


def test_footprint_options_with_the_corridor_reference_are_warned(tmp_path: Path) -> None:
    import rasterio
    from rasterio.transform import from_origin

    from canopyblocks.errors import CanopyBlocksError
    from canopyblocks.reference import FootprintReferenceParams
    from canopyblocks.workflows.blocks import blocks_from_file
    from canopyblocks.workflows.validate import validate_file
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        blocks_from_file(CLIP, None, output=tmp_path / "b.gpkg")
    dtm = tmp_path / "dtm.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PendingDeprecationWarning)  # affine's, not ours
        with rasterio.open(dtm, "w", driver="GTiff", width=4, height=4, count=1,
                           dtype="float32", crs="EPSG:32613",
                           transform=from_origin(0, 4, 1, 1)) as r:
            r.write(np.zeros((1, 4, 4), np.float32))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(CanopyBlocksError):  # the raster lies elsewhere
            validate_file(tmp_path / "b.gpkg", tmp_path / "r.gpkg", reference="corridor",
                          dtm=dtm, dsm_max=dtm, dsm_p90=dtm,
                          footprint_params=FootprintReferenceParams(diameter=20.0))
    assert any(issubclass(w.category, CanopyBlocksWarning)
               and "apply to the footprint reference only" in str(w.message) for w in caught)
