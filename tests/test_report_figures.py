"""What a reader of the report sees: the residual map's hillshade and tick labels (pixels
and rendered text boxes of the figure), and the words and tables of the report's
calibration and datum parts (the HTML text)."""

from __future__ import annotations

import html
import re
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
from shapely.geometry import box

rasterio = pytest.importorskip("rasterio")


def _dtm(path: Path) -> tuple[float, float]:
    """Hilly terrain, 2 m cells, EPSG:32609 (UTM 9N, where the bundled BC tiles lie)."""
    from affine import Affine

    x0, y0, n = 596980.0, 5614000.0, 120
    xx, yy = np.meshgrid(np.arange(n) * 2.0, -np.arange(n) * 2.0)
    z = 300 + 8 * np.sin(xx / 25.0) * np.cos(yy / 30.0)
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1,
                       dtype="float32", crs="EPSG:32609",
                       transform=Affine(2.0, 0.0, x0, 0.0, -2.0, y0)) as dst:
        dst.write(z.astype("float32"), 1)
    return x0 + n, y0 - n  # the centre


def _blocks(cx: float, cy: float, crs: str) -> gpd.GeoDataFrame:
    polys = [box(cx - 6, cy - 100 + 25 * i, cx + 6, cy - 75 + 25 * i) for i in range(8)]
    res = [np.nan, -3.0, -1.0, 0.5, 1.0, 2.0, 3.5, 4.0]
    g = gpd.GeoDataFrame({"res_hmax": res, "use": [True] * 8}, geometry=polys,
                         crs="EPSG:32609")
    return g.to_crs(crs)


def _captured(monkeypatch) -> list:
    import canopyblocks.outputs.footprint_maps as fm

    figs: list = []
    real = fm.save_figure

    def keep(fig, path, **kw):
        figs.append(fig)
        return real(fig, path, **kw)

    monkeypatch.setattr(fm, "save_figure", keep)
    return figs


def test_residual_map_draws_the_hillshade_of_a_dtm_in_another_crs(tmp_path, monkeypatch
                                                                   ) -> None:
    """Blocks in BC Albers (EPSG:3005, the airborne points' CRS) over a DTM in UTM 9N:
    the hillshade must be under them (it was left out: 'does not reach')."""
    from PIL import Image

    from canopyblocks.outputs.footprint_maps import plot_footprint_map

    cx, cy = _dtm(tmp_path / "dtm.tif")
    figs = _captured(monkeypatch)
    png = plot_footprint_map(_blocks(cx, cy, "EPSG:3005"), "res_hmax", tmp_path / "map.png",
                             dtm=tmp_path / "dtm.tif", title="Hmax residual")
    rgb = np.asarray(Image.open(png).convert("RGB")).astype(int)
    grey = (np.ptp(rgb, axis=2) <= 2) & (rgb[..., 0] > 40) & (rgb[..., 0] < 235)
    assert grey.mean() > 0.25, f"hillshade pixels: {grey.mean():.2%}"
    # the shades vary (terrain, not a flat fill)
    assert np.std(rgb[..., 0][grey]) > 10
    ax = figs[0].axes[0]
    assert "EPSG:32609" in ax.get_xlabel() and "(m" in ax.get_ylabel()
    # no two x tick labels touch (six-digit eastings overlapped on a narrow map)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(figs[0])
    canvas.draw()
    r = canvas.get_renderer()
    boxes = [t.get_window_extent(r) for t in ax.get_xticklabels() if t.get_text()]
    assert len(boxes) >= 2
    for a, b in zip(boxes, boxes[1:]):
        assert not a.overlaps(b), [t.get_text() for t in ax.get_xticklabels()]
    # the block without a value is explained, not left blank
    legend = ax.get_legend()
    assert legend is not None and "no value (1)" in [t.get_text() for t in legend.get_texts()]


def test_residual_map_in_its_own_crs_is_unchanged(tmp_path) -> None:
    from PIL import Image

    from canopyblocks.outputs.footprint_maps import plot_footprint_map

    cx, cy = _dtm(tmp_path / "dtm.tif")
    png = plot_footprint_map(_blocks(cx, cy, "EPSG:32609"), "res_hmax", tmp_path / "m.png",
                             dtm=tmp_path / "dtm.tif")
    rgb = np.asarray(Image.open(png).convert("RGB")).astype(int)
    grey = (np.ptp(rgb, axis=2) <= 2) & (rgb[..., 0] > 40) & (rgb[..., 0] < 235)
    assert grey.mean() > 0.25


def _page(tmp_path: Path, sections) -> str:
    from canopyblocks.outputs.report import write_report

    out = write_report(tmp_path / "r.html", "t", sections)
    return html.unescape(out.read_text())


