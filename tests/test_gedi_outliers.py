"""GEDI terrain outliers: valid tall-forest shots and shots on steep slopes are not flagged
(the seed-003 flash-lidar filter, with its 60 m canopy ceiling and its 10 m-below-the-median
rule, flags them); a ground picked far below the terrain still is.

Scenes are simulated with the project's GEDI waveform simulator over synthetic airborne
clouds whose ground and canopy are known: canopy 80-110 m tall; a V-shaped valley with
31 degree sides; footprints 60 m apart (GEDI)."""

from __future__ import annotations

import numpy as np
import pytest

from canopyblocks.errors import InputError
from canopyblocks.readers.las import LasPoints
from canopyblocks.simulate.gedi_waveforms import simulate_gedi
from canopyblocks.simulate.tracks import SimTrack
from canopyblocks.waveforms.gedi_outliers import gedi_outliers
from canopyblocks.waveforms.process import process_waveforms
from canopyblocks.waveforms.terrain_filter import terrain_outliers

X0, Y0 = 500_000.0, 4_000_000.0
LENGTH = 1500.0
SIDE = np.tan(np.radians(31.0))


def _ground(x: np.ndarray, kind: str) -> np.ndarray:
    if kind == "valley":  # V-shaped, bottom at the track's middle
        return 300.0 + SIDE * np.abs(x - LENGTH / 2)
    return 300.0 + 0.05 * x


def _canopy(x: np.ndarray) -> np.ndarray:
    return 80.0 + 30.0 * (0.5 + 0.5 * np.sin(x / 120.0))  # 80-110 m


def _cloud(kind: str, tall: bool, seed: int = 0) -> LasPoints:
    rng = np.random.default_rng(seed)
    gx = np.arange(0.0, LENGTH, 0.7)
    gy = np.arange(-20.0, 20.0, 0.7)
    xx, yy = np.meshgrid(gx, gy)
    xx = xx.ravel() + rng.uniform(0, 0.7, xx.size)
    yy = yy.ravel() + rng.uniform(0, 0.7, yy.size)
    zg = _ground(xx, kind)
    x, y, z, c = [xx], [yy], [zg], [np.full(xx.size, 2)]
    if tall:  # crowns over 60 % of the area, the tallest layer at the canopy height
        cov = rng.random(xx.size) < 0.6
        top = _canopy(xx[cov])
        x.append(xx[cov])
        y.append(yy[cov])
        z.append(zg[cov] + top * rng.uniform(0.95, 1.0, cov.sum()))
        c.append(np.full(cov.sum(), 5))
    return LasPoints.from_arrays(np.concatenate(x) + X0, np.concatenate(y) + Y0,
                                 np.concatenate(z), crs=32610,
                                 classification=np.concatenate(c).astype(np.uint8))


@pytest.fixture(scope="module", params=[("slope", True), ("valley", False),
                                        ("valley", True)], ids=lambda p: f"{p[0]}-{p[1]}")
def scene(request):  # noqa: ANN001, ANN201
    kind, tall = request.param
    pts = _cloud(kind, tall)
    sim = simulate_gedi(pts, SimTrack.line(X0 + 20, Y0, X0 + LENGTH - 20, Y0), seed=2)
    return kind, tall, sim, process_waveforms(sim.batch)


def test_valid_tall_and_steep_shots_are_not_outliers(scene):
    kind, tall, sim, res = scene
    flag = res["flag"].to_numpy(object)
    found = np.isin(flag, ["ok", "terrain_outlier"])
    assert found.sum() >= 20
    truth_g = sim.truth["truth_ground"].to_numpy()
    err = res["ground"].to_numpy() - truth_g
    # the waveforms' grounds are right (independent of any filter) ...
    good = found & (np.abs(err) < 5.0)
    assert good.sum() >= 0.9 * found.sum()
    # ... so none of them is an outlier
    assert not (flag[good] == "terrain_outlier").any(), flag
    if tall:  # canopy 80-110 m: among the shots kept, many are taller than 60 m
        rh = sim.truth["truth_rh98"].to_numpy()[good]
        assert (rh > 60.0).sum() >= 5
    if kind == "slope" and tall:  # and the processing measures them so
        assert np.nanmax(res["rh98"].to_numpy()[good]) > 85.0
    # the seed-003 flash-lidar filter flags valid shots here (this test can fail)
    z = np.where(found, res["ground"].to_numpy(), np.nan)
    h = np.where(found, res["top"].to_numpy() - res["ground"].to_numpy(), np.nan)
    assert terrain_outliers(z, h)[good].sum() >= 3


def test_a_ground_far_below_the_terrain_is_still_an_outlier(scene):
    kind, tall, sim, res = scene
    flag = res["flag"].to_numpy(object)
    found = np.isin(flag, ["ok", "terrain_outlier"])
    z = np.where(found, res["ground"].to_numpy(), np.nan)
    h = np.where(found, res["top"].to_numpy() - z, np.nan)
    i = np.flatnonzero(found)[len(np.flatnonzero(found)) // 3]
    z_bad = z.copy()
    z_bad[i] -= 150.0  # a lowest mode in the noise far below the ground
    out = gedi_outliers(z_bad, h, res["lon"].to_numpy(), res["lat"].to_numpy())
    assert out[i] and out.sum() == 1


def test_canopy_ceiling_and_dem():
    n = 12
    lon = -123.0 + np.arange(n) * 60.0 / 70_000.0
    lat = np.full(n, 41.0)
    z = np.full(n, 100.0)
    h = np.full(n, 101.0)  # a redwood stand
    assert not gedi_outliers(z, h, lon, lat).any()
    h[3] = 400.0  # no tree
    dem = np.full(n, 100.0)
    dem[7] = 300.0  # the DEM says the ground is 200 m higher
    out = gedi_outliers(z, h, lon, lat, dem=dem)
    assert np.flatnonzero(out).tolist() == [3, 7]
    with pytest.raises(InputError, match="same length"):
        gedi_outliers(z, h[:3], lon, lat)
    with pytest.raises(InputError, match="max_gap"):
        gedi_outliers(z, h, lon, lat, max_gap=-1.0)
