"""Exactness of the fast ATL03 file path (not its speed: that lives in bench/).

The fast path projects photons with a per-block local affine map
(:func:`canopyblocks.geo.to_metric_local_affine`), reads columns straight into their
final arrays, picks the UTM zone without sorting and sorts only out-of-order tracks.
Every result is checked against an independent oracle: pyproj's own Transformer on
every photon, ``np.median``, plain h5py reads.
"""

from __future__ import annotations

import h5py
import numpy as np
import pyproj
import pytest

from canopyblocks import geo
from canopyblocks.geo import _median, to_metric_local_affine, utm_crs_for
from canopyblocks.outputs.h5_layouts import Atl03BeamData, write_atl03
from canopyblocks.readers import read_atl03
from canopyblocks.readers._h5 import open_h5

TOL = 1e-4  # metres; the brief asks for < 1 mm against the full pyproj projection
VEGR = "icesat2/vegr_atl03_clip.h5"
HARMONY = "icesat2/harmony_ATL03_gt1l.h5"


def _pyproj(lon: np.ndarray, lat: np.ndarray, epsg: int) -> tuple[np.ndarray, np.ndarray]:
    tr = pyproj.Transformer.from_crs(4326, epsg, always_xy=True)
    x, y = tr.transform(np.asarray(lon, float), np.asarray(lat, float))
    return np.asarray(x), np.asarray(y)


def _track(n: int, lat0: float, lon0: float, dlat_per_m: float, dlon_per_m: float,
           per_m: float, seed: int, jitter_deg: float = 2e-6) -> tuple[np.ndarray, np.ndarray]:
    """Photons along a straight lon/lat line, ``per_m`` per metre, with footprint jitter."""
    rng = np.random.default_rng(seed)
    s = np.sort(rng.random(n)) * (n / per_m)
    lat = lat0 + s * dlat_per_m + rng.normal(0.0, jitter_deg, n)
    lon = lon0 + s * dlon_per_m + rng.normal(0.0, jitter_deg, n)
    return lon, lat


def _check(lon: np.ndarray, lat: np.ndarray, epsg: int, fast: float = 0.25,
           **kw: object) -> float:
    """Fast path vs pyproj on every photon.  ``fast``: pyproj itself projected fewer
    than this fraction of the photons, so the affine map is what is being tested
    (0 = no such check)."""
    seen = []
    real = geo._transform

    def spy(tr, a, b):  # counts the points pyproj projects; the real transform runs
        seen.append(np.size(a))
        return real(tr, a, b)

    geo._transform = spy
    try:
        x, y, crs = to_metric_local_affine(lon, lat, pyproj.CRS.from_epsg(epsg), **kw)
    finally:
        geo._transform = real
    assert crs.to_epsg() == epsg
    if fast:
        assert sum(seen) < fast * lon.size, (sum(seen), lon.size)
    xe, ye = _pyproj(lon, lat, epsg)
    fin = np.isfinite(xe) & np.isfinite(ye)
    # where pyproj gives inf/NaN the fast path gives exactly the same
    np.testing.assert_array_equal(x[~fin], xe[~fin])
    np.testing.assert_array_equal(y[~fin], ye[~fin])
    err = float(np.max(np.hypot(x[fin] - xe[fin], y[fin] - ye[fin]), initial=0.0))
    assert err < TOL, err
    return err


@pytest.mark.parametrize(
    ("lat0", "lon0", "dlat", "dlon", "epsg", "fast"),
    [
        (41.5, -106.57, 9.0e-6, 1.0e-7, 32613, 0.25),  # ICESat-2 heading north, Wyoming
        (41.5, -107.9, 9.0e-6, -2.0e-7, 32613, 0.25),  # 2.9 deg from the central meridian
        (41.5, -99.5, 9.0e-6, 1.0e-7, 32613, 0.25),  # 5.5 deg outside its zone (k ~ 1.004)
        (41.5, -106.57, 1.0e-7, 1.2e-5, 32613, 0.25),  # heading east (shorter blocks needed)
        (-33.9, 151.2, -9.0e-6, 1.0e-7, 32756, 0.25),  # southern hemisphere
        (0.0005, 10.0, -9.0e-6, 0.0, 32632, 0.25),  # crossing the equator
        (85.0, -40.0, 9.0e-6, 1.0e-7, 3413, 0.25),  # polar stereographic north
        (88.0, -106.57, 1.0e-7, 2.5e-4, 3413, 0.5),  # turning latitude: heading east at 88 N
        (-86.0, 120.0, 1.0e-7, -1.0e-4, 3031, 0.25),  # Antarctic, heading west
        (72.0, 20.0, 9.0e-6, 3.0e-6, 32634, 0.25),  # Scandinavia, oblique
    ],
)
def test_affine_projection_matches_pyproj(lat0, lon0, dlat, dlon, epsg, fast):
    lon, lat = _track(200_000, lat0, lon0, dlat, dlon, per_m=15.0, seed=7)
    _check(lon, lat, epsg, fast)


