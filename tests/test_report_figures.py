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
    assert legend is not None and "not in the statistics: no value 1" in [
        t.get_text() for t in legend.get_texts()]


def test_residual_map_labels_hatched_blocks_by_their_reason(tmp_path) -> None:
    """Blocks with a value but low_confidence are hatched and said so (not 'no value')."""
    from canopyblocks.outputs.footprint_maps import _hatched_label

    g = _blocks(0.0, 0.0, "EPSG:32609")
    g["flag"] = ["sparse", "ok", "ok", "ok", "ok", "ok", "ok", "ok"]
    g["use"] = [False, False, False, True, True, True, True, True]
    g["ref_flag"] = ["ok", "ok", "outside", "ok", "ok", "ok", "ok", "ok"]
    hatched = ~(g["use"].to_numpy(bool) & np.isfinite(g["res_hmax"].to_numpy(float)))
    assert _hatched_label(g, hatched, True) == ("not in the statistics: not used 1; "
                                                "reference outside 1; sparse 1")


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
    from canopyblocks.workflows.chain.report import bias_calibration_part

    empty = pd.DataFrame()
    empty.attrs["why"] = "5 usable 50 m blocks of strong beams; at least 6 are needed"
    words, tables = bias_calibration_part(empty, "atl08")
    page = _page(tmp_path, [ReportSection("x", [words], tables)])
    assert ("No bias calibration was fitted for the 'atl08' estimators: 5 usable 50 m "
            "blocks of strong beams; at least 6 are needed.") in page
    assert "<table" not in page


def test_calibration_tables_have_words_and_units_and_keep_the_correction(tmp_path) -> None:
    from canopyblocks.outputs.report import ReportSection, calibration_table
    from canopyblocks.workflows.chain.report import bias_calibration_part

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
    from canopyblocks.workflows.chain.report import datum_sentence

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



# ---- reports that agree with themselves: estimator and reference named, bias offers ----

def _capture_figures(monkeypatch, module) -> list:
    """Replace ``module.save_figure`` by one that keeps the figure (and writes nothing)."""
    seen: list = []

    def keep(fig, path, **_):
        seen.append(fig)
        return Path(path)

    monkeypatch.setattr(module, "save_figure", keep)
    return seen


def _residuals(n: int = 40, *, offset: float = 0.0, sd: float = 1.0, seed: int = 0,
               sigma: bool = False) -> pd.DataFrame:
    """Validated 25 m blocks whose estimates are the reference plus ``offset`` plus
    Gaussian noise of ``sd`` metres (the truth of the error is known)."""
    rng = np.random.default_rng(seed)
    ref_g = 300.0 + rng.uniform(0, 5, n)
    ref_h = rng.uniform(5, 30, n)
    hmax = ref_h + offset + rng.normal(0, sd, n)
    df = pd.DataFrame({"track": "gt1r", "length": 25.0, "block": np.arange(n),
                       "ground": ref_g + rng.normal(0, 0.1, n), "ref_ground": ref_g,
                       "hmax": hmax, "ref_hmax": ref_h, "h90": hmax - 2, "ref_h90": ref_h - 2,
                       "use": True, "flag": "ok", "estimators": "noise=atl08,ground=atl08,top=atl08"})
    df["top"], df["ref_top"] = df["ground"] + df["hmax"], df["ref_ground"] + df["ref_hmax"]
    df["z90"], df["ref_top90"] = df["ground"] + df["h90"], df["ref_ground"] + df["ref_h90"]
    for m in ("ground", "top", "hmax", "h90"):
        df[f"res_{m}"] = df[m] - df[f"ref_{m}"]
    if sigma:
        df["hmax_sigma"], df["ground_sigma"] = 1.5, 0.2
    return df


def test_scatter_and_aspect_titles_name_the_estimator_and_the_reference(monkeypatch,
                                                                        tmp_path) -> None:
    from canopyblocks.outputs import validation_plots as vp
    from canopyblocks.validation.stats import error_stats

    seen = _capture_figures(monkeypatch, vp)
    res = _residuals(sigma=True)
    row = error_stats(res["hmax"].to_numpy(), res["ref_hmax"].to_numpy())
    stats = pd.DataFrame([{"length": 25.0, "metric": "hmax", "group": "aspect:N", **row}])
    vp.write_validation_plots(res, stats, tmp_path, estimator="atl08",
                              reference="footprint-matched reference (RH98 and ground)")
    scatter, aspect = seen
    assert scatter._suptitle.get_text() == ("The 'atl08' estimator vs the footprint-matched "
                                            "reference (RH98 and ground), 25 m blocks")
    assert aspect._suptitle.get_text().startswith("The 'atl08' estimator vs the footprint")
    hmax_ax = scatter.axes[[a.get_title() for a in scatter.axes].index("hmax")]
    assert hmax_ax.get_ylabel().startswith("atl08 Hmax")
    # per-block sigmas drawn as error bars of exactly their length (hmax and ground panels)
    bars = [c for c in hmax_ax.containers
            if c.get_label() == "predicted 1-sigma error of the block"]
    assert len(bars) == 1
    spans = [abs(seg[1][1] - seg[0][1]) for seg in bars[0].lines[2][0].get_segments()]
    assert np.allclose(spans, 3.0)  # +-1.5 m
    assert "predicted 1-sigma error of the block" in [t.get_text() for t in scatter.legends[0].get_texts()]
    vp.write_validation_plots(res, stats, tmp_path, estimator="paper",
                              reference="corridor maximum", prefix="paper_corridor_")
    assert seen[2]._suptitle.get_text().startswith("The paper's method vs the corridor maximum")
    # the paper's method has no sigma: no bars and no legend entry for one
    nosig = res.assign(hmax_sigma=np.nan, ground_sigma=np.nan)
    vp.write_validation_plots(nosig, stats, tmp_path, estimator="paper",
                              reference="corridor maximum", prefix="paper_nosigma_")
    texts = [t.get_text() for lg in seen[4].legends for t in lg.get_texts()]
    texts += [t.get_text() for ax in seen[4].axes if ax.get_legend()
              for t in ax.get_legend().get_texts()]
    assert texts and "predicted 1-sigma error of the block" not in texts


