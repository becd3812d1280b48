"""The L2A-style steps on handmade waveforms with known answers, against a plain
per-sub-sample re-implementation of DESIGN 4.3, and batch == shot by shot."""

from __future__ import annotations

import math

import numpy as np
import pytest

from canopyblocks.errors import InputError
from canopyblocks.waveforms.batch import WaveformBatch
from canopyblocks.waveforms.process import process_waveforms, shot_details
from canopyblocks.waveforms.settings import SETTINGS, WaveformParams
from canopyblocks.waveforms.smoothing import smooth_subsampled
from canopyblocks.waveforms.terrain_filter import terrain_outliers

DZ = 0.15          # m per sample (GEDI: ~0.1498)
MEAN = 200.0       # noise mean, counts
SD = 3.0           # noise sd, counts
BIN0 = 1000.0      # elevation of sample 0, m


def make_batch(waves: list[np.ndarray], *, stale: list[bool] | None = None,
               degraded: list[bool] | None = None, mean: float = MEAN, sd: float = SD,
               time: np.ndarray | None = None) -> WaveformBatch:
    """A batch of handmade shots: sample j at BIN0 - j * DZ, lon/lat moving with j."""
    n = len(waves)
    lengths = np.array([len(w) for w in waves], dtype=np.int64)
    width = max(int(lengths.max()), 1)
    wf = np.full((n, width), mean, dtype=np.float32)
    for i, w in enumerate(waves):
        wf[i, :len(w)] = w
    span = np.maximum(lengths - 1, 0) * DZ
    return WaveformBatch(
        beam="BEAM0101", shot_number=np.arange(n, dtype=np.uint64) + 10**17,
        time=np.arange(n, dtype=np.float64) if time is None else time,
        waveforms=wf, n_samples=lengths,
        elev_bin0=np.full(n, BIN0), elev_lastbin=BIN0 - span,
        lat_bin0=np.full(n, 10.0), lat_lastbin=np.full(n, 10.0) + span * 1e-5,
        lon_bin0=np.full(n, 20.0), lon_lastbin=np.full(n, 20.0) - span * 1e-5,
        noise_mean=np.full(n, mean), noise_sd=np.full(n, sd),
        stale=np.array(stale if stale else [False] * n),
        degraded=np.array(degraded if degraded else [False] * n))


def pulse(length: int, centre: float, amplitude: float, sigma: float) -> np.ndarray:
    j = np.arange(length)
    return amplitude * np.exp(-0.5 * ((j - centre) / sigma) ** 2)


def elev(pos: float) -> float:
    return BIN0 - pos * DZ


# --- a plain re-implementation of DESIGN 4.3, one shot, loops over sub-samples -------

def plain_smooth(resid: np.ndarray, f: int, sd: float, half: int) -> np.ndarray:
    """Linear interpolation (waveform = noise mean outside), then a truncated Gaussian."""
    m = len(resid)
    ext = np.concatenate([np.zeros(half), resid, np.zeros(half)])
    x = np.arange(f * (len(ext) - 1) + 1) / f
    y = np.interp(x, np.arange(len(ext)), ext)
    u = np.arange(-half, half + 1)
    kern = np.exp(-0.5 * (u / sd) ** 2)
    kern /= kern.sum()
    out = np.zeros(f * (m - 1) + 1)
    for i in range(len(out)):
        c = i + f * half
        out[i] = float(np.dot(y[c - half:c + half + 1], kern[::-1]))
    return out


