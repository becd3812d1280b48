"""Every example of the README runs as written on a fresh clone, or is marked as a template.

An example is each logical command of the README's fenced ``bash``/``sh`` blocks, each fenced
``python``/``py`` block, and each command quoted inline in its prose (`` `canopyblocks ...` ``).
A template says so and what to put in: a comment line ``# template: put ... for PLACEHOLDER``
above its command, the same comment as the first line of a Python block, or
``(template: put ... for PLACEHOLDER)`` right after an inline command; every placeholder it
names is in the example. The set-up block (``scripts/demo.sh``, ``scripts/test.sh``: they
install software; CI runs the second) and the activation of ``.venv`` are not run here: the
commands run from the virtualenv running the tests, first on ``PATH`` as the activation puts
it.

Every other example runs once, in the README's order, in a scratch folder holding the
repository's ``tests/`` (the bundled data), so the examples share ``out/`` as the README
chains them. Each must succeed, and its stderr must hold only canopyblocks' own lines: no
warning of another package (``warning from OpenSSL (CryptographyDeprecationWarning)``,
``RequestsDependencyWarning``), no GDAL/PROJ/HDF5 chatter, no traceback.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

FENCE = re.compile(r"^```(\w*)\n(.*?)^```", flags=re.S | re.M)
INLINE = re.compile(r"`(canopyblocks [^`]+)`(\s*\(template:[^)]*\))?")
TEMPLATE = re.compile(r"^#\s*template:\s*(.+)$")
SETUP_MARK = "scripts/demo.sh"
ACTIVATE = ". .venv/bin/activate"


@dataclass(frozen=True)
class Example:
    """One example of the README."""

    kind: str  # "command" or "python"
    text: str
    line: int  # where it is in README.md
    template: str | None = None  # the template's note (what to put in)
    setup: bool = False  # installs software or activates the environment: not run here

    @property
    def runs(self) -> bool:
        return self.template is None and not self.setup


def _line_of(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


def _commands(block: str, line: int) -> list[Example]:
    """The logical commands of a shell block starting at README line ``line`` (its fence):
    continuations joined, comments left out, each ``# template:`` comment attached to the
    command after it."""
    setup = SETUP_MARK in block
    out: list[Example] = []
    note: str | None = None
    lines = block.splitlines()
    i = 0
    while i < len(lines):
        start, text = i, lines[i]
        while text.endswith("\\") and i + 1 < len(lines):
            i += 1
            text = text[:-1] + " " + lines[i]
        i += 1
        stripped = text.strip()
        if stripped.startswith("#"):
            m = TEMPLATE.match(stripped)
            note = m.group(1) if m else note
            continue
        cmd = " ".join(re.sub(r"\s+#\s.*$", "", stripped).split())
        if not cmd:
            continue
        out.append(Example("command", cmd, line + 1 + start, note, setup or cmd == ACTIVATE))
        note = None
    assert note is None, f"README line {line}: a '# template:' comment with no command after it"
    return out


def readme_examples(text: str | None = None) -> list[Example]:
    """Every example of the README, in the README's order."""
    text = README.read_text(encoding="utf-8") if text is None else text
    found: list[tuple[int, list[Example]]] = []
    for m in FENCE.finditer(text):
        lang, body, line = m.group(1), m.group(2), _line_of(text, m.start())
        if lang in ("bash", "sh"):
            found.append((m.start(), _commands(body, line)))
        elif lang in ("python", "py"):
            first = TEMPLATE.match(body.lstrip().splitlines()[0])
            found.append((m.start(), [Example("python", body, line,
                                              first.group(1) if first else None)]))
        else:
            raise AssertionError(f"README line {line}: a code block of language {lang!r}: "
                                 "say bash, sh, python or py, so the examples' test sees it")
    prose = FENCE.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), text)
    for m in INLINE.finditer(prose):
        note = m.group(2)
        note = note.strip()[len("(template:"):-1].strip() if note else None
        cmd = " ".join(m.group(1).split())
        found.append((m.start(), [Example("command", cmd, _line_of(text, m.start()), note)]))
    return [e for _, group in sorted(found, key=lambda f: f[0]) for e in group]


def placeholders(note: str) -> list[str]:
    """What a template's note says to replace: each word after 'for'."""
    return [w.strip("`,;.") for w in re.findall(r"\bfor (\S+)", note)]


# ---------------------------------------------------------------------------------------------
# canopyblocks' own stderr lines
# ---------------------------------------------------------------------------------------------

_PY_WARNING = re.compile(r"^(?P<file>\S.*?):\d+: (?P<category>\w+): ")
_FOREIGN_MARKS = re.compile(
    r"warning from |\w*Warning\b|\bwarning:|\berror:|\w+Error\b|deprecat|Traceback|"
    r"^(ERROR|Warning) \d+:|\bPROJ\b|proj_|\bGDAL\b|HDF5|OpenSSL", flags=re.I)


