"""MABEL L2A reader on files written here, with plain h5py, from the structure of a real
granule (shared/data/mabel/*.dmr.xml): every channel, dtype and attribute of photon/."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import h5py
import numpy as np
import pyproj
import pytest

from canopyblocks.errors import FileFormatError, InputError, NoUsableDataError
from canopyblocks.readers import (
    file_info,
    format_info,
    mabel_channels,
    open_track,
    read_mabel,
)

DMR = "mabel/mabel_l2a_20110322T165030_005_1.h5.dmr.xml"
NS = {"d": "http://xml.opendap.org/ns/DAP/4.0#"}
DAP = {"Float64": "f8", "Float32": "f4", "Byte": "u1", "UInt16": "u2", "Int32": "i4"}
UTM12 = pyproj.CRS.from_epsg(32612)
SCALE = 1000  # photons written per channel = real count // SCALE


def _dmr_layout(path):
    """{'channel049': {dataset: (dtype, size, attrs)}} for the photon/ group of the DMR."""
    out: dict[str, dict] = {}
    for var in ET.parse(path).getroot():
        attrs = {a.get("name"): a.find("d:Value", NS).text for a in var.findall("d:Attribute", NS)}
        full = attrs.get("fullnamepath", "")
        if not full.startswith("/photon/channel") or var.find("d:Dim", NS) is None:
            continue
        _, _, chan, name = full.split("/")
        size = int(var.find("d:Dim", NS).get("size"))
        keep = {k: v for k, v in attrs.items() if k not in ("origname", "fullnamepath",
                                                             "coordinates")}
        out.setdefault(chan, {})[name] = (DAP[var.tag.split("}")[1]], size, keep)
    return out


def _positions(n, seed, channel, jitter=0.0):
    """Photons along a straight flight line in UTM 12N (Arizona-like), s known."""
    rng = np.random.default_rng(seed + channel)
    s = np.sort(rng.uniform(0, 3000.0, n))
    s[0] = 0.0
    x = 500_000.0 + s * np.cos(np.radians(30)) + (rng.normal(0, jitter, n) if jitter else 0)
    y = 3_800_000.0 + s * np.sin(np.radians(30)) + channel * 2.0
    lon, lat = pyproj.Transformer.from_crs(UTM12, 4326, always_xy=True).transform(x, y)
    t = s / 200.0  # aircraft ~200 m/s, delta_time from the first photon
    elev = 1500.0 + rng.normal(0, 5, n)
    return s, np.asarray(lat), np.asarray(lon), t, elev


@pytest.fixture(scope="module")
def layout(sample):
    return _dmr_layout(sample(DMR))


@pytest.fixture(scope="module")
def mabel_file(tmp_path_factory, layout):
    """A MABEL-layout file with all 24 channels of the real granule, counts / SCALE."""
    path = tmp_path_factory.mktemp("mabel") / "mabel_l2a_test.h5"
    truth = {}
    with h5py.File(path, "w") as f:
        for chan, dsets in layout.items():
            ch = int(chan[len("channel"):])
            n = dsets["elev"][1] // SCALE
            s, lat, lon, t, elev = _positions(n, 11, ch)
            values = {"delta_time": t, "elev": elev, "latitude": lat, "longitude": lon,
                      "flag": np.zeros(n), "photon_id": np.ones(n),
                      "shot_num": np.arange(1, n + 1)}
            for name, (dtype, _, attrs) in dsets.items():
                d = f.create_dataset(f"photon/{chan}/{name}", data=values[name].astype(dtype))
                for k, v in attrs.items():
                    d.attrs[k] = v
            truth[ch] = (s, lat, lon, t, elev.astype("f4").astype("f8"))
    return path, truth


def test_dmr_layout_is_what_the_readme_says(layout):
    assert len(layout) == 24
    assert layout["channel001"]["elev"][1] == 618_679
    assert set(layout["channel049"]) == {"delta_time", "elev", "flag", "latitude",
                                         "longitude", "photon_id", "shot_num"}
    assert layout["channel049"]["elev"][0] == "f4" and layout["channel049"]["flag"][0] == "u1"


def test_channels_and_most(mabel_file, layout):
    path, truth = mabel_file
    chans = mabel_channels(path)
    assert chans == {int(c[7:]): d["elev"][1] // SCALE for c, d in layout.items()}
    most = max(chans, key=chans.get)
    assert most == 44  # 1,915,326 photons in the real granule
    tr = read_mabel(path, "most")
    assert tr.track == "channel044" and len(tr) == chans[44]
    assert open_track(path).track == "channel044"


def test_read_channel_values_and_s(mabel_file):
    path, truth = mabel_file
    s, lat, lon, t, elev = truth[49]
    tr = read_mabel(path, 49, crs=UTM12)
    assert tr.track == "channel049" and tr.vertical_datum == "EPSG:4979"
    np.testing.assert_array_equal(tr.lat, lat)
    np.testing.assert_array_equal(tr.lon, lon)
    np.testing.assert_array_equal(tr.time, t)
    np.testing.assert_array_equal(tr.h, elev)
    np.testing.assert_allclose(tr.s, s, atol=1e-3)  # straight line: s recovered to 1 mm
    assert read_mabel(path, "channel049").track == "channel049"


def test_s_with_footprint_scatter_is_monotone_and_close(tmp_path):
    s, lat, lon, t, elev = _positions(4000, 3, 7, jitter=1.0)
    with h5py.File(tmp_path / "m.h5", "w") as f:
        for name, v in (("delta_time", t), ("elev", elev), ("latitude", lat),
                        ("longitude", lon)):
            f[f"photon/channel007/{name}"] = v
    tr = read_mabel(tmp_path / "m.h5", 7, crs=UTM12)
    assert np.all(np.diff(tr.s) >= 0)
    # 1 m of x noise on a line at 30 deg moves s by cos(30) * noise: std 0.87 m, plus the
    # start offset (s starts at the lowest projected photon)
    order = np.argsort(tr.time, kind="stable")
    d = tr.s[order] - s
    assert 0.75 < np.std(d) < 1.0
    assert abs(np.median(d)) < 5.0


@pytest.mark.parametrize("kind", ["bbox", "s_range"])
def test_subset_equals_posthoc_filter(mabel_file, kind):
    path, _ = mabel_file
    full = read_mabel(path, 49)
    if kind == "bbox":
        lo = np.quantile(full.lon, [0.3, 0.6])
        bbox = (float(lo[0]), -90.0, float(lo[1]), 90.0)
        sub = read_mabel(path, 49, bbox=bbox)
        m = (full.lon >= bbox[0]) & (full.lon <= bbox[2])
    else:
        rng = (500.0, 1200.5)
        sub = read_mabel(path, 49, s_range=rng)
        m = (full.s >= rng[0]) & (full.s <= rng[1])
    assert 0 < m.sum() < len(full) and len(sub) == m.sum()
    for col in ("time", "lat", "lon", "h", "s", "x", "y"):
        np.testing.assert_array_equal(getattr(sub, col), getattr(full, col)[m])


def test_errors_name_file_and_choices(mabel_file, tmp_path):
    path, _ = mabel_file
    with pytest.raises(InputError, match=r"mabel_l2a_test\.h5: channel 17 is not in this file; "
                                         r"it has channels 1 \(618 photons\)"):
        read_mabel(path, 17)
    with pytest.raises(InputError, match="channel 'abc' is not a channel number or 'most'"):
        read_mabel(path, "abc")
    with pytest.raises(NoUsableDataError, match="no photons of channel049 inside bbox"):
        read_mabel(path, 49, bbox=(0, 0, 1, 1))
    with pytest.raises(InputError, match="beam applies to ATL03 files only; this is MABEL"):
        open_track(path, beam="gt1l")
    bad = tmp_path / "nochan.h5"
    with h5py.File(bad, "w") as f:
        f["photon/other/elev"] = np.zeros(3)
    with pytest.raises(FileFormatError, match=r"nochan\.h5: not a MABEL L2A file"):
        mabel_channels(bad)
    broken = tmp_path / "broken.h5"
    with h5py.File(broken, "w") as f:
        f["photon/channel003/elev"] = np.zeros(3, "f4")
        f["photon/channel003/latitude"] = np.zeros(3)
        f["photon/channel003/delta_time"] = np.zeros(3)
    with pytest.raises(FileFormatError, match=r"broken\.h5: dataset /photon/channel003/longitude"
                                              r" is missing"):
        read_mabel(broken, 3)


def test_file_info_mabel(mabel_file):
    path, truth = mabel_file
    info = file_info(path)
    assert info["product"] == "MABEL" and len(info["channels"]) == 24
    assert info["most_photons"] == 44
    lat_all = np.concatenate([v[1] for v in truth.values()])
    lon0, lat0, lon1, lat1 = info["bbox"]
    assert lat0 == pytest.approx(lat_all.min()) and lat1 == pytest.approx(lat_all.max())
    assert "channel049:" in format_info(info)