def plain_l2a(w: np.ndarray, params: WaveformParams) -> dict[str, object] | None:
    f = params.subsamples
    g = params.group
    r = w.astype(np.float64) - MEAN
    above = [j for j in range(len(r)) if r[j] > params.preprocessor_threshold * SD]
    if not above:
        return None
    s0 = max(above[0] - params.search_size, 0)
    s1 = min(above[-1] + params.search_size, len(r) - 1)
    loc = plain_smooth(r, f, *params.kernel_shape(params.location_smoothing))
    srch = plain_smooth(r, f, *params.kernel_shape(g.mode_smoothing))
    front, back = g.front_threshold * SD, g.back_threshold * SD
    top = bottom = None
    for i in range(f * s0, f * s1):
        if loc[i] > front and loc[i + 1] > front:
            top = i
            break
    for i in range(f * s1 - 1, f * s0 - 1, -1):
        if loc[i] > back and loc[i + 1] > back:
            bottom = i + 1
            break
    if top is None or bottom is None:
        return None
    modes = [i for i in range(max(top, 1), bottom)
             if srch[i] - srch[i - 1] > 0 and srch[i + 1] - srch[i] <= 0 and srch[i] > back]
    if not modes:
        return None
    total = sum(srch[top:bottom + 1])
    ground = modes[-1]
    if g.ground_min_energy > 0:     # a2: the lowest mode with enough energy below it
        strong = [i for i in modes
                  if sum(srch[i:bottom + 1]) >= g.ground_min_energy / 100 * total]
        ground = strong[-1] if strong else modes[-1]
    pos = {0: bottom, 100: top}
    for k in range(1, 100):
        acc = 0.0
        for i in range(bottom, top - 1, -1):       # upwards from the bottom
            acc += srch[i]
            if acc >= k / 100 * total:
                pos[k] = i + 1
                break
    rh = {k: math.trunc(round((elev(p / f) - elev(ground / f)) * 100, 6)) / 100
          for k, p in pos.items()}
    return {"top": elev(top / f), "ground": elev(ground / f), "rh": rh, "n_modes": len(modes)}


# --- smoothing --------------------------------------------------------------------------

@pytest.mark.parametrize(("sd", "half"), [(24.0, 60), (12.5, 30), (26.0, 52), (3.0, 6)])
def test_fft_smoothing_equals_plain_convolution(sd: float, half: int) -> None:
    rng = np.random.default_rng(3)
    resid = rng.normal(0, 5, size=(4, 120))
    resid[2, 90:] = 0.0                               # a shorter shot, zero-padded
    out = smooth_subsampled(resid, 4, [(sd, half)])[0]
    for i, length in enumerate((120, 120, 90, 120)):
        ref = plain_smooth(resid[i, :length], 4, sd, half)
        np.testing.assert_allclose(out[i, :len(ref)], ref, atol=1e-9)


# --- known answers ----------------------------------------------------------------------

def test_single_pulse_ground_at_peak_and_symmetric_energy() -> None:
    w = MEAN + pulse(400, 200.0, 150.0, 5.0)
    params = WaveformParams(setting="a4", all_rh=True, terrain_filter=False)  # k_f = k_b
    row = process_waveforms(make_batch([w]), params).iloc[0]
    assert row["flag"] == "ok"
    assert row["n_modes"] == 1
    assert row["ground"] == pytest.approx(elev(200.0), abs=1e-9)
    assert abs(row["rh50"]) <= 0.04                    # within a quarter sample (0.0375 m)
    # RH_k sits one sub-sample below where the energy reaches k %: rh25 and rh75 are
    # symmetric about the peak up to two sub-samples (0.075 m) and the cm truncation.
    assert row["rh75"] == pytest.approx(-row["rh25"], abs=0.09)
    assert 0.5 < row["rh75"] < 0.9
    assert row["rh100"] == pytest.approx(-row["rh0"], abs=0.04)
    assert row["top"] == pytest.approx(row["ground"] + row["rh100"], abs=0.011)
    assert row["rh100"] > 5 * DZ
    # lon/lat at the ground sample
    assert row["lat"] == pytest.approx(10.0 + 200 * DZ * 1e-5)
    assert row["cover"] == pytest.approx(0.0, abs=0.01)
    # only the upper tail beyond ground + 2 m (1.7 smoothed sd) is not "penetrated"
    assert 0.95 < row["penetration"] < 1.0


