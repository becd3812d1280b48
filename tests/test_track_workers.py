"""Beams blocked in worker processes (``blocks --workers N``) give the table one process
gives, byte for byte: with the paper's engine and the icesat2 estimators, with labels and
photons, with a beam in another UTM zone than the first, with a beam skipped."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from canopyblocks.blocks import BlockParams
from canopyblocks.blocks.estimators import preset
from canopyblocks.cli import cli
from canopyblocks.outputs.h5_layouts import Atl03BeamData, write_atl03
from canopyblocks.workflows.blocks import blocks_from_file
from canopyblocks.workflows.blocks_tracks import track_workers_for

pytestmark = pytest.mark.filterwarnings("ignore::canopyblocks.errors.CanopyBlocksWarning")

BEAMS = ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")


def _granule(path: Path, lon0: float = -106.57, zone_split: bool = False,
             empty: str | None = None, seed: int = 5) -> Path:
    """Six beams of a forested slope (ground, canopy, background), weak beams a quarter."""
    rng = np.random.default_rng(seed)
    beams = {}
    for i, b in enumerate(BEAMS):
        if b == empty:
            n = 0
        else:
            n = 24_000 if b.endswith("l") else 6_000
        s = np.sort(rng.random(n)) * 3000.0
        ground = 2400.0 + 30.0 * np.sin(s / 400.0)
        u = rng.random(n)
        h = ground + np.where(u < 0.45, rng.normal(0, 0.3, n),
                              np.where(u < 0.85, rng.random(n) * 22.0, rng.uniform(-40, 60, n)))
        # with zone_split the beams straddle the 108 W boundary of UTM zones 12 and 13
        lon = (-108.0 + (0.004 if i == 0 else -0.004 * i) if zone_split
               else lon0 + i * 1e-3) + s * 1.0e-7
        lat = 41.5 + s * 9.0e-6
        sc = np.where(u < 0.85, 4, 0).astype(np.int8)
        beams[b] = Atl03BeamData(delta_time=s / 7000.0, lat=lat, lon=lon, h=h, s=s,
                                 signal_conf=sc)
    return write_atl03(path, beams)


@pytest.fixture(scope="module")
def granule(tmp_path_factory) -> Path:
    return _granule(tmp_path_factory.mktemp("tw") / "ATL03_six.h5")


def _same(a: pd.DataFrame, b: pd.DataFrame) -> None:
    assert list(a.columns) == list(b.columns)
    assert a.crs == b.crs
    pd.testing.assert_frame_equal(pd.DataFrame(a.drop(columns="geometry")),
                                  pd.DataFrame(b.drop(columns="geometry")), check_exact=True)
    assert a.geometry.to_wkb().tolist() == b.geometry.to_wkb().tolist()


@pytest.mark.parametrize("with_estimators", [False, True])
def test_workers_equal_one_process(granule, with_estimators):
    params = BlockParams(lengths=(10.0, 25.0, 100.0))
    est = preset("icesat2") if with_estimators else None
    one = blocks_from_file(granule, params, estimators=est, workers=1)
    two = blocks_from_file(granule, params, estimators=est, workers=2)
    assert two.track_ids == one.track_ids == list(BEAMS)
    assert two.tracks == []  # kept only when the photon layer or the profile needs them
    _same(one.blocks, two.blocks)
    # and the table is not trivially empty: every beam has ok blocks at every length
    ok = one.blocks[one.blocks["flag"] == "ok"]
    assert set(ok["track"]) == set(BEAMS)
    assert set(ok["length"]) == {10.0, 25.0, 100.0}


def test_workers_keep_labels_and_photons(granule):
    params = BlockParams(lengths=(25.0,))
    one = blocks_from_file(granule, params, workers=1, with_photons=True)
    three = blocks_from_file(granule, params, workers=3, with_photons=True)
    assert [t.track for t in three.tracks] == list(BEAMS)
    for t1, t3 in zip(one.tracks, three.tracks):
        np.testing.assert_array_equal(t1.s, t3.s)
        np.testing.assert_array_equal(t1.x, t3.x)
        np.testing.assert_array_equal(one.labels[t1.track][25.0], three.labels[t3.track][25.0])


def test_cli_output_files_are_identical(granule, tmp_path):
    runner = CliRunner()
    outs = []
    for w in (1, 2):
        out = tmp_path / f"w{w}.parquet"
        r = runner.invoke(cli, ["-q", "blocks", str(granule), "--length", "25", "--length",
                                "100", "--workers", str(w), "-o", str(out)])
        assert r.exit_code == 0, r.output
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]


def test_beam_in_another_utm_zone_is_projected_like_the_first(tmp_path):
    g = _granule(tmp_path / "ATL03_zones.h5", zone_split=True)
    params = BlockParams(lengths=(25.0,))
    one = blocks_from_file(g, params, workers=1)
    two = blocks_from_file(g, params, workers=2)
    assert one.blocks.crs.to_epsg() == 32613  # gt1l (east of 108 W) sets the CRS
    _same(one.blocks, two.blocks)
    # gt1r lies in zone 12 on its own: here its x is in zone 13's coordinates, ~500 km
    # east of zone 12's false easting minus the few kilometres west of the boundary
    x = two.blocks.loc[two.blocks["track"] == "gt1r", "x"]
    assert (x < 250_000).all()


def test_skipped_beam_warns_once_and_the_rest_match(tmp_path):
    g = _granule(tmp_path / "ATL03_gap.h5", empty="gt2l")
    params = BlockParams(lengths=(25.0,))
    with warnings.catch_warnings(record=True) as w1:
        warnings.simplefilter("always")
        one = blocks_from_file(g, params, workers=1)
    with warnings.catch_warnings(record=True) as w2:
        warnings.simplefilter("always")
        two = blocks_from_file(g, params, workers=2)
    assert "gt2l" not in two.track_ids and len(two.track_ids) == 5
    _same(one.blocks, two.blocks)
    assert sorted(str(w.message) for w in w1) == sorted(str(w.message) for w in w2)


def test_worker_count_respects_tracks_and_memory():
    assert track_workers_for([10, 10], 8) == 2
    assert track_workers_for([10] * 6, 2) == 2
    assert track_workers_for([10] * 6, 1) == 1
    # a track of 1e12 photons would need 250 TB per worker: one process
    assert track_workers_for([10**12, 10], None) == 1


def test_photon_layer_written_track_by_track(granule, tmp_path):
    """The photons layer, written one track at a time, holds every photon of every beam
    (counts from h5py) with its label, in beam order."""
    import geopandas as gpd
    import h5py

    out = tmp_path / "b.gpkg"
    res = blocks_from_file(granule, BlockParams(lengths=(25.0,)), output=out,
                           with_photons=True, workers=2)
    ph = gpd.read_file(out, layer="photons")
    with h5py.File(granule) as f:
        counts = [f[f"{b}/heights/h_ph"].shape[0] for b in BEAMS]
    assert ph["track"].tolist() == sum(([b] * n for b, n in zip(BEAMS, counts)), [])
    names = {0: "noise", 1: "ground", 2: "canopy", 3: "between", -1: "outside"}
    want = np.concatenate([res.labels[b][25.0] for b in BEAMS])
    assert ph["label_25m"].tolist() == [names.get(int(v), "?") for v in want]
    assert ph.crs == res.blocks.crs


def test_small_pages_is_scoped() -> None:
    """Blocks are computed without numpy's huge-page requests; the caller's setting is
    back afterwards, also after an error."""
    import numpy as np

    from canopyblocks.workflows.blocks import small_pages

    setter = np.core.multiarray._set_madvise_hugepage
    before = setter(True)
    try:
        with small_pages():
            assert setter(False) is False        # off inside
        assert setter(True) is True              # on again after
        try:
            with small_pages():
                raise KeyError("x")
        except KeyError:
            pass
        assert setter(True) is True
    finally:
        setter(before)
