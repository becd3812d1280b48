"""The README runs as written: every command of its command-line block and its Python
block, in order, in a scratch folder holding the repository's ``tests/`` (bundled data).

Placeholders for files a user brings are mapped to bundled or simulated files before
the commands run (no command is edited):

* ``GRANULE_ATL03.h5`` / ``GRANULE_ATL08.h5``: the real Wyoming ATL03/ATL08 clip;
* ``MABEL_L2A.h5``: a file in the real MABEL L2A layout (the layout of the bundled
  granule description, as tests/test_readers_mabel.py writes it);
* ``OTHER_SITE_ATL03.h5``: the photons simulated by the README's own ``simulate`` line;
* the GEDI L1B/L2A pair: unzipped from ``tests/data/gedi/`` (as the README says);
* ``granules/`` and ``tiles/``: the simulated granule and the two bundled tiles.

The set-up block (``scripts/demo.sh``, ``scripts/test.sh``) installs software and is not
run here; the demo's chain is the ``run`` line of the command block.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

pytestmark = [pytest.mark.slow, pytest.mark.pdal]


def readme_blocks(lang: str) -> list[str]:
    """The README's fenced code blocks of one language, in order."""
    text = README.read_text(encoding="utf-8")
    return re.findall(rf"^```{lang}\n(.*?)^```", text, flags=re.S | re.M)


def readme_commands() -> list[str]:
    """The logical commands of the README's bash blocks (continuations joined, comments
    and the environment activation left out), except the installing set-up block."""
    out = []
    for block in readme_blocks("bash"):
        if "scripts/demo.sh" in block:
            continue
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if not line or line.startswith("#") or line.startswith(". "):
                continue
            out.append(line)
    return out


def test_readme_has_the_blocks_this_test_runs() -> None:
    cmds = readme_commands()
    assert len(cmds) >= 15 and all(c.startswith("canopyblocks ") for c in cmds), cmds
    assert len(readme_blocks("python")) == 1


def _mabel_file(path: Path) -> None:
    from test_readers_mabel import DMR, _dmr_layout, _positions

    layout = _dmr_layout(ROOT / "tests" / "data" / DMR)
    with h5py.File(path, "w") as f:
        for chan, dsets in layout.items():
            ch = int(chan[len("channel"):])
            n = dsets["elev"][1] // 1000
            s, lat, lon, t, elev = _positions(n, 11, ch)
            values = {"delta_time": t, "elev": elev, "latitude": lat, "longitude": lon,
                      "flag": np.zeros(n), "photon_id": np.ones(n),
                      "shot_num": np.arange(1, n + 1)}
            for name, (dtype, _, attrs) in dsets.items():
                d = f.create_dataset(f"photon/{chan}/{name}", data=values[name].astype(dtype))
                for k, v in attrs.items():
                    d.attrs[k] = v


def _placeholders(work: Path, command: str) -> None:
    """Create the files a command names that a user would bring."""
    data = ROOT / "tests" / "data"
    if "GRANULE_ATL03.h5" in command and not (work / "GRANULE_ATL03.h5").exists():
        shutil.copy(data / "icesat2" / "vegr_atl03_clip.h5", work / "GRANULE_ATL03.h5")
        shutil.copy(data / "icesat2" / "vegr_atl08_clip.h5", work / "GRANULE_ATL08.h5")
    if "MABEL_L2A.h5" in command and not (work / "MABEL_L2A.h5").exists():
        _mabel_file(work / "MABEL_L2A.h5")
    if "OTHER_SITE_ATL03.h5" in command:
        shutil.copy(work / "out" / "sim_atl03.h5", work / "OTHER_SITE_ATL03.h5")
    if "GEDI0" in command and not list(work.glob("GEDI01_B_*.h5")):
        for z in sorted((data / "gedi").glob("*.zip")):
            with zipfile.ZipFile(z) as zf:
                zf.extractall(work)
    if "granules/" in command:
        (work / "granules").mkdir(exist_ok=True)
        (work / "tiles").mkdir(exist_ok=True)
        shutil.copy(work / "out" / "sim_atl03.h5", work / "granules" / "sim_atl03.h5")
        for t in ("lasR_bcts_1.laz", "lasR_bcts_2.laz"):
            shutil.copy(data / "als" / t, work / "tiles" / t)


@pytest.fixture(scope="module")
def readme_run(tmp_path_factory, pdal_bin):
    """Every README command run in order; their results."""
    work = tmp_path_factory.mktemp("readme")
    (work / "tests").symlink_to(ROOT / "tests")
    env = {**os.environ, "CANOPYBLOCKS_PDAL": pdal_bin,
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    results = []
    for cmd in readme_commands():
        _placeholders(work, cmd)
        r = subprocess.run(["bash", "-c", cmd], cwd=work, env=env, capture_output=True,
                           text=True, timeout=600)
        results.append((cmd, r))
        if r.returncode != 0:
            break
    return work, env, results


def test_every_readme_command_runs_as_written(readme_run) -> None:
    _, _, results = readme_run
    for cmd, r in results:
        assert r.returncode == 0, (f"README command failed (exit {r.returncode}): {cmd}\n"
                                   + "\n".join(r.stderr.splitlines()[-5:]))
    assert len(results) == len(readme_commands())
    for cmd, r in results:  # no traceback, no matplotlib noise, no deprecated names
        assert "Traceback" not in r.stderr and "Axes3D" not in r.stderr, cmd
        assert "deprecated" not in r.stderr, (cmd, r.stderr)


def test_readme_python_block_runs_as_written(readme_run) -> None:
    work, env, results = readme_run
    assert all(r.returncode == 0 for _, r in results)
    code = readme_blocks("python")[0]
    l1b = next(work.glob("GEDI01_B_*.h5")).name
    code = code.replace("GEDI01_B_..._sub.h5", l1b)
    r = subprocess.run([sys.executable, "-c", code], cwd=work, env=env, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "hmax" in r.stdout


def test_readme_run_report_leads_with_the_recommended_estimators(readme_run) -> None:
    """The README's whole chain: the report's first section is the summary."""
    import html as markup

    from canopyblocks.blocks.estimators import RECOMMENDED_PRESET

    work, _, _ = readme_run
    page = markup.unescape((work / "out" / "chain" / "report.html").read_text())
    first = page.split("<h2>")[1]
    assert first.startswith("Summary") and f"'{RECOMMENDED_PRESET}'" in first