def test_no_bias_calibration_says_why_instead_of_an_empty_table(tmp_path) -> None:
    from canopyblocks.outputs.report import ReportSection
    from canopyblocks.workflows.chain_report import bias_calibration_part

    empty = pd.DataFrame()
    empty.attrs["why"] = "5 usable 50 m blocks of strong beams; at least 6 are needed"
    words, tables = bias_calibration_part(empty, "atl08")
    page = _page(tmp_path, [ReportSection("x", [words], tables)])
    assert ("No bias calibration was fitted for the 'atl08' estimators: 5 usable 50 m "
            "blocks of strong beams; at least 6 are needed.") in page
    assert "<table" not in page


def test_calibration_tables_have_words_and_units_and_keep_the_correction(tmp_path) -> None:
    from canopyblocks.outputs.report import ReportSection, calibration_table
    from canopyblocks.workflows.chain_report import bias_calibration_part

    bias = pd.DataFrame({"metric": ["hmax"], "length": [25.0], "strength": ["strong"],
                         "slope": [1.0], "intercept": [7.18], "n": [9.0],
                         "rmse_before": [7.87], "rmse_after": [3.22],
                         "holdout_rmse_before": [7.87], "holdout_rmse_after": [3.22],
                         "n_holdout": [9.0]})
    cut = pd.DataFrame({"length": [25.0], "top_cutoff": [0.05], "ground_cutoff": [0.1],
                        "default_top_cutoff": [0.1], "default_ground_cutoff": [0.2],
                        "n_holdout": [10], "rmse_hmax_default": [11.0],
                        "rmse_hmax_calibrated": [8.35]})
    words, tables = bias_calibration_part(bias, "atl08")
    page = _page(tmp_path, [ReportSection("x", [words], {**tables,
                                                         "c": calibration_table(cut)})])
    heads = re.findall(r"<th>(.*?)</th>", page)
    assert heads and not [h for h in heads if "_" in h], heads  # words wrap; names do not
    assert "correction added (m)" in heads and "held-out RMSE after (m)" in heads
    assert "hmax RMSE, fitted cut-offs (m)" in heads
    assert "7.18" in page  # the correction is shown (a stats table drops intercepts)
    assert re.search(r"<td>25</td>", page)  # lengths as integers


def test_datum_sentence_names_the_conversion() -> None:
    from canopyblocks.workflows.chain_report import datum_sentence

    s = datum_sentence("differ", offset=0.0, tiles="CGVD28 height")
    assert s == ("the photons' heights were converted to the tiles' (CGVD28 height) datum "
                 "with a constant offset of +0 m.")
    assert "geoid raster g.tif" in datum_sentence("differ", geoid="/x/g.tif")
    assert "differ" not in datum_sentence("same", tiles="NAVD88 height")


def test_waveform_axis_names_the_datum_the_file_states(tmp_path) -> None:
    """GEDI's L1B elevations are ellipsoidal; a simulated L1B keeps the tiles' datum and
    says so in its attributes (the plot said 'WGS84 ellipsoid' over CGVD28 heights)."""
    import h5py

    from canopyblocks.outputs.waveform_plot import elevation_datum

    with h5py.File(tmp_path / "sim.h5", "w") as f:
        f.attrs["simulated"] = "canopyblocks GEDI waveform simulation"
        f.attrs["vertical_datum"] = "EPSG:5713"
    with h5py.File(tmp_path / "real.h5", "w") as f:
        f.attrs["short_name"] = "GEDI01_B"
    assert elevation_datum(tmp_path / "sim.h5") == "CGVD28 height"
    assert elevation_datum(tmp_path / "real.h5") == "WGS84 ellipsoid"
    assert elevation_datum(tmp_path / "missing.h5") == "WGS84 ellipsoid"


def test_footprint_scatter_names_the_datum_on_the_ground_axes(tmp_path, monkeypatch) -> None:
    from canopyblocks.outputs.footprint_maps import plot_footprint_scatter

    figs = _captured(monkeypatch)
    res = pd.DataFrame({"ground": [328.0, 329.5, 331.0], "ref_ground": [327.8, 329.0, 331.2],
                        "rh98": [10.0, 15.0, 20.0], "ref_rh98": [11.0, 14.0, 21.0],
                        "use": [True] * 3})
    plot_footprint_scatter(res, tmp_path / "s.png", datum="CGVD28 height")
    ground, rh98 = figs[0].axes[:2]
    assert ground.get_xlabel() == "ALS reference ground (m, CGVD28 height)"
    assert ground.get_ylabel() == "footprint ground (m, CGVD28 height)"
    assert rh98.get_xlabel() == "ALS reference RH98 (m)"  # a height above ground: no datum