def test_two_pulses_modes_rh_cover_penetration() -> None:
    # Canopy at sample 140 (9 m above the ground at 200), ground pulse half as strong;
    # strong enough that the thresholds cut only ~1 % of either pulse.
    w = MEAN + pulse(400, 140.0, 600.0, 4.0) + pulse(400, 200.0, 300.0, 4.0)
    row = process_waveforms(make_batch([w]),
                            WaveformParams(all_rh=True, terrain_filter=False)).iloc[0]
    assert row["n_modes"] == 2
    assert row["ground"] == pytest.approx(elev(200.0), abs=1e-9)
    # one third of the energy is ground: RH25 in the ground pulse, RH45 in the canopy
    assert abs(row["rh25"]) < 1.5
    assert 7.0 < row["rh45"] < 9.0
    # RH50 = the canopy pulse's 25 % quantile: 9 m - 0.674 sd (sd ~ 7 samples after smoothing)
    assert row["rh50"] == pytest.approx(9.0 - 0.674 * 7.0 * DZ, abs=0.15)
    assert row["rh98"] > row["rh95"] > row["rh90"] > row["rh75"] > row["rh50"]
    # R_g = the whole ground pulse (mirrored), R_v = the canopy pulse: 2 / (2 + 1.5)
    assert row["cover"] == pytest.approx(2.0 / 3.5, abs=0.02)
    # energy below ground + 2 m = the ground pulse = 1/3
    assert row["penetration"] == pytest.approx(1.0 / 3.0, abs=0.02)


def test_all_noise_and_empty_shots_are_no_signal() -> None:
    rng = np.random.default_rng(5)
    noise = MEAN + np.clip(rng.normal(0, SD, 500), -3.5 * SD, 3.5 * SD)
    batch = make_batch([noise, np.array([], dtype=np.float64), np.array([MEAN + 100.0]),
                        MEAN + pulse(400, 200.0, 150.0, 5.0)])
    table = process_waveforms(batch)
    assert list(table["flag"]) == ["no_signal", "no_signal", "no_signal", "ok"]
    assert table.loc[:2, ["ground", "top", "rh50", "cover"]].isna().all().all()
    assert (table.loc[:2, "n_modes"] == 0).all()
    assert np.isfinite(table.loc[:2, ["lon", "lat"]]).all().all()   # a place to draw them


def test_stale_and_degraded_are_flagged_not_dropped() -> None:
    w = MEAN + pulse(400, 200.0, 150.0, 5.0)
    table = process_waveforms(make_batch([w, w, w], stale=[True, False, True],
                                         degraded=[False, True, True]))
    assert list(table["flag"]) == ["stale", "degraded", "stale"]
    assert table["ground"].notna().all()


def test_too_many_modes_flagged() -> None:
    w = MEAN + sum(pulse(1000, 100.0 + 30 * k, 80.0, 3.0) for k in range(25))
    params = WaveformParams(terrain_filter=False)   # 720 samples of canopy: > 60 m
    row = process_waveforms(make_batch([w]), params).iloc[0]
    assert row["n_modes"] == 25
    assert row["flag"] == "too_many_modes"
    assert row["ground"] == pytest.approx(elev(100.0 + 30 * 24), abs=1e-9)
    more = WaveformParams(max_modes=30, terrain_filter=False)
    assert process_waveforms(make_batch([w]), more).iloc[0]["flag"] == "ok"


@pytest.mark.parametrize("setting", sorted(SETTINGS))
def test_matches_plain_implementation(setting: str) -> None:
    rng = np.random.default_rng(11)
    params = WaveformParams(setting=setting, all_rh=True, terrain_filter=False)  # type: ignore[arg-type]
    waves = []
    for _ in range(6):
        length = int(rng.integers(300, 420))
        w = MEAN + rng.normal(0, SD, length)
        for _ in range(int(rng.integers(1, 4))):
            w += pulse(length, rng.uniform(120, length - 120), rng.uniform(15, 120),
                       rng.uniform(2.5, 8))
        waves.append(w.astype(np.float32).astype(np.float64))
    table = process_waveforms(make_batch(waves), params)
    for i, w in enumerate(waves):
        ref = plain_l2a(w, params)
        row = table.iloc[i]
        if ref is None:
            assert row["flag"] == "no_signal"
            continue
        assert row["flag"] in ("ok", "too_many_modes")
        assert row["ground"] == pytest.approx(ref["ground"], abs=1e-9)
        assert row["top"] == pytest.approx(ref["top"], abs=1e-9)
        assert row["n_modes"] == ref["n_modes"]
        rh = ref["rh"]
        assert isinstance(rh, dict)
        for k in range(101):
            assert row[f"rh{k}"] == pytest.approx(rh[k], abs=1e-9), (i, k)


