"""The whole chain (`canopyblocks run`): simulated photons over a real tile -> blocks ->
real PDAL rasters -> validation -> layers, plots, report; checked by recomputation."""

from __future__ import annotations

import re
import subprocess
import sys

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import rasterio
import shapely

TILE = "als/lasR_bcts_1.laz"


@pytest.fixture(scope="module")
def chain_out(sample, pdal_bin, tmp_path_factory):
    out = tmp_path_factory.mktemp("chain")
    r = subprocess.run(
        [sys.executable, "-m", "canopyblocks", "-q", "run", str(sample(TILE)), "--seed", "3",
         "--azimuth", "15", "--length", "25", "--length", "50", "--calibrate",
         "--realisations", "20", "-o", str(out)],
        capture_output=True, text=True, timeout=600,
        env={**__import__("os").environ, "CANOPYBLOCKS_PDAL": pdal_bin},
    )
    assert r.returncode == 0, r.stderr
    return out


def test_chain_writes_every_output(chain_out) -> None:
    for name in ("photons_atl03.h5", "blocks.gpkg", "validation.gpkg", "stats.csv",
                 "report.html", "rasters/dtm.tif", "rasters/dsm_max.tif", "rasters/dsm_p90.tif",
                 "plots/profile.png", "plots/validation_25m.png", "plots/aspect_rmse_50m.png",
                 "truth_residuals.csv", "plots/truth_residuals_by_cover.png"):
        assert (chain_out / name).stat().st_size > 0, name
    html = (chain_out / "report.html").read_text()
    images = re.findall(r"<img src='([^']+)'", html)
    assert len(images) >= 5 and all((chain_out / i).exists() for i in images)
    assert not list(chain_out.rglob("*.part*")), "temporary files left behind"


def test_residuals_and_stats_recomputed_independently(chain_out) -> None:
    res = gpd.read_file(chain_out / "validation.gpkg", layer="residuals")
    stats = gpd.read_file(chain_out / "validation.gpkg", layer="stats")
    blocks = gpd.read_file(chain_out / "blocks.gpkg", layer="blocks")
    assert res.crs == blocks.crs and res.geom_type.eq("Polygon").all()
    # residual = photon minus reference, row by row
    for m in ("ground", "top", "hmax", "h90"):
        np.testing.assert_allclose(res[f"res_{m}"], res[m] - res[f"ref_{m}"], atol=1e-6,
                                   equal_nan=True)
    np.testing.assert_allclose(res["ref_hmax"], res["ref_top"] - res["ref_ground"], atol=1e-6,
                               equal_nan=True)
    # the 'all' statistics from the residual layer with plain numpy / pandas
    used = res[res["use"].astype(bool)]
    for (length, metric), row in stats[stats["group"] == "all"].set_index(
            ["length", "metric"]).iterrows():
        r = used.loc[used["length"] == length, f"res_{metric}"].dropna().to_numpy()
        assert row["n"] == r.size > 3
        assert row["bias"] == pytest.approx(r.mean(), abs=1e-6)
        assert row["rmse"] == pytest.approx(np.sqrt(np.mean(r**2)), abs=1e-6)
        assert row["mae"] == pytest.approx(np.mean(np.abs(r)), abs=1e-6)
        sub = used[used["length"] == length].dropna(subset=[metric, f"ref_{metric}"])
        fit = np.polyfit(sub[f"ref_{metric}"], sub[metric], 1)
        assert row["slope"] == pytest.approx(fit[0], rel=1e-6)
        assert row["r2"] == pytest.approx(np.corrcoef(sub[f"ref_{metric}"], sub[metric])[0, 1]
                                          ** 2, abs=1e-9)
    # aspect groups partition the blocks of each length (flat included)
    asp = stats[stats["group"].str.startswith("aspect:")]
    total = stats[stats["group"] == "all"].set_index(["length", "metric"])["n"]
    summed = asp.groupby(["length", "metric"])["n"].sum()
    pd.testing.assert_series_equal(summed.sort_index(), total.sort_index(), check_names=False,
                                   check_dtype=False)


