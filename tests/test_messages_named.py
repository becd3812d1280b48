"""Messages that name the real cause: another package's warning is not printed as ours;
the implausible-Hmax advice names the recommended estimators, and signal confidence only
for photons that have it."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from canopyblocks.blocks.plausibility import ImplausibleBlockWarning, flag_implausible_blocks


def test_foreign_warning_is_not_relabelled(capsys):
    from canopyblocks.cli.log_setup import setup_logging

    saved = warnings.showwarning
    try:
        setup_logging(0, False)
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.warn_explicit("urllib3 (9.9) or chardet (9.9) doesn't match a supported "
                                   "version!", UserWarning,
                                   "/usr/lib/python3/dist-packages/requests/__init__.py", 102)
    finally:
        warnings.showwarning = saved
    err = capsys.readouterr().err
    assert "warning from requests (UserWarning): urllib3" in err, err
    assert "canopyblocks: warning: urllib3" not in err, err


@pytest.mark.parametrize("conf", [None, 0.4])
def test_implausible_advice_names_the_recommended_estimators(conf):
    blocks = pd.DataFrame({"hmax": [12.0, 180.0], "flag": ["ok", "ok"]})
    with pytest.warns(ImplausibleBlockWarning) as rec:
        flag_implausible_blocks(blocks, "gt1r", conf)
    msg = str(rec[0].message)
    assert "atl08 estimators" in msg and "icesat2 preset" not in msg, msg
    assert ("signal confidence" in msg) == (conf is not None), msg
    np.testing.assert_array_equal(blocks["flag"], ["ok", "implausible"])


def test_sigma_column_of_text_is_refused_in_one_line():
    from canopyblocks.errors import InputError
    from canopyblocks.validation.residuals import compute_residuals

    n = 3
    blocks = pd.DataFrame({"track": ["gt1r"] * n, "length": [25.0] * n, "block": range(n),
                           "ground": [1.0] * n, "top": [20.0] * n, "hmax": [19.0] * n,
                           "h90": [15.0] * n, "flag": ["ok"] * n,
                           "hmax_sigma": ["1.2", "wide", "0.9"]})
    ref = pd.DataFrame({"track": ["gt1r"] * n, "length": [25.0] * n, "block": range(n),
                        "ref_ground": [1.0] * n, "ref_top": [19.0] * n,
                        "ref_top90": [15.0] * n, "ref_hmax": [18.0] * n, "ref_h90": [14.0] * n})
    with pytest.raises(InputError, match="'hmax_sigma' holds 1 values that are not numbers"):
        compute_residuals(blocks, ref)
    blocks["hmax_sigma"] = ["1.2", "1.5", "0.9"]  # numbers written as text: read as numbers
    res = compute_residuals(blocks, ref)
    np.testing.assert_allclose(res["hmax_sigma"], [1.2, 1.5, 0.9])