def test_batch_equals_shot_by_shot() -> None:
    rng = np.random.default_rng(21)
    waves = []
    for _ in range(40):
        length = int(rng.integers(150, 900))
        w = MEAN + rng.normal(0, SD, length)
        if rng.random() < 0.85:
            for _ in range(int(rng.integers(1, 5))):
                w += pulse(length, rng.uniform(20, length - 20), rng.uniform(5, 200),
                           rng.uniform(1.5, 9))
        waves.append(w)
    batch = make_batch(waves, stale=list(rng.random(40) < 0.1))
    for setting in ("a1", "a5"):
        params = WaveformParams(setting=setting, all_rh=True, terrain_filter=False)  # type: ignore[arg-type]
        whole = process_waveforms(batch, params)
        assert len(whole) == 40 and (whole["flag"] != "ok").any()
        for i in range(40):
            one = process_waveforms(batch.subset(np.array([i])), params).iloc[0]
            row = whole.iloc[i]
            for col in whole.columns:
                if whole[col].dtype.kind == "f":
                    np.testing.assert_allclose(row[col], one[col], atol=1e-9, err_msg=col)
                else:
                    assert row[col] == one[col], (i, col)


def test_shot_details_agree_with_the_table() -> None:
    w = MEAN + pulse(400, 140.0, 100.0, 4.0) + pulse(400, 200.0, 50.0, 4.0)
    batch = make_batch([MEAN + pulse(400, 150.0, 90.0, 5.0), w])
    params = WaveformParams(setting="a1", all_rh=True, terrain_filter=False)
    row = process_waveforms(batch, params).iloc[1]
    d = shot_details(batch, 1, params)
    assert d.shot_number == 10**17 + 1
    assert d.ground == pytest.approx(row["ground"]) and d.top == pytest.approx(row["top"])
    assert d.rh[50] == pytest.approx(row["rh50"]) and d.rh[98] == pytest.approx(row["rh98"])
    assert len(d.modes) == 2 and d.modes[-1] == pytest.approx(d.ground)
    assert d.front_threshold == pytest.approx(MEAN + 3 * SD)
    assert d.back_threshold == pytest.approx(MEAN + 6 * SD)
    assert d.raw.shape == d.elevation.shape == (400,)
    assert d.smoothed.shape == d.smoothed_elevation.shape == (4 * 399 + 1,)
    # the canopy pulse (100 counts, sd 4) smoothed by sd ~6 samples: 100 * 4 / sqrt(4^2 + 6^2)
    assert d.smoothed.max() - MEAN == pytest.approx(100 * 4 / math.sqrt(16 + 36), rel=0.05)
    assert d.bottom < d.ground < d.top
    with pytest.raises(InputError, match="outside the batch of 2 shots"):
        shot_details(batch, 5, params)


# --- terrain filter ---------------------------------------------------------------------

def test_terrain_filter_on_a_synthetic_profile() -> None:
    ground = 500.0 - 0.5 * np.arange(30)            # a 0.5 m per footprint slope
    height = np.full(30, 20.0)
    ground[10] -= 15.0                              # a pit: 15 m below its neighbours
    ground[20] -= 8.0                               # 8 m below: not an outlier
    height[25] = 65.0                               # too tall
    ground[5] = np.nan                              # no ground: skipped
    out = terrain_outliers(ground, height)
    assert list(np.nonzero(out)[0]) == [10, 25]
    # the pit at the end of the beam, with neighbours on one side only
    g2 = 500.0 - 0.5 * np.arange(12)
    g2[-1] -= 12.0
    assert list(np.nonzero(terrain_outliers(g2, np.full(12, 10.0)))[0]) == [11]
    with pytest.raises(InputError, match="same length"):
        terrain_outliers(np.zeros(3), np.zeros(4))