@pytest.mark.parametrize("block", [16, 64, 256, 1024, 4096])
def test_affine_projection_any_block_size(block):
    lon, lat = _track(150_001, 41.5, -106.57, 9.0e-6, 1.0e-7, per_m=15.0, seed=3)
    _check(lon, lat, 32613, block=block)


def test_affine_projection_sparse_and_scattered_points():
    # a weak beam at night: one photon per 40 m -> blocks are long, refined or exact
    lon, lat = _track(80_000, 41.5, -106.57, 9.0e-6, 1.0e-7, per_m=1 / 40, seed=4)
    _check(lon, lat, 32613, fast=0)
    # no track at all: random points over a UTM zone
    rng = np.random.default_rng(5)
    _check(rng.uniform(-108, -102, 100_000), rng.uniform(30, 60, 100_000), 32613,
           fast=0)


def test_affine_projection_antimeridian_nan_inf_and_out_of_domain():
    lon, lat = _track(120_000, 70.0, 179.99, 1.0e-7, 2.0e-5, per_m=15.0, seed=6)
    lon = ((lon + 180.0) % 360.0) - 180.0  # jumps from +180 to -180 inside the track
    assert lon.max() > 179.99 and lon.min() < -179.9
    lat[1000] = np.nan
    lon[5000:5003] = np.inf
    lat[70_000] = 95.0  # not a latitude: pyproj gives inf
    _check(lon, lat, 3413, fast=0)
    _check(lon[:60_000], lat[:60_000], 32601, fast=0)


def test_affine_projection_small_input_is_pyproj_itself():
    lon, lat = _track(5_000, 41.5, -106.57, 9.0e-6, 1.0e-7, per_m=15.0, seed=8)
    x, y, _ = to_metric_local_affine(lon, lat, pyproj.CRS.from_epsg(32613))
    xe, ye = _pyproj(lon, lat, 32613)
    np.testing.assert_array_equal(x, xe)
    np.testing.assert_array_equal(y, ye)


@pytest.mark.parametrize(("rel", "beam", "fast"), [
    (VEGR, "gt1r", 0.25),  # forest, 41.5 N
    (HARMONY, "gt1l", 0),  # sea ice at 87.3 N, the track turning east: mostly refined/exact
])
def test_affine_projection_on_real_photons(sample, rel, beam, fast):
    with h5py.File(sample(rel), "r") as f:
        lat = f[beam]["heights"]["lat_ph"][:]
        lon = f[beam]["heights"]["lon_ph"][:]
    epsg = utm_crs_for(lon, lat).to_epsg()
    for block in (16, 64, 256):
        _check(lon, lat, epsg, fast, min_photons=0, block=block)
    _check(lon, lat, epsg, fast, min_photons=0)


def _old_utm_epsg(lon: np.ndarray, lat: np.ndarray) -> int:
    """The zone rule written out with np.median of the finite photons."""
    ok = np.isfinite(lon) & np.isfinite(lat)
    lon_c, lat_c = float(np.median(lon[ok])), float(np.median(lat[ok]))
    if lat_c > 84.0:
        return 3413
    if lat_c < -80.0:
        return 3031
    lon_c = ((lon_c + 180.0) % 360.0) - 180.0
    zone = int(np.floor((lon_c + 180.0) / 6.0)) % 60 + 1
    return (32600 if lat_c >= 0 else 32700) + zone


def test_utm_zone_equals_median_rule():
    rng = np.random.default_rng(11)
    for _ in range(400):
        n = int(rng.choice([1, 2, 7, 1000, 250_001]))
        c, cl = rng.uniform(-180.0, 180.0), rng.uniform(-92.0, 92.0)
        w = float(rng.choice([1e-6, 0.01, 1.0, 5.0, 50.0]))
        # degrees WGS84 (utm_crs_for refuses longitudes beyond +-180)
        lon = np.clip(c + rng.normal(0.0, w, n), -180.0, 180.0)
        lat = np.clip(cl + rng.normal(0.0, w, n), -90.0, 90.0)
        if rng.random() < 0.3:
            lon = np.round(lon / 6.0) * 6.0  # exactly on zone edges
        if rng.random() < 0.2:
            lat = np.round(lat / 4.0) * 4.0  # on 0, 84, -80
        if rng.random() < 0.1 and n > 2:
            lon[0] = np.nan
        assert utm_crs_for(lon, lat).to_epsg() == _old_utm_epsg(lon, lat)