def test_profile_shows_the_lead_estimators_with_the_paper_overlaid(monkeypatch,
                                                                   tmp_path) -> None:
    from canopyblocks.outputs import profile_plot
    from canopyblocks.photons import PhotonTrack

    seen = _capture_figures(monkeypatch, profile_plot)
    rng = np.random.default_rng(1)
    s = np.sort(rng.uniform(0, 100, 500))
    track = PhotonTrack(track="gt1r", s=s, h=300 + rng.uniform(0, 20, 500),
                        x=s, y=np.zeros(500), lon=np.zeros(500), lat=np.zeros(500),
                        time=np.zeros(500), crs="EPSG:32609")
    blocks = pd.DataFrame({"track": "gt1r", "length": 25.0, "s_start": [0.0, 25.0],
                           "s_end": [25.0, 50.0], "top": [318.0, 319.0],
                           "ground": [300.5, 300.4], "flag": "ok"})
    paper = blocks.assign(top=[312.0, 313.0], ground=[301.5, 301.4])
    profile_plot.plot_profile(track, blocks, tmp_path / "p.png", name="atl08",
                              overlay=paper, overlay_name="the paper's method")
    legend = [t.get_text() for t in seen[0].axes[0].get_legend().get_texts()]
    assert "canopy top (atl08, 25 m blocks)" in legend
    assert "canopy top (the paper's method, 25 m)" in legend


def _offer(tmp_path, monkeypatch, residuals: pd.DataFrame, reference: str = "footprint"):
    from canopyblocks.workflows import blocks as wblocks
    from canopyblocks.workflows.chain.figures import EstimatorSet
    from canopyblocks.workflows.chain.parts import _lead_bias_calibration

    monkeypatch.setattr(wblocks, "track_strengths", lambda *a, **k: {})
    corridor = residuals.assign(ref_hmax=residuals["ref_hmax"] + 6.0)  # a taller reference
    s = EstimatorSet("atl08", residuals, {}, "_atl08", corridor, pd.DataFrame())
    if reference == "footprint":
        s = s.with_footprint(residuals, pd.DataFrame())
    return _lead_bias_calibration(s, tmp_path / "photons.h5", [], 13.0, tmp_path)


def test_bias_correction_offered_when_fitted_on_the_scored_reference_and_it_helps(
        monkeypatch, tmp_path) -> None:
    """A known +4 m bias against the footprint reference: the correction is fitted against
    that reference (not the corridor maximum, 6 m taller), improves the held-out error,
    is about -4 m, is written and offered."""
    import json

    from canopyblocks.workflows.chain.report import bias_offer_part

    offer = _offer(tmp_path, monkeypatch, _residuals(offset=4.0, sd=0.5))
    assert offer.offered and offer.reference == "footprint"
    hm = offer.table[offer.table["metric"] == "hmax"].iloc[0]
    assert hm["intercept"] == pytest.approx(-4.0, abs=0.3)
    doc = json.loads((tmp_path / "bias_calibration_atl08.json").read_text())
    assert doc["reference"] == "footprint"
    words, tables = bias_offer_part(offer)
    assert words.startswith("A bias correction for the 'atl08' estimator, fitted against "
                            "the footprint-matched reference it is scored on")
    assert "-4." in words


def test_no_bias_correction_offered_when_it_does_not_improve_the_held_out_error(
        monkeypatch, tmp_path) -> None:
    """Unbiased blocks (noise only): a fitted correction cannot improve the held-out error,
    so none is offered or written, and the report says why with the numbers."""
    from canopyblocks.outputs.report import ReportSection
    from canopyblocks.workflows.chain.report import bias_offer_part

    offer = _offer(tmp_path, monkeypatch, _residuals(offset=0.0, sd=1.5, seed=3))
    assert not offer.offered
    assert not (tmp_path / "bias_calibration_atl08.json").exists()
    words, tables = bias_offer_part(offer)
    page = _page(tmp_path, [ReportSection("x", [words], tables)])
    assert re.search(r"No bias correction is offered for the 'atl08' estimator: one fitted "
                     r"against the footprint-matched reference it is scored on does not "
                     r"improve the held-out error everywhere: (hmax|h90) at 25 m goes from [\d.]+ m to "
                     r"[\d.]+ m", page), page
    assert "fitted, not offered" in page
    assert "A bias correction" not in page


