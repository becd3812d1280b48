"""Bad inputs: every failure is a canopyblocks error naming the file and what is wrong."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from canopyblocks.errors import CanopyBlocksError, FileFormatError, InputError
from canopyblocks.outputs.h5_layouts import Atl03BeamData, write_atl03
from canopyblocks.readers import (
    atl03_beams,
    detect_product,
    file_info,
    mabel_channels,
    open_track,
    read_atl03,
    read_mabel,
)

VEGR = "icesat2/vegr_atl03_clip.h5"
VEGR08 = "icesat2/vegr_atl08_clip.h5"


def test_missing_file(tmp_path):
    p = tmp_path / "nope.h5"
    for fn in (lambda: read_atl03(p, "gt1r"), lambda: read_mabel(p, 1),
               lambda: open_track(p), lambda: file_info(p)):
        with pytest.raises(FileFormatError, match=r"nope\.h5: file does not exist"):
            fn()


def test_not_hdf5(tmp_path):
    p = tmp_path / "fake.h5"
    p.write_text("this is not an HDF5 file\n" * 100)
    with pytest.raises(FileFormatError, match=r"fake\.h5: not an HDF5 file"):
        read_atl03(p, "gt1r")
    with pytest.raises(FileFormatError, match=r"fake\.h5: not an HDF5 file"):
        mabel_channels(p)
    with pytest.raises(FileFormatError, match=r"fake\.h5: not a recognised photon file"):
        open_track(p)


def test_not_hdf5_message_names_the_kind_once(tmp_path):
    """The generic reader says "an HDF5 file", never "an HDF5 HDF5 file"."""
    from canopyblocks.readers._h5 import open_h5

    p = tmp_path / "fake.h5"
    p.write_text("this is not an HDF5 file\n" * 100)
    for target in (p, tmp_path):
        with pytest.raises(FileFormatError) as err, open_h5(target):
            pass
        assert "expected an HDF5 file" in str(err.value)
        assert "HDF5 HDF5" not in str(err.value)
    with pytest.raises(FileFormatError, match="expected an HDF5 ATL03 file"), \
            open_h5(p, "ATL03"):
        pass


@pytest.mark.parametrize("fraction", [0.001, 0.3, 0.9, 0.999])
def test_truncated_hdf5(tmp_path, sample, fraction):
    data = sample(VEGR).read_bytes()
    p = tmp_path / "cut.h5"
    p.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(FileFormatError, match=r"cut\.h5: cannot open as HDF5, the file is "
                                              r"truncated or corrupt"):
        read_atl03(p, "gt1r")
    with pytest.raises(FileFormatError, match=r"cut\.h5"):
        file_info(p)


@pytest.mark.filterwarnings("ignore:.*no usable bckgrd_atlas:canopyblocks.errors.CanopyBlocksWarning")
def test_zeroed_blocks_never_leak_library_errors(tmp_path, sample):
    """Zero 2 KiB at fixed-seed random places: the result is a track or a canopyblocks
    error, never a raw h5py/OSError/KeyError."""
    data = bytearray(sample(VEGR).read_bytes())
    rng = np.random.default_rng(20261122)
    p = tmp_path / "zeroed.h5"
    outcomes = set()
    for _ in range(40):
        d = bytearray(data)
        off = int(rng.integers(0, len(d) - 2048))
        d[off:off + 2048] = bytes(2048)
        p.write_bytes(bytes(d))
        for fn in (lambda: read_atl03(p, "gt1r", atl08=sample(VEGR08)), lambda: file_info(p)):
            try:
                fn()
                outcomes.add("ok")
            except CanopyBlocksError as exc:
                assert "zeroed.h5" in str(exc)
                outcomes.add(type(exc).__name__)
    assert "ok" in outcomes


def test_missing_groups_and_datasets(tmp_path, sample):
    p = tmp_path / "nogeo.h5"
    shutil.copy(sample(VEGR), p)
    with h5py.File(p, "a") as f:
        del f["gt1r/geolocation/segment_ph_cnt"]
    with pytest.raises(FileFormatError, match=r"nogeo\.h5: dataset /gt1r/geolocation/"
                                              r"segment_ph_cnt is missing"):
        read_atl03(p, "gt1r")
    p2 = tmp_path / "noh.h5"
    shutil.copy(sample(VEGR), p2)
    with h5py.File(p2, "a") as f:
        del f["gt1r/heights/h_ph"]
    with pytest.raises(FileFormatError, match=r"noh\.h5: dataset /gt1r/heights/h_ph is missing"):
        read_atl03(p2, "gt1r")
    p3 = tmp_path / "nolat.h5"
    shutil.copy(sample(VEGR), p3)
    with h5py.File(p3, "a") as f:
        del f["gt1r/heights/lat_ph"]
    with pytest.raises(FileFormatError, match=r"nolat\.h5: dataset /gt1r/heights/lat_ph"):
        read_atl03(p3, "gt1r")


def test_corrupt_segment_index(tmp_path, sample):
    p = tmp_path / "badidx.h5"
    shutil.copy(sample(VEGR), p)
    with h5py.File(p, "a") as f:
        beg = f["gt1r/geolocation/ph_index_beg"]
        beg[5] = 99_999
    with pytest.raises(FileFormatError, match=r"badidx\.h5: .*point past the 6809 photons"):
        read_atl03(p, "gt1r")


def test_wrong_product(tmp_path, sample):
    with pytest.raises(FileFormatError, match=r"vegr_atl08_clip\.h5: not an ATL03 file"):
        read_atl03(sample(VEGR08), "gt1r")
    with pytest.raises(FileFormatError, match=r"vegr_atl03_clip\.h5: not a MABEL L2A file"):
        read_mabel(sample(VEGR), 1)
    with pytest.raises(InputError, match=r"vegr_atl08_clip\.h5: is an ATL08 file.*atl08="):
        open_track(sample(VEGR08))
    with pytest.raises(FileFormatError, match=r"vegr_atl03_clip\.h5: not an ATL08 file"):
        read_atl03(sample(VEGR), "gt1r", atl08=sample(VEGR))
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["something/else"] = np.zeros(3)
    with pytest.raises(FileFormatError, match=r"other\.h5: HDF5 file but neither ATL03"):
        detect_product(other)
    with pytest.raises(FileFormatError, match=r"other\.h5: not an ATL03 file"):
        atl03_beams(other)
    las = tmp_path / "cloud.laz"
    las.write_bytes(b"LASF")
    with pytest.raises(FileFormatError, match=r"cloud\.laz: is an airborne lidar point cloud"):
        open_track(las)


def test_beam_errors(sample):
    with pytest.raises(InputError, match=r"vegr_atl03_clip\.h5: beam gt2l is not in this file; "
                                         r"it has gt1r \(weak, 6809 photons\)"):
        read_atl03(sample(VEGR), "gt2l")
    with pytest.raises(InputError, match=r"beam 'gt7x' is not an ATL03 beam; use one of gt1l"):
        read_atl03(sample(VEGR), "gt7x")
    with pytest.raises(InputError, match="channel applies to MABEL files only; this is ATL03"):
        open_track(sample(VEGR), channel=3)
    with pytest.raises(InputError, match=r"bbox \(1, 2, 3\) must be four finite numbers"):
        read_atl03(sample(VEGR), "gt1r", bbox=(1, 2, 3))
    with pytest.raises(InputError, match="lon_min > lon_max"):
        read_atl03(sample(VEGR), "gt1r", bbox=(10, 0, 5, 1))
    with pytest.raises(InputError, match="s_min <= s_max"):
        read_atl03(sample(VEGR), "gt1r", s_range=(10, 5))


@pytest.mark.filterwarnings("ignore:.*no usable bckgrd_atlas:canopyblocks.errors.CanopyBlocksWarning")
def test_atl08_from_another_granule(tmp_path, sample):
    # an ATL03-layout file with the clip's segment ids but other times and RGT
    with h5py.File(sample(VEGR), "r") as f:
        lat = f["gt1r/heights/lat_ph"][:]
        lon = f["gt1r/heights/lon_ph"][:]
    n = lat.size
    s = np.linspace(0, 819.0, n)
    d = Atl03BeamData(np.linspace(1.0, 2.0, n), lat, lon, np.full(n, 2500.0), s)
    p = write_atl03(tmp_path / "sim.h5", {"gt1r": d}, rgt=99, cycle=3,
                    segment_dist_x0=771235 * 20.0)
    with pytest.raises(InputError, match=r"vegr_atl08_clip\.h5 is from RGT 150 cycle 15 but "
                                         r"ATL03 file .*sim\.h5 is from RGT 99 cycle 3"):
        read_atl03(p, "gt1r", atl08=sample(VEGR08))
    p2 = write_atl03(tmp_path / "sim2.h5", {"gt1r": d}, rgt=150, cycle=15,
                     segment_dist_x0=771235 * 20.0)
    with pytest.raises(InputError, match=r"ATL08 file .*vegr_atl08_clip\.h5 does not match: "
                                         r"\d+ of \d+ photons joined"):
        read_atl03(p2, "gt1r", atl08=sample(VEGR08))