def test_terrain_filter_flags_footprints_in_time_order() -> None:
    waves = [MEAN + pulse(400, 200.0, 150.0, 5.0) for _ in range(12)]
    waves[6] = MEAN + pulse(400, 200.0 + 100, 150.0, 5.0)   # ground 15 m lower
    times = np.arange(12, dtype=np.float64)[::-1].copy()      # stored backwards in time
    table = process_waveforms(make_batch(waves, time=times))
    assert list(np.nonzero(table["flag"].to_numpy() == "terrain_outlier")[0]) == [6]
    off = process_waveforms(make_batch(waves, time=times), WaveformParams(terrain_filter=False))
    assert (off["flag"] == "ok").all()


# --- parameters ---------------------------------------------------------------------------

def test_params_validated_with_clear_messages() -> None:
    with pytest.raises(InputError, match="not an L2A setting group; use one of a1, a2"):
        WaveformParams(setting="a7")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="kernel='l2a' knows L2A's smoothing only for widths"):
        WaveformParams(mode_smoothing=5.0)
    assert WaveformParams(mode_smoothing=5.0, kernel="nominal").kernel_shape(5.0) == (20.0, 40)
    with pytest.raises(InputError, match="rho_ratio must be a number > 0"):
        WaveformParams(rho_ratio=0)
    with pytest.raises(InputError, match="max_modes must be an integer >= 1"):
        WaveformParams(max_modes=0)
    assert WaveformParams(setting="a5").group == SETTINGS["a5"]
    assert WaveformParams(back_threshold=5.0).group.back_threshold == 5.0


def test_table_columns_and_types() -> None:
    from canopyblocks.schema import FOOTPRINT_COLUMNS
    w = MEAN + pulse(400, 200.0, 150.0, 5.0)
    table = process_waveforms(make_batch([w, w]))
    assert list(table.columns) == [*FOOTPRINT_COLUMNS, "geometry"]
    assert table["shot_number"].dtype == np.int64
    assert (table["setting"] == "a1").all()
    wide = process_waveforms(make_batch([w]), WaveformParams(all_rh=True))
    assert [c for c in wide.columns if c.startswith("rh")] == [f"rh{k}" for k in range(101)]


def test_unusable_noise_or_samples_flagged_with_a_warning() -> None:
    from canopyblocks.waveforms.process import UnusableWaveformWarning
    w = MEAN + pulse(400, 200.0, 150.0, 5.0)
    nan_sample = w.copy()
    nan_sample[50] = np.nan
    batch = make_batch([w, w, w, nan_sample, w])
    sd = batch.noise_sd.copy()
    sd[0], sd[1] = np.nan, 0.0
    mean = batch.noise_mean.copy()
    mean[2] = np.inf
    batch = WaveformBatch(**{**batch.__dict__, "noise_sd": sd, "noise_mean": mean})
    with pytest.warns(UnusableWaveformWarning, match="4 of 5 shots of BEAM0101"):
        table = process_waveforms(batch, WaveformParams(terrain_filter=False))
    assert list(table["flag"]) == ["no_signal"] * 4 + ["ok"]
    assert table["ground"].iloc[:4].isna().all()


def test_empty_batch_and_progress_cancellation() -> None:
    from canopyblocks.errors import CancelledError
    from canopyblocks.progress import Progress
    w = MEAN + pulse(400, 200.0, 150.0, 5.0)
    batch = make_batch([w] * 3)
    empty = process_waveforms(batch.subset(np.array([], dtype=np.intp)))
    assert empty.shape == (0, 20) and empty["shot_number"].dtype == np.int64  # + geometry
    seen: list[float] = []
    process_waveforms(batch, progress=Progress(callback=lambda f, msg: seen.append(f)))
    assert seen and seen[-1] == 1.0
    with pytest.raises(CancelledError):
        process_waveforms(batch, progress=Progress(cancelled=lambda: True))