def own_warning_classes() -> set[str]:
    """Names of canopyblocks' warning classes (CanopyBlocksWarning and its subclasses, by
    their ``class X(...Warning...)`` lines in the package's source)."""
    names: set[str] = set()
    for src in (ROOT / "core" / "canopyblocks").rglob("*.py"):
        names |= set(re.findall(r"^class (\w+)\([^)]*Warning[^)]*\):", src.read_text(),
                                flags=re.M))
    return names


def foreign_lines(stderr: str) -> list[str]:
    """The lines of a README example's stderr that are not canopyblocks' own.

    canopyblocks' own lines are those of its logger and warnings (``canopyblocks: ...``,
    ``canopyblocks: warning: ...``, cli/log_setup.py), Python warnings raised from its own
    code or of its own classes (``.../canopyblocks/...py:N: SomeWarning: ...`` and the source
    line under it, from the Python API), and the plain summary lines a command prints (counts, tables, "validated
    9 of 10 blocks", "the report gives the errors measured on unseen tiles"): canopyblocks
    says a warning or an error only with its prefix, so a plain line with a warning's or an
    error's label (``warning:``, ``SomeWarning``, ``error:``, ``SomeError``), a deprecation,
    a traceback or GDAL/PROJ/HDF5 is another package's, as is log_setup's
    ``warning from <package> (<category>): ...``.
    """
    out: list[str] = []
    after_own_warning = False
    for line in re.split(r"[\r\n]+", stderr):
        if not line.strip():
            continue
        if after_own_warning and line.startswith((" ", "\t")):  # the warning's source line
            after_own_warning = False
            continue
        after_own_warning = False
        if line.startswith("canopyblocks: "):
            continue
        m = _PY_WARNING.match(line)
        if m and m.group("category").endswith("Warning"):
            after_own_warning = ("canopyblocks" in Path(m.group("file")).parts
                                 or m.group("category") in own_warning_classes())
            if after_own_warning:
                continue
        if m or _FOREIGN_MARKS.search(line):
            out.append(line)
    return out


def test_foreign_lines_are_told_from_canopyblocks_own() -> None:
    own = ("canopyblocks: warning: track gt1r: 1 of 39 blocks hold fewer than min_photons\n"
           "canopyblocks: 10 blocks (10 ok) from gt1r -> out/sim_blocks.gpkg\n"
           "validated 9 of 10 blocks -> out/validation.gpkg\n"
           "Read with care: the tiles validated here are the tiles the recommended estimators "
           "were fitted on; the report gives the errors measured on unseen tiles.\n"
           "     10 m  ground  n=21   bias=-0.07 m [-0.17 to +0.02]  rmse=0.22 m\n"
           "  canopyblocks blocks PHOTONS --length 10 --top-cutoff 0.001 -o blocks_10m.gpkg\n"
           "/venv/lib/python3.11/site-packages/canopyblocks/readers/atl03.py:88: "
           "CanopyBlocksWarning: x.h5: gt1r has no bckgrd_atlas\n"
           "  warnings.warn(msg, CanopyBlocksWarning, stacklevel=2)\n")
    assert foreign_lines(own) == []
    assert foreign_lines("<string>:7: SparseBlockWarning: track gt1r: 1 of 39 blocks\n"
                         "<string>:7: UserWarning: something\n") == [
        "<string>:7: UserWarning: something"]
    foreign = [
        "warning from OpenSSL (CryptographyDeprecationWarning): DSA is deprecated and will "
        "be removed in a future release",
        "warning from requests (RequestsDependencyWarning): urllib3 (2.8.0) or chardet "
        "(5.1.0)/charset_normalizer (3.4.0) doesn't match a supported version!",
        "/usr/lib/python3/dist-packages/requests/__init__.py:87: RequestsDependencyWarning: "
        "urllib3 (2.8.0) or chardet (5.1.0) doesn't match a supported version!",
        "/usr/lib/python3/dist-packages/OpenSSL/crypto.py:1573: "
        "CryptographyDeprecationWarning: DSA is deprecated",
        "Warning 1: TIFFReadDirectory:Sum of Photometric type-related color channels",
        "ERROR 1: PROJ: proj_create_from_database: Cannot find proj.db",
        "HDF5-DIAG: Error detected in HDF5 (1.14.2) thread 0:",
        "Traceback (most recent call last):",
        "RuntimeWarning: invalid value encountered in divide",
        "rasterio.errors.NotGeoreferencedWarning: Dataset has no geotransform",
        "OSError: [Errno 2] No such file or directory",
    ]
    for line in foreign:
        assert foreign_lines(own + line + "\n  the source line\n") == [line], line


# ---------------------------------------------------------------------------------------------
# the examples: found, each run or a template
# ---------------------------------------------------------------------------------------------


def test_examples_are_found_and_each_runs_or_is_a_marked_template() -> None:
    examples = readme_examples()
    runs = [e for e in examples if e.runs]
    templates = [e for e in examples if e.template is not None]
    setup = [e for e in examples if e.setup]
    assert len(examples) == len(runs) + len(templates) + len(setup)
    assert [e.text for e in setup] == ["bash scripts/demo.sh", "bash scripts/test.sh", ACTIVATE]
    assert len(runs) >= 25 and len(templates) >= 9, (len(runs), len(templates))
    assert sum(e.kind == "python" for e in runs) >= 1
    for e in templates:
        names = placeholders(e.template or "")
        assert names, f"README line {e.line}: the template note names nothing to put in"
        missing = [n for n in names if n not in e.text]
        assert not missing, f"README line {e.line}: {missing} not in the example {e.text!r}"
    for e in runs:  # a placeholder a fresh clone does not have is a template's
        assert not re.search(r"\b[A-Z][A-Z0-9]*_[A-Z0-9_]*\.h5\b|my-bucket|example\.org",
                             e.text), f"README line {e.line}: a placeholder in {e.text!r}"


