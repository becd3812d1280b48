"""ATL03 reader (+ ATL08 join) on the real sample granules in shared/data/icesat2.

Expected numbers come from shared/data/README.md and from independent
recomputations written here with plain h5py and Python loops over segments.
"""

from __future__ import annotations

import logging

import h5py
import numpy as np
import pytest

from canopyblocks.errors import InputError, NoUsableDataError
from canopyblocks.readers import (
    BeamInfo,
    atl03_beams,
    file_info,
    format_info,
    open_track,
    read_atl03,
)
from canopyblocks.readers._h5 import H5File

VEGR = "icesat2/vegr_atl03_clip.h5"
VEGR08 = "icesat2/vegr_atl08_clip.h5"
HARMONY = "icesat2/harmony_ATL03_gt1l.h5"


def _oracle(path, beam):
    """Per photon (file order): s, segment id, 1-based index in segment; by a loop over
    segments using segment_ph_cnt (photons are stored segment after segment)."""
    with h5py.File(path, "r") as f:
        g = f[beam]["geolocation"]
        cnt = g["segment_ph_cnt"][:]
        dist_x = g["segment_dist_x"][:]
        seg_id = g["segment_id"][:]
        along = f[beam]["heights"]["dist_ph_along"][:]
        n = f[beam]["heights"]["h_ph"].shape[0]
    s = np.empty(n)
    sid = np.empty(n, np.int64)
    idx = np.empty(n, np.int64)
    row = 0
    for k in range(cnt.size):  # loop over segments: an oracle, not library code
        for j in range(int(cnt[k])):
            s[row] = dist_x[k] + float(along[row])
            sid[row] = seg_id[k]
            idx[row] = j + 1
            row += 1
    assert row == n
    return s, sid, idx


@pytest.fixture(scope="module")
def vegr_track(sample):
    return read_atl03(sample(VEGR), "gt1r")


def test_vegr_beams_and_counts(sample):
    beams = atl03_beams(sample(VEGR))
    assert beams == [BeamInfo("gt1r", "weak", 6809, 2)]
    with h5py.File(sample(VEGR), "r") as f:
        assert f["gt1r/geolocation/segment_id"].shape == (41,)  # README: 41 segments


def test_vegr_track_matches_readme_facts(vegr_track):
    tr = vegr_track
    assert len(tr) == 6809
    assert tr.track == "gt1r"
    assert tr.vertical_datum == "EPSG:4979"
    assert tr.crs.to_epsg() == 32613  # 106.57 W -> UTM 13N
    assert 41.531 < tr.lat.min() < 41.533 and 41.538 < tr.lat.max() < 41.540
    assert -106.572 < tr.lon.min() < tr.lon.max() < -106.569
    assert round(float(tr.h.min())) == 2243 and round(float(tr.h.max())) == 2720
    assert 815 < tr.s.max() - tr.s.min() < 825  # ~820 m of track
    tr.validate()


def test_vegr_s_equals_independent_recomputation(sample, vegr_track):
    s, _, _ = _oracle(sample(VEGR), "gt1r")
    assert np.all(np.diff(vegr_track.s) >= 0)
    np.testing.assert_allclose(vegr_track.s, np.sort(s), rtol=0, atol=1e-6)
    with h5py.File(sample(VEGR), "r") as f:
        t = f["gt1r/heights/delta_time"][:]
        h = f["gt1r/heights/h_ph"][:]
        conf = f["gt1r/heights/signal_conf_ph"][:, 0]
    order = np.argsort(s, kind="stable")
    np.testing.assert_array_equal(vegr_track.time, t[order])
    np.testing.assert_array_equal(vegr_track.h, h[order].astype(np.float64))
    np.testing.assert_array_equal(vegr_track.signal_conf, conf[order])


def test_vegr_clip_has_off_by_one_ph_index_beg(sample, caplog):
    """The clip's ph_index_beg is the running count without +1; the reader repairs it."""
    with h5py.File(sample(VEGR), "r") as f:
        beg = f["gt1r/geolocation/ph_index_beg"][:]
        cnt = f["gt1r/geolocation/segment_ph_cnt"][:]
    assert beg[0] == 1
    np.testing.assert_array_equal(beg[1:], np.cumsum(cnt)[:-1])  # should be cumsum + 1
    with caplog.at_level(logging.INFO, logger="canopyblocks"):
        read_atl03(sample(VEGR), "gt1r")
    assert "off by one" in caplog.text


