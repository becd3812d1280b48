"""The real QGIS application under Xvfb, with the plugin installed from the built zip.

Issue 12's acceptance test: a fresh profile, the zip from ``scripts/build_plugin.py``
unpacked into it and enabled, QGIS 3.40 started with exactly the runtime the README
documents (``PYTHONPATH=/opt/canopyblocks-qgis-python:<checkout>/core``, no virtualenv),
the chain run with ``processing.runAndLoadResults`` (tests/qgis/app_startup.py), then the
project checked: every output loaded and styled by the plugin, elevation properties on the
layers the Elevation Profile needs, no Python error in the message log.  The rendered map
is kept as an artifact (``$CANOPYBLOCKS_ARTIFACTS`` or ``tests/artifacts/``), not compared.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
import zipfile
from pathlib import Path

import pytest

pytestmark = [pytest.mark.qgis, pytest.mark.pdal]

ROOT = Path(__file__).resolve().parents[2]
TILE = ROOT / "tests" / "data" / "als" / "lasR_bcts_1.laz"


@pytest.fixture(scope="module")
def app_run(built_zip, gedi_l1b, pdal_bin, tmp_path_factory, qgis_process_env) -> dict:
    from conftest import require  # tests/qgis/conftest.py

    require(shutil.which("qgis") is not None, "the QGIS application (package 'qgis')",
            "run: bash scripts/install_qgis.sh")
    require(shutil.which("Xvfb") is not None, "Xvfb (package 'xvfb')",
            "run: bash scripts/install_qgis.sh")
    work = tmp_path_factory.mktemp("qgis_app")
    prof = work / "profiles"
    plugins = prof / "profiles" / "default" / "python" / "plugins"
    plugins.mkdir(parents=True)
    with zipfile.ZipFile(built_zip) as zf:
        zf.extractall(plugins)
    ini = prof / "profiles" / "default" / "QGIS" / "QGIS3.ini"
    ini.parent.mkdir(parents=True)
    ini.write_text("[PythonPlugins]\ncanopyblocks_qgis=true\n")
    out = work / "out"
    out.mkdir()
    display = f":{90 + os.getpid() % 9}"
    xvfb = subprocess.Popen(["Xvfb", display, "-screen", "0", "1600x1000x24", "-nolisten",
                             "tcp"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        env = qgis_process_env(prof)  # the README's runtime and core, no virtualenv
        env.pop("QT_QPA_PLATFORM", None)
        env.pop("QGIS_CUSTOM_CONFIG_PATH", None)
        env.pop("VIRTUAL_ENV", None)
        env["PATH"] = os.pathsep.join(p for p in env["PATH"].split(os.pathsep)
                                      if not (Path(p) / "pyvenv.cfg").exists()
                                      and not (Path(p).parent / "pyvenv.cfg").exists())
        env["DISPLAY"] = display
        env["CANOPYBLOCKS_PDAL"] = pdal_bin
        env["CANOPYBLOCKS_APP_JSON"] = json.dumps(
            {"out": str(out), "tile": str(TILE), "l1b": str(gedi_l1b)})
        r = subprocess.run(["qgis", "--profiles-path", str(prof), "--nologo",
                            "--noversioncheck", "--code", str(ROOT / "tests" / "qgis" /
                                                                "app_startup.py")],
                           env=env, capture_output=True, text=True, timeout=240)
    finally:
        xvfb.terminate()
        xvfb.wait(timeout=10)
    result_file = out / "result.json"
    assert result_file.exists(), f"QGIS wrote no result (exit {r.returncode}):\n{r.stderr[-3000:]}"
    result = json.loads(result_file.read_text())
    artifacts = Path(os.environ.get("CANOPYBLOCKS_ARTIFACTS", ROOT / "tests" / "artifacts"))
    for name in ("map.png", "profile.png", "canvas.png", "window.png", "dialog.png"):
        if (out / name).exists():
            artifacts.mkdir(parents=True, exist_ok=True)
            shutil.copy(out / name, artifacts / f"qgis_app_{name}")
    result["out"] = str(out)
    return result


def _layer(result: dict, name_part: str) -> dict:
    hits = [lyr for lyr in result["layers"] if lyr["name"] == name_part] or \
        [lyr for lyr in result["layers"] if name_part.lower() in lyr["name"].lower()]
    assert hits, f"no layer named like {name_part!r}: {[lyr['name'] for lyr in result['layers']]}"
    return hits[0]


def test_the_chain_runs_and_loads_without_python_errors(app_run) -> None:
    assert "error" not in app_run, app_run.get("error")
    assert app_run["messages"] == [], app_run["messages"]
    names = {lyr["name"] for lyr in app_run["layers"]}
    # every output of the chain is in the project: vectors and the three rasters
    for part in ("Blocks", "Photons", "Residuals", "DTM", "DSM (maximum)",
                 "DSM (90th percentile)", "aspect", "GEDI footprints", "DTM fill mask"):
        assert any(part.lower() in n.lower() for n in names), (part, names)
    # names say what a layer was made from: input, beam and block lengths
    assert "Blocks - sim gt1r 25, 10 m" in names, names
    assert "Photons with labels - sim gt1r 25, 10 m" in names, names
    assert any(n.startswith("DTM - lasR_bcts_1") for n in names), names
    assert len(names) == len(app_run["layers"])  # no two layers share a name


def test_outputs_are_styled_by_the_plugin(app_run) -> None:
    blocks = _layer(app_run, "Blocks")
    assert blocks["renderer"] == "categorizedSymbol"
    # classes per block length (each its own colour scale), and one for blocks without height
    assert blocks["rules"][0].startswith("10 m blocks: 0.0 to ")
    assert blocks["rules"][5].startswith("25 m blocks: 0.0 to ")
    assert blocks["rules"][-1].startswith("no hmax")
    assert _layer(app_run, "Residuals")["renderer"] == "graduatedSymbol"
    assert _layer(app_run, "aspect")["renderer"] == "categorizedSymbol"
    assert _layer(app_run, "DTM")["renderer"] == "singlebandpseudocolor"


def test_layers_stand_in_the_elevation_profile(app_run) -> None:
    blocks = _layer(app_run, "Blocks")
    assert blocks["z_field"] == "ground" and blocks["extrusion"]
    assert _layer(app_run, "Photons")["z_field"] == "h"
    fp = _layer(app_run, "GEDI footprints")
    assert fp["has_z"] or fp["z_field"] == "ground"
    assert _layer(app_run, "DTM")["elevation"] is True


def test_draw_order_rasters_below_points_on_top(app_run) -> None:
    kinds = [(lyr["kind"], lyr["name"]) for lyr in app_run["layers"] if lyr.get("kind")]
    rasters = [i for i, (k, _) in enumerate(kinds) if k == "raster"]
    assert rasters and min(rasters) > max(i for i, (k, _) in enumerate(kinds) if k == "vector")
    names = [n for _, n in kinds]
    first = [next(i for i, n in enumerate(names) if n.startswith(part))
             for part in ("Blocks", "Photons with labels", "Residuals")]
    assert first == sorted(first), names


def test_a_map_was_rendered(app_run) -> None:
    png = Path(app_run["out"]) / "map.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def _png(path: Path):  # noqa: ANN202
    import numpy as np
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGBA")).astype(int)


def test_the_elevation_profile_draws_the_block_bars(app_run) -> None:
    """The profile of the loaded layer, QGIS's default 'respect layer symbology' on: each
    block's bar where its ground and Hmax put it, in a green class colour."""
    import numpy as np

    prof = app_run["profile"]
    assert prof["respect_symbology"] is True
    img = _png(Path(app_run["out"]) / "profile.png")
    drawn = img[..., 3] > 0
    bars = prof["bars"]
    assert len(bars) >= 5
    hits = 0
    for b in bars:
        c = b["col"]
        band = drawn[:, max(c - 2, 0):c + 3].any(axis=1)
        top, ground = b["top_row"], b["ground_row"]
        if ground - top < 8:
            continue
        inside = band[top + 2:ground - 2]
        assert inside.mean() > 0.9, (b, inside.mean())
        row = img[(top + ground) // 2, max(c - 2, 0):c + 3]
        px = row[np.argmax(row[:, 3])]
        assert px[1] > px[0] and px[1] > px[2], (b, px)  # a green class colour
        hits += 1
    assert hits >= 5


def test_the_map_canvas_shows_the_styled_blocks(app_run) -> None:
    """A screenshot of the desktop's map canvas: at each block point, its style's colour
    (a green class for blocks with a height, grey for the others), not the background."""
    import numpy as np

    img = _png(Path(app_run["out"]) / "canvas.png")
    h, w = img.shape[:2]
    checked = 0
    for p in app_run["canvas"]["points"]:
        x, y = p["x"], p["y"]
        if not (3 <= x < w - 3 and 3 <= y < h - 3):
            continue
        patch = img[y - 1:y + 2, x - 1:x + 2, :3].reshape(-1, 3)
        if p["has_hmax"]:
            assert any(g > r + 10 and g > b for r, g, b in patch), (p, patch.tolist())
        else:
            assert any(abs(r - g) < 12 and abs(g - b) < 12 and r < 200 for r, g, b in patch)
        checked += 1
    assert checked >= 10
    # and the canvas is not blank: more than 2 % of its pixels are not the background
    bg = img[0, 0, :3]
    assert (np.abs(img[..., :3] - bg).sum(axis=2) > 30).mean() > 0.02


def test_the_dialog_shows_plain_numbers_and_an_advanced_group(app_run) -> None:
    """Block heights' dialog as the toolbox opens it: numbers as one writes them, the rarely
    changed parameters in a collapsed "Advanced Parameters" group, no doubled [optional]."""
    d = app_run["dialog"]
    assert "2.5" in d["spins"], d["spins"]  # the noise filter's k, not "2.500000"
    assert not any(t.endswith("00000") for t in d["spins"]), d["spins"]
    assert any("advanced" in title.lower() for title, _ in d["groups"]), d["groups"]
    # collapsed: the rarely changed parameters are there but not shown until opened
    assert any(t.startswith("Noise filter k") for t in d["labels"])
    assert not any(t.startswith("Noise filter k") for t in d["visible_labels"])
    assert any(t.startswith("Block lengths") for t in d["visible_labels"])
    text = " ".join(d["labels"])
    assert "[optional] [optional]" not in text and "(optional) [optional]" not in text
    assert "seed-001" not in text and "DESIGN" not in text


def test_the_beam_box_lists_the_beams_of_the_chosen_file(app_run) -> None:
    """Choosing the photon file in the dialog fills the beam list with the file's beams that
    hold photons (checked against the file read here with h5py)."""
    import h5py

    with h5py.File(Path(app_run["out"]) / "sim.h5") as f:
        truth = [b for b in ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")
                 if f"{b}/heights/h_ph" in f and f[f"{b}/heights/h_ph"].shape[0] > 0]
    assert truth
    assert app_run["dialog"]["beams"] == truth
