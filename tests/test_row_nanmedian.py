"""The GEDI outlier rule's row medians equal numpy's ``nanmedian`` bit for bit (rows with
NaN gaps, ties, signed zeros, odd and even counts, one number)."""

from __future__ import annotations

import numpy as np
import pytest

from canopyblocks.waveforms.gedi_outliers import row_nanmedian


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("width", [1, 10, 45])
def test_row_nanmedian_is_numpys(seed: int, width: int) -> None:
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 5.0, (3000, width))
    x[rng.random(x.shape) < 0.3] = np.nan
    x[rng.random(x.shape) < 0.05] = 0.0
    x[rng.random(x.shape) < 0.05] = -0.0
    x[rng.random(x.shape) < 0.05] = 2.5
    x = x[np.isfinite(x).any(axis=1)]
    got, want = row_nanmedian(x), np.nanmedian(x, axis=1)
    assert np.array_equal(got.view(np.int64), want.view(np.int64))
    full = np.nan_to_num(x)  # without any NaN
    assert np.array_equal(row_nanmedian(full).view(np.int64),
                          np.nanmedian(full, axis=1).view(np.int64))
    assert np.array_equal(row_nanmedian(np.array([[1.0, np.nan, 3.0, 10.0]])), [3.0])
