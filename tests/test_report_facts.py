"""Every count, n, bias and RMSE a report prints agrees with the run's own layers.

``canopyblocks run`` is run five ways (simulated photons over a bundled tile, with the
cut-off calibration; simulated photons over a freshly made tile; GEDI; ESFL; dual), each
small.  For each: the numbers of ``facts.csv`` are recomputed from the residual layers
of ``validation.gpkg`` (use = true and both values finite); every sentence of the
report stating a bias, RMSE and n, every count sentence, every statistics-table row,
and every terminal summary line is found among them; the counts add up; and each block
has one terrain class in every layer.  Nothing here pins a value: the sigma model and
the flags may change, the report must still agree with itself.
"""

from __future__ import annotations

import html
import os
import re
import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import laspy
import numpy as np
import pandas as pd
import pyogrio
import pyproj
import pytest

TILE = "als/lasR_bcts_1.laz"
_PAIRS = {"ground": "ref_ground", "top": "ref_top", "hmax": "ref_hmax", "h90": "ref_h90",
          "rh98": "ref_rh98", "rh50": "ref_rh50", "cover": "ref_cover",
          "height": "ref_height"}


def _run(*args: object, pdal: str) -> subprocess.CompletedProcess[str]:
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "run", *map(str, args)],
                       capture_output=True, text=True, timeout=600,
                       env={**os.environ, "CANOPYBLOCKS_PDAL": pdal})
    assert r.returncode == 0, r.stderr
    return r


def _fresh_tile(path: Path, seed: int = 4) -> None:
    """A 160 m tile never seen by the project: a 6 degree slope facing east, round
    crowns 8-24 m tall on 60 % of it, ground points (class 2) under the gaps."""
    rng = np.random.default_rng(seed)
    n = 160 * 160 * 8
    x = rng.uniform(0, 160, n)
    y = rng.uniform(0, 160, n)
    zg = 200.0 - np.tan(np.radians(6.0)) * x
    cx = rng.uniform(0, 160, 260)
    cy = rng.uniform(0, 160, 260)
    ch = rng.uniform(8, 24, 260)
    cr = rng.uniform(2.5, 4.5, 260)
    d2 = (x[:, None] - cx) ** 2 + (y[:, None] - cy) ** 2
    inside = d2 <= cr ** 2
    k = np.where(inside.any(axis=1), np.argmax(inside, axis=1), -1)
    crown = k >= 0
    height = np.where(crown, ch[k] * (1 - 0.5 * rng.uniform(0, 1, n)), 0.0)
    hit_ground = ~crown | (rng.uniform(0, 1, n) < 0.25)
    z = np.where(hit_ground, zg, zg + height)
    cls = np.where(hit_ground, 2, 5).astype(np.uint8)
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = [0.01, 0.01, 0.01]
    hdr.offsets = [600_000.0, 5_000_000.0, 0.0]
    hdr.add_crs(pyproj.CRS("EPSG:32610"))
    las = laspy.LasData(hdr)
    las.x = x + 600_000.0
    las.y = y + 5_000_000.0
    las.z = z
    las.classification = cls
    las.write(path)


@pytest.fixture(scope="module")
def runs(sample, pdal_bin, tmp_path_factory) -> dict[str, tuple[Path, str]]:
    tmp = tmp_path_factory.mktemp("report_facts")
    tile = sample(TILE)
    fresh = tmp / "fresh.las"
    _fresh_tile(fresh)
    out: dict[str, tuple[Path, str]] = {}
    for name, args in (
        ("photons", (tile, "--seed", "3", "--azimuth", "15", "--length", "25", "--length",
                     "50", "--calibrate", "--realisations", "0")),
        ("fresh", (fresh, "--seed", "5", "--length", "25", "--realisations", "0")),
        ("gedi", (tile, "--sensor", "gedi", "--seed", "1")),
        ("esfl", (tile, "--sensor", "esfl", "--seed", "1")),
        ("dual", (tile, "--sensor", "dual", "--seed", "1")),
    ):
        o = tmp / name
        r = _run(*args, "-o", o, pdal=pdal_bin)
        out[name] = (o, r.stdout + r.stderr)
    return out


