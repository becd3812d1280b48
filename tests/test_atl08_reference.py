"""ATL08 land segments as a reference: reading the real clip, matching to blocks."""

from __future__ import annotations

from pathlib import Path

import geopandas as gpd
import h5py
import numpy as np
import pandas as pd
import pytest

from canopyblocks.cli import main
from canopyblocks.errors import FileFormatError, InputError
from canopyblocks.geo import to_metric
from canopyblocks.outputs.tables import read_layer, write_table
from canopyblocks.reference.atl08 import atl08_reference_values, read_atl08_segments
from canopyblocks.schema import BLOCK_COLUMNS
from canopyblocks.validation import validate_atl08

ATL08 = "icesat2/vegr_atl08_clip.h5"
# the clip's values, printed once with h5py (gt1r/land_segments/canopy/h_canopy)
H_CANOPY = [6.623291, 10.518555, 6.695557, 8.509766, 4.614258, 9.282227, 6.714355, 7.257324,
            8.128174]
H_TE = [2447.4802, 2446.1375, 2455.4048, 2465.3127, 2478.0667, 2484.6855, 2495.841, 2511.9648,
        2528.4275]


def test_read_real_segments(sample) -> None:  # noqa: ANN001
    seg = read_atl08_segments(sample(ATL08))
    assert len(seg) == 9 and set(seg["beam"]) == {"gt1r"}
    np.testing.assert_allclose(seg["h_canopy"], H_CANOPY, atol=1e-5)
    np.testing.assert_allclose(seg["h_te_best_fit"], H_TE, atol=1e-3)
    assert list(seg["segment_id_beg"]) == list(range(771236, 771277, 5))
    with h5py.File(sample(ATL08)) as f:
        rh = f["gt1r/land_segments/canopy/canopy_h_metrics"][:, 16]  # RH90 of RH10..RH95
    np.testing.assert_allclose(seg["rh90"], rh)
    assert (seg["rh90"] <= seg["h_canopy"]).all()  # RH90 below RH98
    with pytest.raises(InputError, match="gt1r"):
        read_atl08_segments(sample(ATL08), "gt3l")


def test_bad_files(tmp_path: Path, sample) -> None:  # noqa: ANN001
    with pytest.raises(FileFormatError):
        read_atl08_segments(tmp_path / "missing.h5")
    with pytest.raises(FileFormatError, match="not an ATL08"):
        read_atl08_segments(sample("icesat2/vegr_atl03_clip.h5"))
    # a copy with one land segment filled (3.4028235e38) -> NaN
    p = tmp_path / "fill.h5"
    with h5py.File(sample(ATL08)) as src, h5py.File(p, "w") as dst:
        src.copy("gt1r", dst)
        dst["gt1r/land_segments/canopy/h_canopy"][4] = np.float32(3.4028235e38)
    seg = read_atl08_segments(p)
    assert np.isnan(seg["h_canopy"][4]) and np.isfinite(seg["h_canopy"]).sum() == 8


def _blocks_on_segments(sample, shift: float = 3.0) -> gpd.GeoDataFrame:  # noqa: ANN001
    """100 m blocks whose centres sit ``shift`` m along track from the segment centres."""
    with h5py.File(sample(ATL08)) as f:
        lat = f["gt1r/land_segments/latitude"][:].astype(float)
        lon = f["gt1r/land_segments/longitude"][:].astype(float)
    x, y, crs = to_metric(lon, lat)
    d = np.hypot(np.diff(x), np.diff(y))
    s_mid = np.concatenate([[0.0], np.cumsum(d)]) + 50.0
    ux, uy = np.gradient(x), np.gradient(y)
    norm = np.hypot(ux, uy)
    bx, by = x + shift * ux / norm, y + shift * uy / norm
    n = len(x)
    df = pd.DataFrame({"track": "gt1r", "length": 100.0, "block": np.arange(n),
                       "s_start": s_mid - 50.0, "s_end": s_mid + 50.0, "x": bx, "y": by,
                       "lon": lon, "lat": lat, "n_photons": 200, "n_kept": 190,
                       "n_between": 120, "ground": np.array(H_TE) + 1.0})
    df["top"] = df["ground"] + np.array(H_CANOPY) + 2.0
    df["hmax"] = df["top"] - df["ground"]
    df["z90"] = df["ground"] + 5.0
    df["h90"] = 5.0
    df["flag"] = "ok"
    df["hmax_sigma"], df["ground_sigma"], df["use"] = 2.0, 0.5, True
    return gpd.GeoDataFrame(df[list(BLOCK_COLUMNS)], geometry=gpd.points_from_xy(bx, by),
                            crs=crs)


def test_match_and_residuals(sample) -> None:  # noqa: ANN001
    blocks = _blocks_on_segments(sample)
    # reversed order and an extra far block: matching must not depend on row order
    far = blocks.iloc[[0]].assign(block=99, x=blocks["x"].iloc[0] + 5000.0)
    blocks = pd.concat([blocks.iloc[::-1], far], ignore_index=True)
    seg = read_atl08_segments(sample(ATL08))
    ref = atl08_reference_values(blocks, seg)
    order = blocks["block"].to_numpy()
    main_rows = order < 99
    np.testing.assert_allclose(ref["ref_hmax"][main_rows], np.array(H_CANOPY)[order[main_rows]],
                               atol=1e-5)
    np.testing.assert_allclose(ref["ref_ground"][main_rows], np.array(H_TE)[order[main_rows]],
                               atol=1e-3)
    assert list(ref["atl08_segment_id"][main_rows]) == \
        list(771236 + 5 * order[main_rows])
    assert ref["ref_flag"].iloc[-1] == "nomatch" and np.isnan(ref["ref_ground"].iloc[-1])
    res = validate_atl08(blocks, sample(ATL08), width=14.0)
    r = res.residuals
    ok = r["use"].to_numpy()
    assert ok.sum() == 9
    np.testing.assert_allclose(r["res_ground"][ok], 1.0, atol=1e-3)
    np.testing.assert_allclose(r["res_hmax"][ok], 2.0, atol=1e-4)
    np.testing.assert_allclose(r["res_top"][ok], 3.0, atol=1e-3)
    st = res.stats
    row = st[(st["metric"] == "hmax") & (st["group"] == "all")].iloc[0]
    assert row["n"] == 9 and row["bias"] == pytest.approx(2.0, abs=1e-4)
    assert row["slope"] == pytest.approx(1.0, abs=1e-4)  # photon = ref + 2 exactly


def test_max_distance(sample) -> None:  # noqa: ANN001
    blocks = _blocks_on_segments(sample, shift=30.0)
    seg = read_atl08_segments(sample(ATL08))
    assert (atl08_reference_values(blocks, seg)["ref_flag"] == "ok").all()
    assert (atl08_reference_values(blocks, seg, max_distance=20.0)["ref_flag"]
            == "nomatch").all()


def test_cli_atl08(sample, tmp_path: Path) -> None:  # noqa: ANN001
    bp = tmp_path / "blocks.gpkg"
    write_table(_blocks_on_segments(sample), bp)
    out = tmp_path / "v.gpkg"
    assert main(["-q", "validate", str(bp), "--atl08", str(sample(ATL08)), "-o", str(out),
                 "--width", "14"]) == 0
    st = read_layer(out, "stats")
    assert st[(st["metric"] == "ground") & (st["group"] == "all")]["n"].iloc[0] == 9