def test_sigma_sentence_puts_the_observed_coverage_beside_the_prediction() -> None:
    from canopyblocks.validation.facts import fact_rows, facts_table
    from canopyblocks.validation.residuals import RESIDUAL_PAIRS
    from canopyblocks.workflows.chain.report import low_confidence_sentence

    blocks = pd.DataFrame({"flag": ["ok", "ok", "low_confidence", "low_confidence", "sparse"],
                           "hmax_sigma": [1.0, 2.0, 9.0, 12.0, np.nan]})
    # residuals 0.5 and 3.0 against sigmas 1 and 2: one within 1 sigma, both within 2
    res = pd.DataFrame({"length": 25.0, "flag": blocks["flag"], "ref_flag": "ok",
                        "use": blocks["flag"] == "ok", "hmax": [10.5, 13.0, 1, 1, np.nan],
                        "ref_hmax": [10.0, 10.0, 1, 1, 1], "hmax_sigma": blocks["hmax_sigma"]})
    facts = facts_table(fact_rows(res, estimators="atl08", reference="footprint", layer="s",
                                  pairs=RESIDUAL_PAIRS, metrics=("hmax",)))
    assert facts["left_out"].iloc[0] == "low_confidence 2; sparse 1"
    said = low_confidence_sentence(blocks, "atl08", facts)
    assert "median sigma 1.50 m" in said and "50% within 1 sigma" in said
    assert "100% within 2 sigma" in said and "flagged low_confidence" in said
    assert low_confidence_sentence(pd.DataFrame({"flag": ["ok"]}), "atl08") == ""


def test_numbers_and_simulation_headers_as_a_reader_reads_them(tmp_path) -> None:
    from canopyblocks.outputs.report import ReportSection, format_number
    from canopyblocks.workflows.chain.report import truth_report_table

    assert [format_number(v) for v in (13.0, 1.23456, -0.039, 100.0)] == \
        ["13", "1.23", "-0.04", "100"]
    t = pd.DataFrame({"diameter": [13.0, 17.0], "realisations": [100, 100],
                      "mean_cover": [0.54, 0.54], "ground_bias": [-0.116, -0.127],
                      "n_top": [11661.0, 10981.0]})
    page = _page(tmp_path, [ReportSection("x", [], {"t": truth_report_table(t)})])
    heads = re.findall(r"<th>(.*?)</th>", page)
    assert heads == ["footprint diameter (m)", "photon draws", "mean cover (fraction)",
                     "ground bias (m)", "canopy-top photons"]
    assert "<td>13</td>" in page and "13.000" not in page and "<td>-0.12</td>" in page


def test_gedi_glossary_follows_the_reference_the_run_used() -> None:
    from canopyblocks.workflows.chain.glossary import GLOSSARY, gedi_glossary_section

    terms = ["footprint-matched airborne reference", "cover", "bias", "slope class",
             "reference outside"]
    wave = " ".join(gedi_glossary_section(terms, "waveform").paragraphs)
    assert "formed into the waveform" in wave and "share of a footprint's return energy" in wave
    assert "more than 2 m" not in wave and "metres (cover: fraction)" in wave
    assert "of the footprint" in wave and "corridor" not in wave
    pts = " ".join(gedi_glossary_section(terms, "points").paragraphs)
    assert "weighted by the footprint" in pts and "formed into the waveform" not in pts
    # the photon reports keep theirs; 'reference outside' is partly covered, with values
    assert "weighted by the footprint" in GLOSSARY["footprint-matched airborne reference"]
    assert "no reference value" not in GLOSSARY["reference outside"]
    assert "less than 90 %" in GLOSSARY["reference outside"]


def test_too_few_for_an_interval_and_one_footprint_singular() -> None:
    from canopyblocks.workflows.chain.waveform_report import facts_lines, facts_sentence

    one = pd.DataFrame([{"metric": "rh98", "n": 1, "n_blocks": 1, "bias": 0.5,
                         "bias_lo": np.nan, "bias_hi": np.nan, "rmse": 0.5,
                         "rmse_lo": np.nan, "rmse_hi": np.nan, "r2": np.nan}])
    said = facts_sentence(one, {})
    assert "(n = 1 footprint; too few footprints (1) for an interval or R²)" in said
    line = " ".join(facts_lines(one, {}, "ref"))
    assert "nan" not in line and "too few footprints (1) for an interval or R²" in line
    assert "of 1 footprint " in line


def test_unseen_figures_name_their_condition_and_the_terminal_the_caveat() -> None:
    from canopyblocks.workflows.chain.glossary import UNSEEN_FIGURES, training_caveat

    assert UNSEEN_FIGURES.startswith("for the 'atl08' estimators plus an additive bias "
                                     "calibration")
    assert "lasR_bcts_1" in training_caveat(["t/lasR_bcts_1.laz"])
    assert training_caveat(["t/pyfor_test.laz"]) == ""