def _text(path: Path) -> str:
    page = (path / "report.html").read_text(encoding="utf-8")
    page = re.sub(r"<style>.*?</style>", "", page, flags=re.S)
    return html.unescape(re.sub(r"<[^>]+>", " ", page))


def _tables(path: Path) -> list[pd.DataFrame]:
    """The report's tables (header cells, body cells), read without a parser library."""
    page = (path / "report.html").read_text(encoding="utf-8")
    out = []
    for t in re.findall(r"<table.*?</table>", page, flags=re.S):
        heads = [html.unescape(h.strip()) for h in re.findall(r"<th>(.*?)</th>", t, re.S)]
        rows = [[html.unescape(c.strip()) for c in re.findall(r"<td>(.*?)</td>", tr, re.S)]
                for tr in re.findall(r"<tr[^>]*>(.*?)</tr>", t, flags=re.S)]
        rows = [r for r in rows if len(r) == len(heads)]
        out.append(pd.DataFrame(rows, columns=heads))
    return out


def _residual_layer(gpkg: Path, stats_layer: str) -> pd.DataFrame:
    return gpd.read_file(gpkg, layer=stats_layer.replace("stats", "residuals", 1))


def _recomputed(res: pd.DataFrame, length: float, metric: str, reference: str = ""
                ) -> tuple[int, float, float, int]:
    """n, bias, RMSE and all rows of one length and metric, from a residuals layer (a
    waveform run's independent comparison: the points' own column, and footprints whose
    formed reference found no ground kept)."""
    sub = res[np.isclose(res["length"], length)] if "length" in res else res
    y = sub[metric].to_numpy(float)
    # the points' own column beside a formed reference (ESFL's reference is the points)
    points = reference == "airborne points" and f"{_PAIRS[metric]}_points" in sub
    x = sub[_PAIRS[metric] + ("_points" if points else "")].to_numpy(float)
    use = sub["use"].astype(bool).to_numpy()
    if points:
        use = use | ((sub["flag"] == "no_ground") & (sub["ref_flag"] == "no_ground")).to_numpy()
    use = use & np.isfinite(x) & np.isfinite(y)
    r = y[use] - x[use]
    n = int(use.sum())
    if not n:
        return 0, np.nan, np.nan, len(sub)
    return n, float(r.mean()), float(np.sqrt(np.mean(r * r))), len(sub)


def _facts(out: Path) -> pd.DataFrame:
    f = pd.read_csv(out / "facts.csv", keep_default_na=False, na_values=[""])
    assert len(f) and set(f["reference"]) <= {"footprint", "corridor", "airborne points",
                                              "waveform-formed"}
    # a waveform run names its size for what it is: the footprint diameter or cell size
    return f.rename(columns={"footprint_diameter": "length", "cell_size": "length"})


RUNS = ("photons", "fresh", "gedi", "esfl", "dual")


@pytest.mark.parametrize("name", RUNS)
def test_facts_recomputed_from_the_layers(runs, name) -> None:
    out, _ = runs[name]
    facts = _facts(out)
    gpkg = out / "validation.gpkg"
    for r in facts.itertuples():
        res = _residual_layer(gpkg, r.layer)
        n, bias, rmse, n_all = _recomputed(res, r.length, r.metric, r.reference)
        assert (n, r.n_blocks) == (r.n, n_all), r
        if n:
            assert bias == pytest.approx(r.bias, abs=1e-3), r
            assert rmse == pytest.approx(r.rmse, abs=1e-3), r
            if n >= 2 and np.isfinite(r.bias_lo):
                assert r.bias_lo <= r.bias <= r.bias_hi and r.rmse_lo <= r.rmse <= r.rmse_hi
            elif n >= 2:   # a waveform run gives no interval below 10 footprints
                assert n < 10 and r.interval == "none", r
        # every block left out is counted, by reason, and they add up
        why = r.left_out if isinstance(r.left_out, str) else ""
        left = sum(int(p.rsplit(" ", 1)[1]) for p in why.split("; ") if p)
        assert r.n + left == r.n_blocks, r


