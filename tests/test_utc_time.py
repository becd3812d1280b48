"""UTC beside delta_time, checked against the products' own time statements: the real
ATL03 file's METADATA/Extent range and the GEDI granule's start time in its name."""

from __future__ import annotations

import h5py
import numpy as np

from canopyblocks.readers.utc_time import utc_from_delta_time


def test_atl03_photons_fall_in_the_granule_time_range_its_metadata_states(sample) -> None:
    path = sample("icesat2/harmony_ATL03_gt1l.h5")
    with h5py.File(path, "r") as f:
        ext = f["METADATA/Extent"].attrs
        begin = np.datetime64(ext["rangeBeginningDateTime"].decode().rstrip("Z"), "ns")
        end = np.datetime64(ext["rangeEndingDateTime"].decode().rstrip("Z"), "ns")
        dt = f["gt1l/heights/delta_time"][:]
    utc = utc_from_delta_time(dt)
    assert not np.isnat(utc).any()
    assert begin <= utc.min() and utc.max() <= end, (utc.min(), utc.max(), begin, end)


def test_the_missions_epoch_and_out_of_era_times() -> None:
    # delta_time 0 is the epoch itself; fractions of a second are kept to the nanosecond
    got = utc_from_delta_time([0.0, 0.5, np.nan, -3.2e8])
    assert got[0] == np.datetime64("2018-01-01T00:00:00", "ns")
    assert got[1] == np.datetime64("2018-01-01T00:00:00.5", "ns")
    assert np.isnat(got[2]) and np.isnat(got[3])  # before 2017-01-01: not this clock


def test_gedi_footprints_have_utc_inside_their_orbit(gedi_l1b, tmp_path) -> None:
    """The granule name GEDI01_B_2019108080338_O01964 says the orbit started on
    2019-04-18 (day 108) at 08:03:38 UTC; an orbit lasts about 92 minutes."""
    from canopyblocks.workflows.waveforms import footprints_from_l1b

    fp, _ = footprints_from_l1b(gedi_l1b, beams=["BEAM0101"], workers=1)
    utc = fp["time_utc"].to_numpy("datetime64[ns]")
    start = np.datetime64("2019-04-18T08:03:38", "ns")
    assert not np.isnat(utc).any()
    assert (utc >= start).all() and (utc <= start + np.timedelta64(93, "m")).all()
    assert list(fp.columns[-2:]) == ["time_utc", "geometry"]
    out = tmp_path / "fp.gpkg"  # a GeoPackage reads back the same times (no '08:21:60')
    fp.to_file(out, layer="footprints")
    import geopandas as gpd

    back = gpd.read_file(out, layer="footprints")["time_utc"]
    back = back.dt.tz_localize(None) if back.dt.tz is not None else back
    np.testing.assert_array_equal(back.to_numpy("datetime64[ns]"), utc)
    # the same instants as delta_time, to the millisecond the layer keeps
    d = (utc - utc[0]).astype("timedelta64[ns]").astype(np.int64) / 1e9
    np.testing.assert_allclose(d, fp["time"] - fp["time"].iloc[0], atol=1.001e-3)


def test_a_simulated_file_has_no_utc(tmp_path) -> None:
    from canopyblocks.readers.utc_time import file_counts_from_sdp_epoch

    with h5py.File(tmp_path / "s.h5", "w") as f:
        f.attrs["simulated"] = "canopyblocks GEDI waveform simulation"
    assert not file_counts_from_sdp_epoch(tmp_path / "s.h5")
    assert file_counts_from_sdp_epoch(tmp_path / "nope.h5")


def test_photon_layer_has_utc_inside_the_granule_range(sample, tmp_path) -> None:
    """blocks --photon-layer on the real ATL03 file: time_utc beside time, every photon
    inside the range its METADATA states."""
    import geopandas as gpd

    from canopyblocks.cli import main

    path = sample("icesat2/harmony_ATL03_gt1l.h5")
    out = tmp_path / "b.gpkg"
    assert main(["-q", "blocks", str(path), "--length", "25", "--photon-layer",
                 "-o", str(out)]) == 0
    ph = gpd.read_file(out, layer="photons")
    cols = list(ph.columns)
    assert cols[cols.index("time") + 1] == "time_utc"
    t = ph["time_utc"]
    t = (t.dt.tz_localize(None) if t.dt.tz is not None else t).to_numpy("datetime64[ns]")
    with h5py.File(path, "r") as f:
        ext = f["METADATA/Extent"].attrs
        begin = np.datetime64(ext["rangeBeginningDateTime"].decode().rstrip("Z"), "ns")
        end = np.datetime64(ext["rangeEndingDateTime"].decode().rstrip("Z"), "ns")
    assert len(t) and not np.isnat(t).any()
    assert begin - np.timedelta64(1, "ms") <= t.min() and t.max() <= end


def test_files_canopyblocks_wrote_have_no_utc(tmp_path) -> None:
    """An ATL03-layout file canopyblocks wrote counts from its first shot: no UTC, and
    --time refuses it rather than dating it 2018-01-01."""
    import pytest

    from canopyblocks.errors import InputError
    from canopyblocks.readers.utc_time import file_counts_from_sdp_epoch
    from canopyblocks.workflows.blocks_granules import granule_time_span

    p = tmp_path / "sim.h5"
    with h5py.File(p, "w") as f:
        f.attrs["description"] = ("ATL03-layout photons written by canopyblocks (simulated "
                                  "or converted); not a NASA product")
        f["gt1r/heights/delta_time"] = np.array([0.0, 1.0])
    assert not file_counts_from_sdp_epoch(p)
    with pytest.raises(InputError, match="leave --time out"):
        granule_time_span(p)