def test_reference_values_from_the_rasters_by_brute_force(chain_out) -> None:
    """ref_ground = mean of DTM cells touched by the corridor; ref_top = max of DSM cells."""
    res = gpd.read_file(chain_out / "validation.gpkg", layer="residuals")
    with rasterio.open(chain_out / "rasters/dtm.tif") as d, \
            rasterio.open(chain_out / "rasters/dsm_max.tif") as m:
        dtm, dsm, tr, nod = d.read(1), m.read(1), d.transform, d.nodata
    res_x, res_y = tr.a, -tr.e
    rows = res[res["ref_flag"] == "ok"].head(12)
    assert len(rows) >= 8
    for _, b in rows.iterrows():
        poly = b.geometry
        x0, y0, x1, y1 = poly.bounds
        c0, c1 = int((x0 - tr.c) // res_x), int((x1 - tr.c) // res_x)
        r0, r1 = int((tr.f - y1) // res_y), int((tr.f - y0) // res_y)
        g, t = [], []
        for r in range(max(r0, 0), min(r1 + 1, dtm.shape[0])):
            for c in range(max(c0, 0), min(c1 + 1, dtm.shape[1])):
                cell = shapely.box(tr.c + c * res_x, tr.f - (r + 1) * res_y,
                                   tr.c + (c + 1) * res_x, tr.f - r * res_y)
                if cell.intersects(poly):
                    if dtm[r, c] != nod:
                        g.append(dtm[r, c])
                    if dsm[r, c] != nod:
                        t.append(dsm[r, c])
        assert b["ref_ground"] == pytest.approx(np.mean(g), abs=1e-4)
        assert b["ref_top"] == pytest.approx(np.max(t), abs=1e-4)


def test_simulated_photons_keep_the_tile_datum_and_ids(chain_out) -> None:
    blocks = gpd.read_file(chain_out / "blocks.gpkg", layer="blocks")
    res = gpd.read_file(chain_out / "validation.gpkg", layer="residuals")
    assert blocks.crs.to_epsg() == 3005  # the tile's CRS, not a UTM zone
    assert set(pd.unique(blocks["length"])) == {25.0, 50.0}
    key = ["track", "length", "block"]
    assert res[key].merge(blocks[key]).shape[0] == len(res) == len(blocks)
    ok = res[res["use"].astype(bool)]
    # ground from photons within a metre or two of the DTM (seed 001: ground is robust)
    assert ok["res_ground"].abs().median() < 2.0


def test_calibration_outputs(chain_out) -> None:
    cal = pd.read_csv(chain_out / "calibration.csv")
    assert list(cal["length"]) == [25.0, 50.0]
    assert ((cal["top_cutoff"] > 0) & (cal["top_cutoff"] < 1)).all()
    assert (cal["n_holdout"] > 3).all() and np.isfinite(cal["rmse_hmax_calibrated"]).all()
    import pyogrio

    layers = {n for n, _ in pyogrio.list_layers(chain_out / "validation.gpkg")}
    assert {"residuals", "stats", "residuals_calibrated", "stats_calibrated"} <= layers
    assert "Calibrated cut-offs" in (chain_out / "report.html").read_text()


def test_seed002_analysis_of_the_simulation(chain_out) -> None:
    """Seed 002's photon classification against footprint truth, 13 and 17 m footprints."""
    t = pd.read_csv(chain_out / "truth_residuals.csv")
    assert sorted(t["diameter"]) == [13.0, 17.0]
    assert (t["realisations"] == 20).all()
    # the ground rule (min of 20 photons + 3 PSF) is unbiased within decimetres over a real
    # forest floor; the canopy-top rule (max of 20 - 1 m) lands metres below the highest return
    assert (t["ground_bias"].abs() < 0.5).all() and (t["ground_rms"] < 1.5).all()
    assert (t["top_bias"] < -1.0).all()


def _section(html: str, heading: str) -> str:
    for part in html.split("<h2>")[1:]:
        if part.startswith(heading):
            return part
    raise AssertionError(f"no section {heading!r}")


def _table_rows(section: str) -> list[list[str]]:
    body = section.split("<tbody>")[1].split("</tbody>")[0]
    return [re.findall(r"<td>(.*?)</td>", tr, flags=re.S)
            for tr in re.findall(r"<tr>(.*?)</tr>", body, flags=re.S)]


def test_report_opens_with_the_recommended_estimators_like_with_like(chain_out) -> None:
    """The first section names the recommended preset, and every number of its sentence
    and table equals a re-computation from the residual layer it names (plain numpy)."""
    import html as markup

    from canopyblocks.blocks.estimators import RECOMMENDED_PRESET

    page = markup.unescape((chain_out / "report.html").read_text())
    first = page.split("<h2>")[1]
    assert first.startswith("Summary")
    assert f"The recommended estimators, '{RECOMMENDED_PRESET}'" in first
    assert "footprint-matched" in first and "<img src='plots/residual_map.png'" in first
    layer = re.search(r"layer '([a-z0-9_]+)' of validation.gpkg", first).group(1)
    # the recommended estimators are the default: the run's own layers hold them
    assert layer == "stats_footprint"
    res = gpd.read_file(chain_out / "validation.gpkg", layer="residuals_footprint")
    blocks = gpd.read_file(chain_out / "blocks.gpkg", layer="blocks")
    assert set(blocks["estimators"]) == {"noise=atl08,ground=atl08,top=atl08"}
    used = res[res["use"].astype(bool)]
    truth = {}
    for length in (25.0, 50.0):
        for m in ("ground", "hmax"):
            sub = used[used["length"] == length].dropna(subset=[m, f"ref_{m}"])
            r = (sub[m] - sub[f"ref_{m}"]).to_numpy()
            truth[(length, m)] = (r.size, r.mean(), np.sqrt(np.mean(r ** 2)),
                                  np.corrcoef(sub[f"ref_{m}"], sub[m])[0, 1] ** 2)
            assert r.size >= 3
    # 'At 25 m: ground bias +0.07 m (95 % interval +0.01 to +0.12 m), RMSE 0.16 m (0.12 to
    # 0.20 m), R² 0.96 (n = 21 blocks); canopy height (Hmax) ...'
    ci = r" \([^)]*\)"
    said = re.search(rf"At 25 m: ground bias ([-+.\d]+) m{ci}, RMSE ([.\d]+) m{ci}, "
                     rf"R² ([.\d]+) \(n = (\d+) blocks\); canopy height \(Hmax\) bias "
                     rf"([-+.\d]+) m{ci}, RMSE ([.\d]+) m{ci}, R² ([.\d]+) \(n = (\d+) "
                     r"blocks\)", first)
    assert said, first[:1500]
    # every length said, not only 25 m; the layer names its reference's statistic and
    # gives every block left out one reason
    assert "At 50 m: ground bias" in first
    assert set(res["ref_statistic"]) == {"pooled"}
    assert "statistic 'pooled'" in first
    left = res[~res["use"].astype(bool)]
    assert (left["reason"].fillna("") != "").all()
    assert (res.loc[res["use"].astype(bool), "reason"].fillna("") == "").all()
    g, h = truth[(25.0, "ground")], truth[(25.0, "hmax")]
    got = [float(v) for v in said.groups()]
    want = [g[1], g[2], g[3], g[0], h[1], h[2], h[3], h[0]]
    for a, b in zip(got, want):
        assert a == pytest.approx(b, abs=0.0051)
    # the table: length, metric, n, bias, rmse, r2 for every length
    rows = _table_rows(first)
    assert len(rows) == 4
    for length, metric, n, bias, _bci, rmse, _rci, r2, _all, _left in rows:
        t = truth[(float(length), "hmax" if "Hmax" in metric else metric)]
        assert int(n) == t[0]
        for a, b in zip((bias, rmse, r2), t[1:]):  # printed to the centimetre
            assert float(a) == pytest.approx(b, abs=0.0051)
    # the paper's method comes second, against the same reference, with its bias stated
    second = page.split("<h2>")[2]
    assert second.startswith("The paper's method") and "footprint-matched" in second


def test_report_tables_have_integer_lengths_units_no_intercepts_no_tiny_groups(
        chain_out) -> None:
    html = (chain_out / "report.html").read_text()
    assert "intercept" not in html
    assert "<th>length (m)</th>" in html and "<th>RMSE (m)</th>" in html
    assert not re.search(r"<td>\d+\.0+</td>\s*<td>(ground|top|hmax|h90)</td>", html)
    ns = [int(n) for n in re.findall(r"<td>(?:aspect|slope) [^<]*</td>\s*<td>(\d+)</td>", html)]
    assert ns and min(ns) >= 3


def test_no_internal_names_in_output_files(chain_out) -> None:
    names = [p.relative_to(chain_out).as_posix() for p in chain_out.rglob("*")]
    assert names and not [n for n in names if "seed0" in n.lower()], names
    page = (chain_out / "report.html").read_text().lower()
    assert "seed 00" not in page and "seed00" not in page


def _sections(page: str) -> dict[str, str]:
    return {s.split("</h2>")[0]: s for s in page.split("<h2>")[1:]}


def test_report_figures_and_bias_offer_agree_with_the_headline(chain_out) -> None:
    """The summary's estimators and reference are those of its map, profile and the
    plain-named scatter plots; the paper's method against the corridor maximum is a
    section of its own with its own figures; a bias correction is offered only when it was
    fitted against the footprint reference the headline scores on and improved every
    held-out error."""
    import html as markup
    import json

    from canopyblocks.blocks.estimators import RECOMMENDED_PRESET

    page = markup.unescape((chain_out / "report.html").read_text())
    sec = _sections(page)
    summary = sec["Summary"]
    assert f"'{RECOMMENDED_PRESET}'" in summary and "footprint-matched" in summary
    assert "<img src='plots/residual_map.png'" in summary
    assert "<img src='plots/profile.png'" in summary
    from canopyblocks.workflows.chain.report import FOOTPRINT_WORDS

    details = sec[f"The '{RECOMMENDED_PRESET}' estimator against the {FOOTPRINT_WORDS}: "
                  "details"]
    assert "<img src='plots/validation_25m.png'" in details
    paper = sec["The paper's method against the corridor maximum"]
    assert "<img src='plots/paper_corridor_validation_25m.png'" in paper
    assert "plots/validation_25m.png" not in paper
    for other in (s for h, s in sec.items() if "corridor maximum" not in h):
        assert "paper_corridor_" not in other
    # bias: offered only with a footprint-fitted, held-out-improving calibration
    files = sorted(chain_out.glob("bias_calibration_*.json"))
    offered = "A bias correction for" in page
    assert offered == bool(files)
    for f in files:
        doc = json.loads(f.read_text())
        assert doc["reference"] == "footprint"
        for m in doc["models"]:
            assert m["holdout_rmse_after"] < m["holdout_rmse_before"]
    if not offered:
        assert f"No bias correction is offered for the '{RECOMMENDED_PRESET}' estimator" \
            in summary
    assert "corridor maximum it is scored on" not in page


def test_cutoffs_on_the_grid_edge_are_named(chain_out) -> None:
    from canopyblocks.blocks.calibration import DEFAULT_GRID

    cal = pd.read_csv(chain_out / "calibration.csv")
    edge = {min(DEFAULT_GRID), max(DEFAULT_GRID)}
    on_edge = [(c, v) for c in ("top_cutoff", "ground_cutoff") for v in cal[c] if v in edge]
    page = (chain_out / "report.html").read_text()
    sec = _sections(page)["Calibrated cut-offs of the paper&#x27;s method"]
    assert ("On the edge of the searched grid" in sec) == bool(on_edge)
    for c, v in on_edge:
        assert f"the {c.split('_')[0]} cut-off {v:g} of the" in sec


def test_report_when_the_blocks_are_made_with_the_recommended_estimators(
        sample, pdal_bin, tmp_path) -> None:
    """``run --preset atl08``: the summary leads with the user's blocks (layer
    ``stats_footprint``), and the paper's method is computed beside them for its own
    sections (layers ``*_paper``), its corridor figures named as such."""
    import html as markup

    out = tmp_path / "atl08"
    r = subprocess.run(
        [sys.executable, "-m", "canopyblocks", "-q", "run", str(sample(TILE)), "--seed", "3",
         "--azimuth", "15", "--length", "25", "--preset", "atl08", "--realisations", "0",
         "-o", str(out)],
        capture_output=True, text=True, timeout=600,
        env={**__import__("os").environ, "CANOPYBLOCKS_PDAL": pdal_bin})
    assert r.returncode == 0, r.stderr
    page = markup.unescape((out / "report.html").read_text())
    sec = _sections(page)
    assert "layer 'stats_footprint' of validation.gpkg" in sec["Summary"]
    assert "The recommended estimators, 'atl08'" in sec["Summary"]
    assert "'stats_footprint_paper'" in sec["The paper's method and its known bias"]
    assert "'stats_paper'" in sec["The paper's method against the corridor maximum"]
    assert "Block heights written (the 'atl08' estimator)" in sec
    assert (out / "plots" / "paper_corridor_validation_25m.png").exists()
    import pyogrio

    layers = {n for n, _ in pyogrio.list_layers(out / "validation.gpkg")}
    assert {"stats_footprint", "stats_paper", "stats_footprint_paper"} <= layers