def _close(a: float, b: float) -> bool:
    """``b`` printed to 2 decimals from the value ``a`` that facts.csv holds to 4: within
    half a cent plus facts.csv's rounding (0.7350 printed as 0.74 from 0.73504)."""
    return abs(float(a) - float(b)) <= 0.0051


@pytest.mark.parametrize("name", RUNS)
def test_every_number_in_the_text_is_a_fact(runs, name) -> None:
    out, terminal = runs[name]
    facts = _facts(out)
    text = " ".join(_text(out).split())
    said = re.findall(   # a waveform run below 10 footprints gives no interval or R²
        r"bias ([-+]\d+\.\d\d)(?: m)?(?: \(95 % interval ([-+]\d+\.\d\d) to "
        r"([-+]\d+\.\d\d)(?: m)?\))?, RMSE (\d+\.\d\d)(?: m)?(?: \((\d+\.\d\d) to "
        r"(\d+\.\d\d)(?: m)?\))?(?:, R² (\S+))? \(n = (\d+) (?:blocks|footprints?)[;)]",
        text)
    assert said, text[:2000]
    for b, blo, bhi, rm, rlo, rhi, _r2, n in said:
        printed = {k: v for k, v in dict(bias=b, rmse=rm, bias_lo=blo, bias_hi=bhi,
                                         rmse_lo=rlo, rmse_hi=rhi).items() if v}
        assert _has(facts, int(n), **printed), (b, rm, n)
    # the terminal says the same numbers
    lines = re.findall(r"n=(\d+)\D.*?bias=([-+]\d+\.\d\d).*?rmse=(\d+\.\d\d)", terminal)
    assert lines, terminal
    for n, b, rm in lines:
        assert _has(facts, int(n), bias=b, rmse=rm), (n, b, rm)


def _has(facts: pd.DataFrame, n: int, **printed: str) -> bool:
    """A facts row of ``n`` whose columns round to the ``printed`` numbers."""
    hit = facts["n"] == n
    for col, text in printed.items():
        hit &= np.array([_close(v, text) for v in facts[col]], dtype=bool)
    return bool(hit.any())


@pytest.mark.parametrize("name", RUNS)
def test_counts_add_up_to_the_layers(runs, name) -> None:
    out, _ = runs[name]
    facts = _facts(out)
    text = " ".join(_text(out).split())
    blocks = re.findall(r"the statistics use (\d+) of the (\d+) blocks \(([^)]*)\); left "
                        r"out, by reason: (.*?) \((\d+) blocks\)", text)
    feet = re.findall(r"the statistics of (\w+) use (\d+) of the (\d+) footprints; left "
                      r"out, by reason: ([^.]*)\.", text)
    assert blocks or feet, text[:1500]
    for used, total, _per, reasons, left in blocks:
        assert int(used) + int(left) == int(total)
        assert sum(int(p.rsplit(" ", 1)[1]) for p in reasons.split("; ") if p != "none") \
            == int(left)
        hm = facts[facts["metric"] == "hmax"].groupby(["estimators", "reference"])[
            ["n", "n_blocks"]].sum()
        assert ((hm["n"] == int(used)) & (hm["n_blocks"] == int(total))).any()
    for metric, used, total, reasons in feet:
        rows = facts[facts["metric"] == metric]
        assert ((rows["n"] == int(used)) & (rows["n_blocks"] == int(total))).any()
        assert int(used) + sum(int(p.rsplit(" ", 1)[1]) for p in reasons.split("; ")
                               if p != "none") == int(total)