def test_template_markers_are_read_from_the_three_places() -> None:
    text = ("```bash\n# template: put your granule for G.h5\ncanopyblocks info G.h5 \\\n"
            "    --beam gt1r   # a comment\ncanopyblocks info tests/x.h5\n```\n"
            "Prose `canopyblocks blocks A_*.h5 -o s.parquet` (template: put yours for A_*.h5)"
            " and `canopyblocks segments\n  x.h5 -o s.gpkg` runs.\n"
            "```py\n# template: put your URL for https://e.org/x\nread('https://e.org/x')\n```\n")
    ex = readme_examples(text)
    assert [(e.kind, e.text, e.template) for e in ex] == [
        ("command", "canopyblocks info G.h5 --beam gt1r", "put your granule for G.h5"),
        ("command", "canopyblocks info tests/x.h5", None),
        ("command", "canopyblocks blocks A_*.h5 -o s.parquet", "put yours for A_*.h5"),
        ("command", "canopyblocks segments x.h5 -o s.gpkg", None),
        ("python", "# template: put your URL for https://e.org/x\nread('https://e.org/x')\n",
         "put your URL for https://e.org/x"),
    ]
    assert placeholders("put your folder for /data/t/ and your area for `a.gpkg`.") == [
        "/data/t/", "a.gpkg"]


def test_readme_qgis_table_lists_every_algorithm_of_the_provider() -> None:
    """The README's table of the toolbox: every algorithm of provider.ALGORITHMS, in menu
    order, with its display name and id (read from the plugin's source: no QGIS needed)."""
    provider = (ROOT / "qgis_plugin" / "provider.py").read_text()
    names = re.findall(r"^\s+(\w+Algorithm),$",
                       provider.split("ALGORITHMS = (", 1)[1].split(")", 1)[0], flags=re.M)
    want = []
    for cls in names:
        for src in (ROOT / "qgis_plugin" / "algorithms").glob("*.py"):
            code = src.read_text()
            if re.search(rf"^class {cls}\b", code, flags=re.M):
                body = code.split(f"class {cls}", 1)[1]
                want.append((re.search(r'DISPLAY = "([^"]+)"', body).group(1),
                             re.search(r'ALG_ID = "([^"]+)"', body).group(1)))
    assert len(want) == len(names) >= 13
    text = README.read_text(encoding="utf-8")
    table = re.findall(r"^\| (.+?) \| `(\w+)` \|$", text.split("## QGIS", 1)[1], flags=re.M)
    assert table == want


# ---------------------------------------------------------------------------------------------
# the examples run
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def readme_run(tmp_path_factory, pdal_bin):
    """Every example that runs, run in order in one scratch folder; their results."""
    work = tmp_path_factory.mktemp("readme")
    (work / "tests").symlink_to(ROOT / "tests")
    env = {**os.environ, "CANOPYBLOCKS_PDAL": pdal_bin,
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("PYTHONWARNINGS", None)
    results = []
    for e in readme_examples():
        if not e.runs:
            continue
        argv = ["bash", "-c", e.text] if e.kind == "command" else [sys.executable, "-c", e.text]
        r = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True,
                           timeout=900)
        results.append((e, r))
        if r.returncode != 0:
            break
    return work, results


@pytest.mark.slow
@pytest.mark.pdal
def test_every_readme_example_runs_as_written(readme_run) -> None:
    _, results = readme_run
    for e, r in results:
        assert r.returncode == 0, (f"README line {e.line} failed (exit {r.returncode}): "
                                   f"{e.text}\n" + "\n".join(r.stderr.splitlines()[-5:]))
    assert len(results) == sum(e.runs for e in readme_examples())


@pytest.mark.slow
@pytest.mark.pdal
def test_readme_examples_print_only_canopyblocks_own_lines(readme_run) -> None:
    _, results = readme_run
    for e, r in results:
        assert foreign_lines(r.stderr) == [], f"README line {e.line}: {e.text[:200]}"
    python = [r for e, r in results if e.kind == "python"]
    assert python and "hmax" in python[0].stdout


@pytest.mark.slow
@pytest.mark.pdal
def test_readme_run_report_leads_with_the_recommended_estimators(readme_run) -> None:
    """The README's whole chain: the report's first section is the summary."""
    import html as markup

    from canopyblocks.blocks.estimators import RECOMMENDED_PRESET

    work, _ = readme_run
    page = markup.unescape((work / "out" / "chain" / "report.html").read_text())
    first = page.split("<h2>")[1]
    assert first.startswith("Summary") and f"'{RECOMMENDED_PRESET}'" in first
