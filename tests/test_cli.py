"""The command line end to end: `info`, `blocks` on real and simulated files, exit codes.

The block layer written by `canopyblocks blocks` is compared block by block with the plain
per-block implementation of DESIGN.md section 1 in tests/test_blocks_oracle.py.
"""

from __future__ import annotations

import json
import subprocess
import sys

import geopandas as gpd
import numpy as np
import pyogrio
import pytest

from canopyblocks import BlockParams, read_atl03, read_mabel
from canopyblocks.cli import main
from canopyblocks.schema import BLOCK_COLUMNS
from test_blocks_oracle import expected_flags, oracle

LENGTHS = (10.0, 25.0, 50.0)
ATL03 = "icesat2/vegr_atl03_clip.h5"


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "canopyblocks", "-q", *args],
                          capture_output=True, text=True, timeout=300)


def check_against_oracle(track, blocks: gpd.GeoDataFrame, params: BlockParams) -> int:
    """Compare every block of every length with the oracle; return the number compared."""
    n = 0
    for length in params.lengths:
        rows, _ = oracle(track.s, track.h, track.signal_conf, params, length)
        got = blocks[(blocks["length"] == length) & (blocks["track"] == track.track)]
        got = got.sort_values("block")
        assert list(got["block"]) == [r["block"] for r in rows]
        for col in ("n_photons", "n_kept", "n_between"):
            assert list(got[col]) == [r[col] for r in rows], col
        for col in ("top", "ground", "z90"):
            np.testing.assert_allclose(got[col].to_numpy(), [r[col] for r in rows],
                                       rtol=0, atol=1e-9, err_msg=col)
        assert list(got["flag"]) == expected_flags(rows)
        n += len(rows)
    return n


def test_blocks_on_the_real_atl03_clip_matches_the_oracle(sample, tmp_path) -> None:
    out = tmp_path / "out.gpkg"
    png = tmp_path / "profile.png"
    r = run_cli("blocks", str(sample(ATL03)), "--preset", "paper", "--length", "10",
                "--length", "25", "--length", "50", "-o", str(out), "--profile", str(png), "--photon-layer")
    assert r.returncode == 0, r.stderr
    assert {n for n, _ in pyogrio.list_layers(out)} == {"blocks", "photons"}
    blocks = gpd.read_file(out, layer="blocks")
    assert list(blocks.columns) == [*BLOCK_COLUMNS, "estimators", "geometry"]
    assert set(blocks["estimators"]) == {"noise=sigma,ground=paper,top=paper"}
    assert blocks.crs.to_epsg() == 32613
    track = read_atl03(sample(ATL03), "gt1r")
    assert check_against_oracle(track, blocks, BlockParams(lengths=LENGTHS)) == len(blocks)
    # every photon in exactly one block per length
    for length in LENGTHS:
        assert blocks.loc[blocks["length"] == length, "n_photons"].sum() == 6809
    np.testing.assert_allclose(blocks["hmax"], blocks["top"] - blocks["ground"])
    photons = gpd.read_file(out, layer="photons")
    assert len(photons) == 6809 and "label_10m" in photons
    assert png.stat().st_size > 10_000


def test_blocks_with_signal_confidence_matches_the_oracle(sample, tmp_path) -> None:
    out = tmp_path / "conf.parquet"
    r = run_cli("blocks", str(sample(ATL03)), "--preset", "paper", "--length", "25",
                "--min-signal-conf", "2",
                "-o", str(out))
    assert r.returncode == 0, r.stderr
    blocks = gpd.read_parquet(out)
    track = read_atl03(sample(ATL03), "gt1r")
    check_against_oracle(track, blocks, BlockParams(lengths=(25.0,), min_signal_conf=2))
    # with the land-confidence filter the canopy is metres tall, not the noise's hundreds
    ok = blocks[blocks["flag"] == "ok"]
    assert len(ok) >= 25 and ok["hmax"].median() < 20