def test_atl08_join_counts_and_delta_time(sample):
    tr = read_atl03(sample(VEGR), "gt1r", atl08=sample(VEGR08))
    s, sid, idx = _oracle(sample(VEGR), "gt1r")
    with h5py.File(sample(VEGR08), "r") as f:
        sp = f["gt1r/signal_photons"]
        a_sid, a_idx = sp["ph_segment_id"][:], sp["classed_pc_indx"][:]
        a_flag, a_dt = sp["classed_pc_flag"][:], sp["delta_time"][:]
    assert a_flag.size == 1771  # README: 1,771 classified photons in ATL08
    lookup = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(a_sid, a_idx))}
    expected = np.full(s.size, -1, np.int8)
    matched_atl08 = np.full(s.size, -1)
    for row in range(s.size):
        k = lookup.get((int(sid[row]), int(idx[row])))
        if k is not None:
            expected[row] = a_flag[k]
            matched_atl08[row] = k
    order = np.argsort(s, kind="stable")
    np.testing.assert_array_equal(tr.classification, expected[order])
    joined = tr.classification >= 0
    assert joined.sum() == 1610
    # the 161 not joined lie in ATL08 segments past the clip's last ATL03 segment
    assert int(np.sum(a_sid > sid.max())) == 1771 - 1610
    # every joined photon has exactly ATL08's delta_time
    np.testing.assert_array_equal(tr.time[joined], a_dt[matched_atl08[order][joined]])
    assert dict(zip(*np.unique(tr.classification[joined], return_counts=True))) == {
        0: 262, 1: 171, 2: 729, 3: 448}


def test_readme_1516_comes_from_trusting_the_clip_ph_index_beg(sample):
    """README says 1,516 photons join with identical delta_time: that is the count when
    the clip's (off-by-one) ph_index_beg is trusted; the correct join has 1,610, all equal."""
    with h5py.File(sample(VEGR), "r") as f:
        g = f["gt1r/geolocation"]
        beg, seg = g["ph_index_beg"][:], g["segment_id"][:]
        t = f["gt1r/heights/delta_time"][:]
    with h5py.File(sample(VEGR08), "r") as f:
        sp = f["gt1r/signal_photons"]
        a_sid, a_idx, a_dt = sp["ph_segment_id"][:], sp["classed_pc_indx"][:], sp["delta_time"][:]
    pos = np.searchsorted(seg, a_sid)
    inside = a_sid <= seg.max()
    rows = beg[pos[inside]] - 1 + a_idx[inside] - 1  # naive row from ph_index_beg
    assert int(np.sum(t[rows] == a_dt[inside])) == 1516


def test_harmony_sea_ice_granule(sample):
    path = sample(HARMONY)
    assert atl03_beams(path) == [BeamInfo("gt1l", "weak", 2909, 6)]
    tr = read_atl03(path, "gt1l")
    assert len(tr) == 2909
    assert np.all(tr.signal_conf == -1)
    s, _, _ = _oracle(path, "gt1l")
    np.testing.assert_allclose(tr.s, np.sort(s), rtol=0, atol=1e-6)
    assert np.all(np.isfinite(tr.x)) and np.all(np.isfinite(tr.y))
    with pytest.raises(NoUsableDataError,
                       match=r"gt1l of .*harmony_ATL03_gt1l\.h5: no photon has land signal "
                             r"confidence >= 2 \(all -1: not a land surface type"):
        read_atl03(path, "gt1l", min_signal_conf=2)


def test_min_signal_conf_filters(sample):
    with h5py.File(sample(VEGR), "r") as f:
        conf = f["gt1r/heights/signal_conf_ph"][:, 0]
    tr = read_atl03(sample(VEGR), "gt1r", min_signal_conf=2)
    assert len(tr) == int(np.sum(conf >= 2)) == 1587
    assert tr.signal_conf.min() >= 2
    with pytest.raises(InputError, match="min_signal_conf 7 must be an integer in -2..4"):
        read_atl03(sample(VEGR), "gt1r", min_signal_conf=7)