@pytest.mark.parametrize("name", RUNS)
def test_every_table_row_is_in_a_layer(runs, name) -> None:
    """Each row of a statistics table (n, bias, RMSE) is a row of a stats layer."""
    out, _ = runs[name]
    gpkg = out / "validation.gpkg"
    known: set[tuple[int, str, str]] = set()
    for layer in pyogrio.list_layers(gpkg)[:, 0]:
        if layer.startswith("stats"):
            s = gpd.read_file(gpkg, layer=layer)
            known |= {(int(r.n), f"{r.bias:.2f}", f"{r.rmse:.2f}") for r in s.itertuples()
                      if np.isfinite(r.bias)}
    checked = 0
    for t in _tables(out):
        ncol = next((c for c in t.columns if c.startswith("n (")), None)
        if ncol is None or "bias (m)" not in t or "RMSE (m)" not in t:
            continue
        for r in t.itertuples(index=False):
            row = dict(zip(t.columns, r))
            if not row["bias (m)"]:
                continue
            key = (int(row[ncol]), f"{float(row['bias (m)']):.2f}",
                   f"{float(row['RMSE (m)']):.2f}")
            assert key in known, (key, t.columns.tolist())
            checked += 1
    assert checked


@pytest.mark.parametrize("name", ("photons", "fresh"))
def test_each_block_has_one_terrain_class_everywhere(runs, name) -> None:
    out, _ = runs[name]
    gpkg = out / "validation.gpkg"
    seen: dict[tuple[str, float, int], tuple[str, str]] = {}
    n_layers = 0
    for layer in pyogrio.list_layers(gpkg)[:, 0]:
        if not layer.startswith("residuals"):
            continue
        n_layers += 1
        res = gpd.read_file(gpkg, layer=layer)
        for r in res.itertuples():
            key = (str(r.track), float(r.length), int(r.block))
            cls = (str(r.aspect_class), str(r.slope_class))
            assert seen.setdefault(key, cls) == cls, (layer, key, seen[key], cls)
    assert n_layers >= 3


def test_calibration_rmse_and_n_are_of_one_set_of_blocks(runs) -> None:
    """The held-out RMSE of the default cut-offs is over the n held out blocks: where
    those are all the paper's blocks used, it is the paper's RMSE of its statistics."""
    out, _ = runs["photons"]
    cal = pd.read_csv(out / "calibration.csv")
    paper = gpd.read_file(out / "validation.gpkg", layer="stats_paper")
    matched = 0
    for r in cal.itertuples():
        p = paper[(paper["group"] == "all") & (paper["metric"] == "hmax")
                  & np.isclose(paper["length"], r.length)].iloc[0]
        if int(p["n"]) == int(r.n_holdout):
            assert r.rmse_hmax_default == pytest.approx(p["rmse"], abs=0.01)
            matched += 1
    assert matched


def test_waveform_words(runs) -> None:
    out, _ = runs["gedi"]
    text = " ".join(_text(out).split())
    assert "is not an acquisition: it was simulated" in text
    assert "Footprint diameter 22 m" in text
    stats = pd.read_csv(out / "stats.csv")
    assert "footprint_diameter" in stats and "length" not in stats
    covers = [g for g in stats["group"] if str(g).startswith("cover:")]
    assert covers and all(re.fullmatch(r"cover:(0(\.\d+)?-(0\.\d+|1)|unknown)", g)
                          for g in covers), covers
    assert "Glossary" in text and "r2" not in text
    # the glossary defines the reference and cover the way this run formed them
    gloss = text[text.index("Glossary"):]
    assert "formed into the waveform" in gloss and "more than 2 m above" not in gloss
    assert "setting only its detection thresholds" in text


def test_photon_report_says_what_facts_csv_holds(runs) -> None:
    out, said = runs["photons"]
    text = " ".join(_text(out).split())
    assert "facts.csv holds every number" not in text
    assert "stats.csv (the run's own blocks" in text and "corridor maximum" in text
    assert "for the 'atl08' estimators plus an additive bias calibration" in text
    # the terminal says the report's first caveat (the tiles are the fitted ones)
    assert "are the tiles the recommended estimators and the sigma model were fitted on" \
        in said