def test_median_equals_numpy():
    rng = np.random.default_rng(12)
    for n in (200_000, 200_001, 1_000_003, 2_000_000):
        for a in (rng.random(n), np.sort(rng.normal(size=n)), np.round(rng.random(n) * 5),
                  np.full(n, 2.5), np.r_[np.zeros(n // 2), np.ones(n - n // 2)],
                  np.r_[np.full(n - 3, 7.0), [1e300, -1e300, 0.0]]):
            assert _median(a) == float(np.median(a))


# ------------------------------------------------------------------ the reader itself
def _write(path, n: int, seed: int, disorder_m: float = 0.0) -> None:
    rng = np.random.default_rng(seed)
    s = np.sort(rng.random(n)) * (n / 15.0)
    lat = 41.5 + s * 9.0e-6 + rng.normal(0.0, 2e-6, n)
    lon = -106.57 + s * 1.0e-7
    h = 2400.0 + rng.normal(0.0, 5.0, n)
    conf = rng.integers(-1, 5, n).astype(np.int8)
    write_atl03(path, {"gt1l": Atl03BeamData(delta_time=s / 7000.0, lat=lat, lon=lon, h=h,
                                             s=s, signal_conf=conf,
                                             extra={"truth": rng.random(n)})},
                segment_dist_x0=4_600_000.0)
    if disorder_m:  # real granules: dist_ph_along scatters, s is locally out of order
        with h5py.File(path, "r+") as f:
            d = f["gt1l/heights/dist_ph_along"]
            d[...] = d[()] + rng.uniform(-disorder_m, disorder_m, n).astype(np.float32)


def _raw(path) -> dict[str, np.ndarray]:
    """Plain h5py: every column in file order, s = segment_dist_x + dist_ph_along."""
    with h5py.File(path, "r") as f:
        g = f["gt1l"]
        cnt = g["geolocation/segment_ph_cnt"][()]
        beg = g["geolocation/ph_index_beg"][()]
        dist_x = g["geolocation/segment_dist_x"][()]
        hts = g["heights"]
        n = hts["h_ph"].shape[0]
        s = np.empty(n)
        along = hts["dist_ph_along"][()].astype(np.float64)
        for b, c, d in zip(beg, cnt, dist_x):  # a loop over segments: the oracle
            if c > 0:
                s[b - 1:b - 1 + c] = d + along[b - 1:b - 1 + c]
        return {"time": hts["delta_time"][()], "lat": hts["lat_ph"][()],
                "lon": hts["lon_ph"][()], "h": hts["h_ph"][()].astype(np.float64), "s": s,
                "signal_conf": hts["signal_conf_ph"][()][:, 0],
                "truth": g["canopyblocks_truth/truth"][()]}


@pytest.mark.parametrize("disorder_m", [0.0, 0.1, 1.5])  # 0.1: sorted in windows
@pytest.mark.filterwarnings("ignore:.*no usable bckgrd_atlas:canopyblocks.errors.CanopyBlocksWarning")
def test_read_atl03_fast_path_equals_plain_h5py(tmp_path, disorder_m):
    path = tmp_path / "a.h5"
    _write(path, 150_000, seed=21, disorder_m=disorder_m)
    raw = _raw(path)
    order = np.argsort(raw["s"], kind="stable")
    if disorder_m:
        assert np.count_nonzero(np.diff(raw["s"]) < 0) > 10_000
    tr = read_atl03(path, "gt1l")
    assert len(tr) == 150_000
    for k in ("time", "lat", "lon", "h", "s", "signal_conf"):
        np.testing.assert_array_equal(getattr(tr, k), raw[k][order], err_msg=k)
    np.testing.assert_array_equal(tr.extra["truth"], raw["truth"][order])
    assert tr.crs.to_epsg() == 32613
    xe, ye = _pyproj(tr.lon, tr.lat, 32613)
    assert np.max(np.hypot(tr.x - xe, tr.y - ye)) < TOL
    # a subset and a signal-confidence filter give the same photons as the masks
    sub = read_atl03(path, "gt1l", s_range=(4_600_000.0 + 2000.0, 4_600_000.0 + 6000.0),
                     min_signal_conf=2)
    m = (raw["s"][order] >= 4_602_000.0) & (raw["s"][order] <= 4_606_000.0) \
        & (raw["signal_conf"][order] >= 2)
    np.testing.assert_array_equal(sub.time, raw["time"][order][m])
    np.testing.assert_array_equal(sub.signal_conf, raw["signal_conf"][order][m])


def test_h5_direct_reads_equal_h5py(tmp_path):
    path = tmp_path / "d.h5"
    rng = np.random.default_rng(31)
    with h5py.File(path, "w") as f:
        f["f4"] = rng.random(100_003).astype(np.float32)
        f["i4"] = rng.integers(-5, 5, 100_003).astype(np.int32)
        f["be"] = rng.random(1000).astype(">f8")
        f["c5"] = rng.integers(-2, 5, (3_000_001, 5)).astype(np.int8)
    with h5py.File(path, "r") as g, open_h5(path) as f:
        np.testing.assert_array_equal(f.read("f4", dtype=np.float64),
                                      g["f4"][()].astype(np.float64))
        np.testing.assert_array_equal(f.read("f4", np.s_[17:99_000], dtype=np.float64),
                                      g["f4"][17:99_000].astype(np.float64))
        assert f.read("f4", np.s_[5:5], dtype=np.float64).shape == (0,)
        np.testing.assert_array_equal(f.read("i4", np.s_[-10:], dtype=np.int64),
                                      g["i4"][-10:].astype(np.int64))
        np.testing.assert_array_equal(f.read("i4", dtype=np.int8), g["i4"][()].astype(np.int8))
        np.testing.assert_array_equal(f.read("be"), g["be"][()])
        np.testing.assert_array_equal(f.read_column("c5", 3, 2_999_999, 0),
                                      g["c5"][3:2_999_999, 0])
        np.testing.assert_array_equal(f.read_column("c5", 0, 10, 4, np.int16),
                                      g["c5"][0:10, 4].astype(np.int16))


@pytest.mark.parametrize(("lat0", "lon0"), [(41.5, -106.57), (41.5, -108.0), (-0.0001, 10.0),
                                            (84.0, 20.0), (-80.0005, 0.0), (60.0, 179.5)])
def test_affine_projection_default_crs_is_the_median_zone(lat0, lon0):
    # tracks that straddle a zone edge, the equator, 84 N, 80 S or the antimeridian
    lon, lat = _track(100_003, lat0, lon0, -9.0e-6, 2.0e-5, per_m=15.0, seed=9)
    lon = ((lon + 180.0) % 360.0) - 180.0
    lat[-1] = np.nan  # in the last partial block
    expect = _old_utm_epsg(lon, lat)
    x, y, crs = to_metric_local_affine(lon, lat)
    assert crs.to_epsg() == expect
    xe, ye = _pyproj(lon, lat, expect)
    ok = np.isfinite(xe)
    assert np.max(np.hypot(x[ok] - xe[ok], y[ok] - ye[ok])) < TOL
    np.testing.assert_array_equal(x[~ok], xe[~ok])


def test_affine_projection_default_crs_when_block_middles_mislead():
    # every block's middle photon lies in UTM zone 13, most photons in zone 12
    n = 100_000
    lon = np.full(n, -111.0) + np.arange(n) * 1e-9
    lon[8::16] = -105.0
    lat = 41.5 + np.arange(n) * 1e-8
    x, y, crs = to_metric_local_affine(lon, lat, block=16)
    assert crs.to_epsg() == _old_utm_epsg(lon, lat) == 32612
    xe, ye = _pyproj(lon, lat, 32612)
    assert np.max(np.hypot(x - xe, y - ye)) < TOL


def test_stable_order_equals_numpy_stable_argsort():
    from canopyblocks.photons import stable_order

    rng = np.random.default_rng(41)
    base = 4.6e6 + np.sort(rng.random(200_000)) * 13_000.0
    cases = [
        base + rng.uniform(-1.5, 1.5, base.size),  # real ATL03: locally shuffled
        np.round(base + rng.uniform(-1.5, 1.5, base.size)),  # many ties: stability
        np.r_[base[:1000], 0.0, -0.0, 5.0, 0.0],  # zeros of both signs
        np.r_[base[:1000], -3.0, 2.0],  # negative values
        np.r_[base[:1000], np.nan, 2.0, np.inf],  # NaN and inf
        np.r_[np.inf, base[:1000], np.inf, 1e-310],  # +inf and a subnormal, all > 0
    ]
    for s in cases:
        np.testing.assert_array_equal(stable_order(s), np.argsort(s, kind="stable"))


def test_h5_direct_reads_fall_back_and_fail_cleanly(tmp_path):
    from canopyblocks.errors import FileFormatError

    path = tmp_path / "e.h5"
    with h5py.File(path, "w") as f:
        f["empty"] = h5py.Empty("f4")
        f["one_d"] = np.arange(10, dtype=np.int8)
        f["strided"] = np.arange(20.0)
    with open_h5(path) as f:
        with pytest.raises(FileFormatError, match="one_d"):
            f.read_column("one_d", 0, 5, 0)
        np.testing.assert_array_equal(f.read("strided", np.s_[2:12:3]), np.arange(2.0, 12, 3))
        assert f.read("empty") is not None
