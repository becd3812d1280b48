"""The fast path of the L2A-style processing gives the plain answers.

- ``float32_cut``: comparing float32 samples with it is exactly subtracting the noise
  mean in float64 and comparing with the threshold (brute force over the neighbours of
  every cut and random samples);
- the signal bounds never leave out a sub-sample pair the brute-force smoothing of the
  whole waveform puts above a threshold inside the search window;
- whole shots built to sit on the edges of those bounds (lone noise spikes above the
  thresholds near and far from the signal, signals at the ends of a shot, float64 and
  float32 samples) give what the plain per-sub-sample implementation of the
  processing gives, in every setting group.
"""

from __future__ import annotations

import numpy as np
import pytest

from canopyblocks.waveforms.process import _reach, _scan, process_waveforms
from canopyblocks.waveforms.scan import float32_cut
from canopyblocks.waveforms.settings import SETTINGS, WaveformParams
from test_waveforms_steps import MEAN, SD, make_batch, plain_l2a, plain_smooth, pulse


def test_float32_cut_is_exact() -> None:
    rng = np.random.default_rng(5)
    n = 4000
    mean = rng.uniform(-50, 5000, n) * rng.choice([1.0, 1e-3, 1e3], n)
    t = rng.uniform(1e-6, 100, n) * rng.choice([1.0, 1e-4, 1e4], n)
    cut = float32_cut(mean, t)
    assert cut.dtype == np.float32 and np.isfinite(cut).all()
    probes = [cut]
    for direction in (np.inf, -np.inf):
        x = cut
        for _ in range(3):
            x = np.nextafter(x, np.float32(direction))
            probes.append(x)
    probes.append((mean + t * rng.uniform(0.5, 1.5, n)).astype(np.float32))
    for x in probes:
        truth = (x.astype(np.float64) - mean) > t
        np.testing.assert_array_equal(x >= cut, truth)
    bad = float32_cut(np.array([np.nan, 1.0]), np.array([1.0, np.inf]))
    assert np.isnan(bad[0]) and not (np.float32(3e38) >= bad[1])


def _adversarial_waves(rng: np.random.Generator, count: int) -> list[np.ndarray]:
    waves = []
    for i in range(count):
        length = int(rng.integers(160, 700))
        w = MEAN + rng.normal(0, SD, length)
        kind = i % 6
        if kind != 5:                               # kind 5: noise only, with spikes
            if kind == 0:                           # mid-shot
                centre = rng.uniform(0.3, 0.7) * length
            elif kind == 1:                         # at the start of the shot
                centre = rng.uniform(3, 20)
            elif kind == 2:                         # at its end
                centre = length - rng.uniform(3, 20)
            else:
                centre = rng.uniform(40, length - 40)
            for _ in range(int(rng.integers(1, 4))):
                w += pulse(length, centre + rng.normal(0, 12), rng.uniform(8, 150),
                           rng.uniform(1.5, 8))
        for _ in range(int(rng.integers(0, 6))):    # lone samples over the thresholds
            j = int(rng.integers(0, length))
            w[j] = MEAN + SD * rng.uniform(2.0, 40.0)
        waves.append(w)
    return waves


@pytest.mark.parametrize("setting", sorted(SETTINGS))
def test_bounds_hold_every_pair_above_a_threshold(setting: str) -> None:
    rng = np.random.default_rng(sorted(SETTINGS).index(setting) + 40)
    params = WaveformParams(setting=setting)  # type: ignore[arg-type]
    group = params.group
    f = params.subsamples
    waves = _adversarial_waves(rng, 60)
    batch = make_batch(waves)
    scan = _scan(batch, params)
    for i, w in enumerate(waves):
        r = w.astype(np.float32).astype(np.float64) - MEAN
        loc = plain_smooth(r, f, *params.kernel_shape(params.location_smoothing))
        s0, s1 = int(scan.window_start[i]), int(scan.window_end[i])
        if not scan.has_window[i]:
            assert not (r > params.preprocessor_threshold * SD).any()
            continue
        for level in (group.front_threshold * SD, group.back_threshold * SD):
            pairs = [p for p in range(f * s0, f * s1)
                     if loc[p] > level and loc[p + 1] > level]
            if pairs:
                assert scan.may_have_signal[i], (i, level)
                assert f * scan.bound_start[i] <= pairs[0], (i, level)
                if level == group.back_threshold * SD:
                    assert pairs[-1] < f * scan.bound_end[i], (i, level)
    assert _reach(params) > 0


@pytest.mark.parametrize("setting", sorted(SETTINGS))
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_edge_shots_match_plain_implementation(setting: str, dtype: type) -> None:
    rng = np.random.default_rng(sorted(SETTINGS).index(setting) + 7)
    params = WaveformParams(setting=setting, all_rh=True, terrain_filter=False)  # type: ignore[arg-type]
    waves = [w.astype(np.float32).astype(np.float64) for w in _adversarial_waves(rng, 36)]
    batch = make_batch(waves)
    if dtype is np.float64:
        batch = type(batch)(**{**batch.__dict__, "waveforms": batch.waveforms.astype(np.float64)})
    table = process_waveforms(batch, params)
    checked = 0
    for i, w in enumerate(waves):
        ref = plain_l2a(w, params)
        row = table.iloc[i]
        if ref is None:
            assert row["flag"] == "no_signal", i
            continue
        checked += 1
        assert row["ground"] == pytest.approx(ref["ground"], abs=1e-9), i
        assert row["top"] == pytest.approx(ref["top"], abs=1e-9), i
        assert row["n_modes"] == ref["n_modes"], i
        rh = ref["rh"]
        assert isinstance(rh, dict)
        for k in range(101):
            assert row[f"rh{k}"] == pytest.approx(rh[k], abs=1e-9), (i, k)
    assert checked >= 12