@pytest.mark.parametrize("q", [(None, (0.2, 0.4)), ((0.6, 0.8), None), ((0.1, 0.9), (0.45, 0.5))])
def test_bbox_subset_equals_posthoc_filter(sample, vegr_track, q):
    full = vegr_track
    qlon, qlat = q
    lon0, lon1 = np.quantile(full.lon, qlon) if qlon else (-180.0, 180.0)
    lat0, lat1 = np.quantile(full.lat, qlat) if qlat else (-90.0, 90.0)
    bbox = (float(lon0), float(lat0), float(lon1), float(lat1))
    sub = read_atl03(sample(VEGR), "gt1r", bbox=bbox, crs=full.crs)
    m = (full.lon >= bbox[0]) & (full.lon <= bbox[2]) & (full.lat >= bbox[1]) & \
        (full.lat <= bbox[3])
    assert 0 < m.sum() < len(full)
    assert len(sub) == m.sum()
    for col in ("time", "lat", "lon", "h", "s", "x", "y", "signal_conf"):
        np.testing.assert_array_equal(getattr(sub, col), getattr(full, col)[m])


def test_s_range_subset_equals_posthoc_filter(sample, vegr_track):
    s0 = float(vegr_track.s.min())
    rng = (s0 + 100.5, s0 + 333.3)
    sub = read_atl03(sample(VEGR), "gt1r", s_range=rng)
    m = (vegr_track.s >= rng[0]) & (vegr_track.s <= rng[1])
    assert len(sub) == m.sum() > 0
    np.testing.assert_array_equal(sub.s, vegr_track.s[m])
    np.testing.assert_array_equal(sub.time, vegr_track.time[m])


def test_subset_reads_only_part_of_the_photon_rows(sample, monkeypatch):
    reads = []
    orig = H5File.read

    def spy(self, name, sel=None, **kw):
        if name.endswith("heights/h_ph"):
            reads.append(sel)
        return orig(self, name, sel, **kw)

    monkeypatch.setattr(H5File, "read", spy)
    read_atl03(sample(VEGR), "gt1r", bbox=(-106.6, 41.5350, -106.5, 41.5355))
    assert len(reads) == 1 and isinstance(reads[0], slice)
    n_read = reads[0].stop - reads[0].start
    assert 0 < n_read < 6809 / 3


def test_empty_subset_names_coverage(sample):
    with pytest.raises(NoUsableDataError, match=r"no photons of gt1r inside bbox.*covers lon"):
        read_atl03(sample(VEGR), "gt1r", bbox=(10, 10, 11, 11))


def test_open_track_and_file_info(sample):
    tr = open_track(sample(VEGR), atl08=sample(VEGR08))
    assert tr.track == "gt1r" and int(np.sum(tr.classification >= 0)) == 1610
    info = file_info(sample(VEGR))
    assert info["product"] == "ATL03"
    assert (info["rgt"], info["cycle"], info["sc_orient"]) == (150, 15, 0)
    assert info["beams"] == [dict(name="gt1r", strength="weak", n_photons=6809, spot=2)]
    lon0, lat0, lon1, lat1 = info["bbox"]
    assert 41.531 < lat0 < lat1 < 41.540 and -106.572 < lon0 < lon1 < -106.569
    t0, t1 = info["time_span"]
    assert 0 < t1 - t0 < 1.0  # 820 m at ~7 km/s
    text = format_info(info)
    assert "gt1r: weak, spot 2, 6809 photons" in text
    info08 = file_info(sample(VEGR08))
    assert info08["product"] == "ATL08" and info08["beams"] == ["gt1r"]


def test_progress_and_cancel(sample):
    from canopyblocks.errors import CancelledError
    from canopyblocks.progress import Progress

    seen = []
    read_atl03(sample(VEGR), "gt1r", atl08=sample(VEGR08),
               progress=Progress(callback=lambda f, m: seen.append(f)))
    assert seen[0] == 0.0 and seen[-1] == 1.0 and seen == sorted(seen)
    with pytest.raises(CancelledError):
        read_atl03(sample(VEGR), "gt1r", progress=Progress(cancelled=lambda: True))
