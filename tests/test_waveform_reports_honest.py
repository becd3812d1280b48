"""The waveform reports (``run --sensor gedi|esfl|dual``) read as a reviewer would: the
independent airborne quantities lead, a simulation's round trip is named as such, no
interval, R² or "validated" below 10 footprints, no R² of an elevation, every terminal
warning about an input repeated, the simulation's settings stated."""

from __future__ import annotations

import ast
import html
import re
import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest


def _run(*args: object) -> subprocess.CompletedProcess[str]:
    r = subprocess.run([sys.executable, "-m", "canopyblocks", "run", *map(str, args)],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    return r


def _text(out: Path) -> str:
    page = (out / "report.html").read_text(encoding="utf-8")
    page = re.sub(r"<style>.*?</style>", "", page, flags=re.S)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", page)).split())


@pytest.fixture(scope="module")
def runs(sample, tmp_path_factory) -> dict[str, tuple[Path, str]]:
    tmp = tmp_path_factory.mktemp("waveform_reports")
    out = {}
    for name, tiles, seed in (("gedi", ["als/lasR_bcts_1.laz", "als/lasR_bcts_2.laz"], 0),
                              ("dual", ["als/lidR_MixedConifer.laz"], 1),
                              ("esfl", ["als/lidR_MixedConifer.laz"], 1)):
        o = tmp / name
        r = _run(*[sample(t) for t in tiles], "--sensor", name, "--seed", seed, "-o", o)
        out[name] = (o, r.stdout + r.stderr)
    return out


def _facts(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / "facts.csv", keep_default_na=False, na_values=[""])


def test_gedi_leads_with_the_independent_airborne_quantities(runs) -> None:
    out, terminal = runs["gedi"]
    text = _text(out)
    summary = text[text.index("Summary"):text.index("Inputs")]
    assert "validated" not in text.lower()
    ind = summary.index("Against the independent airborne quantities under each footprint")
    trip = summary.index("Round trip, not an independent check")
    assert ind < trip
    facts = _facts(out)
    # the footprint's size is named for what it is
    assert "footprint_diameter" in facts and "length" not in facts
    assert set(facts["footprint_diameter"]) == {22.0}
    assert set(facts["reference"]) == {"airborne points", "waveform-formed"}
    # the independent numbers recomputed from the layer: footprint minus class-2 ground
    res = gpd.read_file(out / "validation.gpkg", layer="residuals_footprints")
    use = res["use"].astype(bool).to_numpy()
    d = (res["ground"] - res["ref_ground_points"]).to_numpy(float)[use]
    d = d[np.isfinite(d)]
    row = facts[(facts["reference"] == "airborne points")
                & (facts["metric"] == "ground")].iloc[0]
    assert int(row["n"]) == d.size
    assert row["bias"] == pytest.approx(d.mean(), abs=1e-3)
    assert row["rmse"] == pytest.approx(np.sqrt(np.mean(d * d)), abs=1e-3)
    # the waveform's lowest mode sits above the class-2 ground (what simulate's terminal
    # showed), the round trip near zero: the two must differ
    trip_row = facts[(facts["reference"] == "waveform-formed")
                     & (facts["metric"] == "ground")].iloc[0]
    assert abs(trip_row["bias"]) < 0.15 and row["bias"] > 0.2
    assert f"ground bias {row['bias']:+.2f} m" in summary[ind:trip]
    # no R² of an elevation (the relief alone would make it 1.00), R² of heights only
    assert np.isnan(row["r2"]) and np.isnan(trip_row["r2"])
    assert not re.search(r"ground bias [^;]*R²", summary)
    rh98 = facts[(facts["reference"] == "airborne points") & (facts["metric"] == "rh98")]
    if int(rh98["n"].iloc[0]) >= 10:
        assert np.isfinite(rh98["r2"].iloc[0])
    # the terminal leads with the same independent numbers
    assert terminal.index("independent airborne quantities") < terminal.index("round trip")
    # the simulation's settings are in the inputs
    inputs = text[text.index("Inputs"):]
    assert "Simulation settings: a shot every 60 m" in inputs


def test_dual_gives_no_interval_or_r2_below_ten_footprints(runs) -> None:
    out, terminal = runs["dual"]
    text = _text(out)
    facts = _facts(out)
    assert "validated" not in text.lower()
    few = facts[facts["n"] < 10]
    assert len(few) == len(facts), facts    # a 90 m tile: 6 footprints
    assert few[["bias_lo", "bias_hi", "rmse_lo", "rmse_hi", "r2"]].isna().all().all()
    for r in few.itertuples():
        assert f"too few footprints ({int(r.n)}) for an interval or R²" in text
        assert f"too few footprints ({int(r.n)}) for an interval or R²" in terminal
    # no interval or R² printed with a count under 10
    for m in re.finditer(r"\(n = (\d+) footprints?", text):
        before = text[max(0, m.start() - 120):m.start()]
        if int(m.group(1)) < 10:
            assert "95 % interval" not in before.split(";")[-1] and "R²" not in \
                before.split(";")[-1]
    # the settings the pairs were simulated and read with
    assert "Simulation settings: noise sd 0.05 of each pair's near-infrared peak" in text
    assert "leaves 0.05, 0.45 and of soil 0.15, 0.25" in text
    assert "the dual-wavelength method 'paper'" in text
    # the independent points lead, the pair formed from them is the round trip
    assert text.index("Against the independent airborne points under each footprint") \
        < text.index("Round trip, not an independent check")


def test_esfl_repeats_the_terminal_warning_and_states_its_settings(runs) -> None:
    out, terminal = runs["esfl"]
    text = _text(out)
    assert "height-normalised" in terminal
    summary = text[text.index("Summary"):text.index("Inputs and method")]
    assert "Warnings about the inputs (as on the terminal): (1)" in summary
    assert "looks height-normalised" in summary
    assert "Simulation settings: noise sd 0.05 of the mean brightest-pixel peak" in text
    assert "Reading: energy fraction f = " in text
    facts = _facts(out)
    assert "cell_size" in facts and "length" not in facts
    stats = pd.read_csv(out / "stats.csv")
    assert "cell_size" in stats and "length" not in stats
    # elevations (ground, top) carry no R² and no fit, in facts.csv and in the table
    elev = facts[facts["metric"].isin(["ground", "top"])]
    assert elev["r2"].isna().all()
    assert not re.search(r"ground elevation bias [^;]*R²", text)
    page = (out / "report.html").read_text(encoding="utf-8")
    table = re.findall(r"<table.*?</table>", page, flags=re.S)[-1]
    heads = re.findall(r"<th>(.*?)</th>", table)
    for tr in re.findall(r"<tr>(.*?)</tr>", table, flags=re.S):
        cells = dict(zip(heads, re.findall(r"<td>(.*?)</td>", tr, flags=re.S)))
        if cells.get("metric") in ("ground", "top"):
            assert all(cells.get(c, "") == "" for c in heads if c.startswith(("R²", "slope"))
                       ), cells


def test_no_internal_section_numbers_in_user_strings() -> None:
    """No string a user can read (every literal but docstrings) names a DESIGN section."""
    root = Path(__file__).parents[1] / "core"
    found = []
    for p in root.rglob("*.py"):
        tree = ast.parse(p.read_text(encoding="utf-8"))
        docs = {id(n.body[0].value) for n in ast.walk(tree)
                if isinstance(n, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef,
                                  ast.ClassDef))
                and n.body and isinstance(n.body[0], ast.Expr)
                and isinstance(n.body[0].value, ast.Constant)}
        found += [f"{p.name}:{n.lineno}" for n in ast.walk(tree)
                  if isinstance(n, ast.Constant) and isinstance(n.value, str)
                  and "DESIGN" in n.value and id(n) not in docs]
    assert found == []
