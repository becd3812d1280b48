"""``waveforms --l2a`` with an L2A file holding only the selected algorithm's values (what
subsetting services keep): accepted, compared on the shots whose selected algorithm
(L2A ``selected_algorithm`` or L2B ``selected_l2a_algorithm``) is the setting processed,
and the comparison says how many shots it leaves out and why."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from canopyblocks.errors import InputError
from canopyblocks.workflows.waveforms import compare_with_l2a, footprints_from_l1b

BEAM = "BEAM0101"


def _selected_only(src: Path, dst: Path, other_every: int = 4, keep_selected: bool = True
                   ) -> Path:
    """The L2A with every per-setting dataset removed; every ``other_every``-th shot of
    BEAM0101 said to come from algorithm 2."""
    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        for b in [k for k in f if k.startswith("BEAM")]:
            g = f[b]
            for k in [k for k in g["geolocation"] if k[-3:-1] == "_a"]:
                del g["geolocation"][k]
            for k in [k for k in g if k.startswith("rx_processing_a")]:
                del g[k]
            if not keep_selected:
                del g["selected_algorithm"]
        sel = f[f"{BEAM}/selected_algorithm"] if keep_selected else None
        if sel is not None:
            a = sel[()]
            a[::other_every] = 2
            sel[...] = a
    return dst


@pytest.fixture(scope="module")
def table(gedi_l1b):  # noqa: ANN001, ANN201
    return footprints_from_l1b(gedi_l1b, beams=BEAM)[0]


def test_selected_only_l2a_is_compared_on_its_setting(table, gedi_l2a, tmp_path):
    full, stats_full = compare_with_l2a(table, gedi_l2a)
    path = _selected_only(gedi_l2a, tmp_path / "sel.h5")
    sub, stats = compare_with_l2a(table, path)
    with h5py.File(path) as f:
        sn = f[f"{BEAM}/shot_number"][()].astype(np.int64)
        algo = dict(zip(sn.tolist(), f[f"{BEAM}/selected_algorithm"][()].tolist()))
        q = dict(zip(sn.tolist(), f[f"{BEAM}/quality_flag"][()].tolist()))
    ours = table["shot_number"].to_numpy(np.int64)
    other = np.array([algo[s] != 1 for s in ours])
    assert other.sum() == (len(ours) + 3) // 4  # 19 of 73
    # the selected-algorithm values are setting a1's (every shot's algorithm was 1)
    same = ~other
    np.testing.assert_allclose(sub["l2a_ground"].to_numpy()[same],
                               full["l2a_ground"].to_numpy()[same])
    valid = sub["l2a_valid"].to_numpy(bool)
    assert not valid[other].any()
    ok = table["flag"].to_numpy(object) == "ok"
    good_q = np.array([q[s] == 1 for s in ours])
    assert valid.sum() == int((same & ok & good_q).sum())
    row = stats[(stats["beam"] == "all") & (stats["metric"] == "ground")].iloc[0]
    assert row["n"] == valid.sum()
    assert f"L2A selected another algorithm than a1 {int(other.sum())}" in row["left_out"]


def test_flagged_shots_left_out_are_counted(table, gedi_l2a):
    t = table.copy()
    flag = t["flag"].to_numpy(object).copy()
    ok = np.flatnonzero(flag == "ok")
    flag[ok[:5]] = "terrain_outlier"
    t["flag"] = flag
    _, stats = compare_with_l2a(t, gedi_l2a)
    row = stats[(stats["beam"] == "all") & (stats["metric"] == "ground")].iloc[0]
    assert "flagged terrain_outlier here 5" in row["left_out"]


def test_selected_only_without_the_algorithm_is_refused_or_taken_from_l2b(
        table, gedi_l1b, gedi_l2a, tmp_path):
    path = _selected_only(gedi_l2a, tmp_path / "bare.h5", keep_selected=False)
    with pytest.raises(InputError, match="selected_l2a_algorithm"):
        compare_with_l2a(table, path)
    with h5py.File(gedi_l1b) as src:
        sn = src[f"{BEAM}/shot_number"][()]
        lat = src[f"{BEAM}/geolocation/latitude_bin0"][()]
        lon = src[f"{BEAM}/geolocation/longitude_bin0"][()]
    l2b = tmp_path / "l2b.h5"
    with h5py.File(l2b, "w") as f:
        g = f.create_group(BEAM)
        g["shot_number"] = sn
        g["cover"] = np.full(sn.size, 0.25, np.float32)
        g["geolocation/lat_lowestmode"] = lat
        g["geolocation/lon_lowestmode"] = lon
        algo = np.ones(sn.size, np.uint8)
        algo[:10] = 5
        g["selected_l2a_algorithm"] = algo
    _, stats = compare_with_l2a(table, path, l2b)
    row = stats[(stats["beam"] == "all") & (stats["metric"] == "ground")].iloc[0]
    assert "L2A selected another algorithm than a1 10" in row["left_out"]