def test_blocks_on_simulated_atl03_and_mabel_files(sample, tmp_path) -> None:
    """Files the engine has not seen: photons simulated over a real airborne tile."""
    from canopyblocks.readers.las import read_las
    from canopyblocks.simulate import (
        SimParams,
        line_through,
        simulate_photons,
        write_simulation_atl03,
        write_simulation_mabel,
    )

    pts = read_las(sample("als/lasR_bcts_1.laz"))
    sim = simulate_photons(pts, line_through(pts.bounds, 20.0, inset=7.0),
                           SimParams(diameter=13.0, photon_rate="temperate"), seed=7)
    h5 = write_simulation_atl03(sim, tmp_path / "sim_atl03.h5")
    mabel = write_simulation_mabel(sim, tmp_path / "sim_mabel.h5")
    for path, read in ((h5, lambda p: read_atl03(p, "gt1r")),
                       (mabel, lambda p: read_mabel(p, "most"))):
        out = tmp_path / f"{path.stem}.gpkg"
        r = run_cli("blocks", str(path), "--preset", "paper", "--length", "10", "--length",
                    "25", "--length", "50", "-o", str(out))
        assert r.returncode == 0, r.stderr
        blocks = gpd.read_file(out, layer="blocks")
        n = check_against_oracle(read(path), blocks, BlockParams(lengths=LENGTHS))
        assert n == len(blocks) > 20


def test_info_text_and_json(sample) -> None:
    r = run_cli("info", str(sample(ATL03)))
    assert r.returncode == 0 and "gt1r" in r.stdout and "6809 photons" in r.stdout
    r = run_cli("info", "--json", str(sample(ATL03)))
    info = json.loads(r.stdout)
    assert info["product"] == "ATL03" and info["beams"][0]["n_photons"] == 6809


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["blocks", "{missing}", "-o", "{out}"], "does not exist"),
        (["blocks", "{junk}", "-o", "{out}"], "truncated or corrupt"),
        (["blocks", "{readme}", "-o", "{out}"], "not a recognised photon file"),
        (["blocks", "{atl03}", "--beam", "gt9x", "-o", "{out}"], "gt9x"),
        (["blocks", "{atl03}", "--length", "-5", "-o", "{out}"], "length"),
        (["blocks", "{atl03}", "--top-cutoff", "1.5", "-o", "{out}"], "cutoff"),
        (["blocks", "{atl03}", "-o", "{bad_suffix}"], "unknown suffix"),
        (["blocks", "{harmony}", "--min-signal-conf", "2", "-o", "{out}"],
         "no photon has land signal confidence"),
        (["blocks", "{truncated}", "-o", "{out}"], "truncated"),
    ],
)
def test_bad_input_exits_2_with_one_line_and_no_file(sample, tmp_path, args, message) -> None:
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)
    readme = tmp_path / "readme.md"
    readme.write_text("not photons")
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(sample(ATL03).read_bytes()[:300_000])
    paths = {"missing": tmp_path / "nope.h5", "junk": junk, "out": tmp_path / "o.gpkg",
             "atl03": sample(ATL03), "bad_suffix": tmp_path / "o.shp",
             "harmony": sample("icesat2/harmony_ATL03_gt1l.h5"), "truncated": truncated, "readme": readme}
    r = run_cli(*[a.format(**paths) for a in args])
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("canopyblocks: error:")]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert message.lower() in lines[0].lower()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.h5", "readme.md", "truncated.h5"]


def test_main_returns_exit_codes_in_process(sample, tmp_path, capsys) -> None:
    assert main(["--version"]) == 0
    assert main(["blocks", str(tmp_path / "nope.h5"), "-o", str(tmp_path / "o.gpkg")]) == 2
    assert "does not exist" in capsys.readouterr().err



@pytest.mark.parametrize("command, option", [("validate", "--points"), ("batch", "--tiles"),
                                             ("calibrate", "--points")])
def test_survey_help_says_exactly_what_is_read_by_url(command, option, capsys) -> None:
    """The help of a survey option says what is read by URL (COPC, ept.json), and a plain
    LAZ by URL is refused in one line that the help does not contradict."""
    import re

    from canopyblocks.options import SURVEY_SOURCES_HELP

    assert main([command, "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert " ".join(SURVEY_SOURCES_HELP.split()) in text
    assert "local LAS/LAZ tiles" in text and "(path or URL" not in text
    assert re.search(r"COPC or an ept\.json, local or by URL", text)
