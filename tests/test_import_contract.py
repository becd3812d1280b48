"""The import contract of the package (docs/ARCHITECTURE.md): no circles, no arrow back up.

Read from the code itself with ``ast`` (nothing is imported): every ``import`` of
``core/canopyblocks`` and ``qgis_plugin``, at module level, inside functions and under
``TYPE_CHECKING`` alike, is an arrow from the importing module to the imported one.

- No two modules may import each other, directly or round a longer loop.
- The rooms stand in layers, bottom first; a module may import its own layer and the
  layers below it, never one above (``blocks`` and ``waveforms`` share a layer and do not
  import each other; ``cli`` and ``qgis_plugin`` neither)::

      foundation -> forms -> readers -> blocks | waveforms -> reference -> validation
        -> outputs -> simulate -> workflows -> cli | qgis_plugin -> __main__

  ``forms`` are the in-memory tracks the readers fill and every estimator reads
  (``photons.PhotonTrack``, ``waveforms.batch.WaveformBatch``).
- The package face ``canopyblocks/__init__.py`` (lazy re-exports) and the alias table of
  old module paths (``_aliases``, string-based) stand outside the layers.

- The front doors (``cli``, ``qgis_plugin``) import only ``workflows`` and the foundation
  (the QGIS plugin's ``import_core("canopyblocks.x")`` calls count as imports): every
  command and algorithm is parameters in, one workflow call, outputs out.
- ``h5py`` is imported only in ``readers/`` and ``outputs/h5*``.

The checks are tested on small made-up import graphs too, so that they can fail.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: The layers, bottom first: each a list of rooms (module prefixes). The rooms of a layer
#: named "a|b" stay apart (they may not import each other); the others may.
LAYERS: list[tuple[str, list[str]]] = [
    ("foundation", ["canopyblocks.errors", "canopyblocks.schema", "canopyblocks.progress",
                    "canopyblocks.arguments", "canopyblocks.geo", "canopyblocks.atomic",
                    "canopyblocks.options"]),
    ("forms", ["canopyblocks.photons", "canopyblocks.waveforms.batch"]),
    ("readers", ["canopyblocks.readers"]),
    ("blocks|waveforms", ["canopyblocks.blocks", "canopyblocks.waveforms"]),
    ("reference", ["canopyblocks.reference"]),
    ("validation", ["canopyblocks.validation"]),
    ("outputs", ["canopyblocks.outputs"]),
    ("simulate", ["canopyblocks.simulate"]),
    ("workflows", ["canopyblocks.workflows"]),
    ("cli|qgis_plugin", ["canopyblocks.cli", "qgis_plugin"]),
    ("python -m", ["canopyblocks.__main__"]),
]

#: Outside the layers: the package face and the table of old module paths.
OUTSIDE = {"canopyblocks", "canopyblocks._aliases"}


def modules(root: Path = ROOT) -> dict[str, tuple[Path, bool]]:
    """{dotted module: (file, is_package)} of the core package and the QGIS plugin."""
    out: dict[str, tuple[Path, bool]] = {}
    for base, pkg in ((root / "core", "canopyblocks"), (root, "qgis_plugin")):
        for path in sorted((base / pkg).rglob("*.py")):
            parts = list(path.relative_to(base).with_suffix("").parts)
            is_pkg = parts[-1] == "__init__"
            if is_pkg:
                parts = parts[:-1]
            out[".".join(parts)] = (path, is_pkg)
    return out


def _targets(module: str, is_pkg: bool, node: ast.Import | ast.ImportFrom,
             known: set[str]) -> list[str]:
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        if node.level:
            pkg = module.split(".") if is_pkg else module.split(".")[:-1]
            pkg = pkg[:len(pkg) - node.level + 1]
            base = ".".join(pkg + ([node.module] if node.module else []))
        else:
            base = node.module or ""
        names = [base] + [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in known]
    out = []
    for name in names:
        while name and name not in known:  # ``from pkg.mod import name``: the module
            name = name.rpartition(".")[0]
        if name and name != module:
            out.append(name)
    return out


def _core_by_name(node: ast.AST, known: set[str]) -> str | None:
    """The module of an ``import_core("canopyblocks.x")`` / ``importlib.import_module(...)``
    call with a literal name (the QGIS plugin's lazy imports), else None."""
    if not (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)):
        return None
    f = node.func
    name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
    if name not in ("import_core", "import_module"):
        return None
    target = node.args[0].value
    while target and target not in known:
        target = target.rpartition(".")[0]
    return target or None


def import_graph(mods: dict[str, tuple[Path, bool]]) -> dict[str, dict[str, int]]:
    """{module: {imported module: line of the first such import}}."""
    known = set(mods)
    graph: dict[str, dict[str, int]] = {}
    for module, (path, is_pkg) in mods.items():
        arrows = graph.setdefault(module, {})
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for target in _targets(module, is_pkg, node, known):
                    arrows.setdefault(target, node.lineno)
            elif (target := _core_by_name(node, known)) is not None and target != module:
                arrows.setdefault(target, node.lineno)
    return graph


def third_party(mods: dict[str, tuple[Path, bool]], package: str) -> dict[str, int]:
    """{module: line} of the modules importing the third-party ``package``."""
    out: dict[str, int] = {}
    for module, (path, _) in mods.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level \
                else []
            if any(n == package or n.startswith(package + ".") for n in names):
                out.setdefault(module, node.lineno)
    return out


#: The rooms the front doors may import: the workflows and the foundation.
DOOR_ROOMS = ("canopyblocks.workflows", *LAYERS[0][1])
FRONT_DOORS = ("canopyblocks.cli", "qgis_plugin")

#: Front-door imports still going around the workflows, each to be replaced by a workflow
#: call (the list only shrinks; a new entry fails the test).
DOOR_DEBT: set[tuple[str, str]] = {
    # the reference rasters' algorithm asks PDAL's version for its log
    ("qgis_plugin.algorithms.referencerasters", "canopyblocks.reference.pdal"),
}

#: Modules outside ``readers/`` and ``outputs/h5*`` still importing h5py (only shrinks).
H5PY_DEBT: set[str] = {
    "canopyblocks.simulate.sensor_files",  # writes the ESFL cubes and dual pairs itself
}


def around_the_door(graph: dict[str, dict[str, int]]) -> list[str]:
    """Front-door modules importing anything but the workflows, the foundation, the package
    face and their own room."""
    bad = []
    for module, arrows in sorted(graph.items()):
        door = next((d for d in FRONT_DOORS if module == d or module.startswith(d + ".")), None)
        if door is None:
            continue
        for target, line in sorted(arrows.items()):
            if target == "canopyblocks" or target == door or target.startswith(door + ".") \
                    or any(target == r or target.startswith(r + ".") for r in DOOR_ROOMS):
                continue
            bad.append(f"{module}:{line} imports {target}")
    return bad


def _door_key(line: str) -> tuple[str, str]:
    module, _, target = line.partition(" imports ")
    return module.split(":")[0], target


def circles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Strongly connected sets of more than one module (Tarjan, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, {}))))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, {})))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        found.append(sorted(comp))
    return found


def place(module: str) -> tuple[int, str] | None:
    """(layer number, room) of a module; None outside the layers."""
    if module in OUTSIDE:
        return None
    best: tuple[int, str] | None = None
    for number, (_, rooms) in enumerate(LAYERS):
        for room in rooms:
            if (module == room or module.startswith(room + ".")) and (
                    best is None or len(room) > len(best[1])):
                best = (number, room)
    return best


def upward(graph: dict[str, dict[str, int]]) -> list[str]:
    """Modules that stand in no layer; arrows into a higher layer, or between two rooms of
    a layer whose rooms stay apart."""
    places = {m: place(m) for m in graph}
    bad = [f"{m} stands in no layer: add its room to LAYERS"
           for m, p in sorted(places.items()) if p is None and m not in OUTSIDE]
    for module, arrows in sorted(graph.items()):
        here = places[module]
        for target, line in sorted(arrows.items()):
            there = places[target] if target in places else place(target)
            if here is None or there is None:
                continue  # outside the layers, or told above
            if there[0] > here[0]:
                bad.append(f"{module}:{line} imports {target}: {LAYERS[there[0]][0]} stands "
                           f"above {LAYERS[here[0]][0]}")
            elif there[0] == here[0] and there[1] != here[1] and "|" in LAYERS[here[0]][0] \
                    and not (there[1].startswith(here[1] + ".")
                             or here[1].startswith(there[1] + ".")):
                bad.append(f"{module}:{line} imports {target}: {here[1]} and {there[1]} share "
                           f"the layer {LAYERS[here[0]][0]} and stay apart")
    return bad


@pytest.fixture(scope="module")
def graph() -> dict[str, dict[str, int]]:
    return import_graph(modules())


def test_no_import_circles(graph):
    assert circles(graph) == []


def test_no_import_runs_back_up(graph):
    assert upward(graph) == []


def test_the_front_doors_call_only_the_workflows(graph):
    """cli/ and qgis_plugin/ import workflows/ and the foundation only (listed debt aside)."""
    found = around_the_door(graph)
    new = [b for b in found if _door_key(b) not in DOOR_DEBT]
    assert new == [], "a front door goes around the workflows: " + "; ".join(new)
    paid = DOOR_DEBT - {_door_key(b) for b in found}
    assert not paid, f"paid debt: remove from DOOR_DEBT {sorted(paid)}"


def test_h5py_only_in_readers_and_h5_outputs():
    users = third_party(modules(), "h5py")
    ok = ("canopyblocks.readers", "canopyblocks.outputs.h5")
    bad = {m for m in users if not m.startswith(ok)}
    assert bad - H5PY_DEBT == set(), {m: users[m] for m in bad - H5PY_DEBT}
    assert H5PY_DEBT - bad == set(), f"paid debt: remove from H5PY_DEBT {H5PY_DEBT - bad}"


def test_the_package_face_imports_only_errors_and_the_alias_table_at_load_time():
    """``import canopyblocks`` stays fast: everything else loads on first use."""
    tree = ast.parse((ROOT / "core/canopyblocks/__init__.py").read_text(encoding="utf-8"))
    loaded = set()
    for node in tree.body:  # module level, outside ``if TYPE_CHECKING``
        if isinstance(node, ast.ImportFrom) and node.level:
            loaded |= {node.module or a.name for a in node.names} if node.module is None \
                else {node.module}
    assert loaded <= {"errors", "_aliases"}


def test_modules_at_most_600_lines():
    long = {str(p.relative_to(ROOT)): n for p, _ in modules().values()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 600}
    assert long == {}


def test_old_module_paths_are_the_new_modules():
    """An old path (before the rooms) gives the very module at the new path."""
    import importlib

    aliases = importlib.import_module("canopyblocks._aliases")
    for old, new in aliases.MOVED_MODULES.items():
        assert importlib.import_module(old) is importlib.import_module(new), old


# ---- the checks themselves can fail (made-up graphs with a known answer)

def test_a_made_up_circle_is_found():
    g = {"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}
    assert circles(g) == [["a", "b", "c"]]
    assert circles({"a": {"b": 1}, "b": {}}) == []


def test_a_made_up_upward_import_is_found():
    g = {"canopyblocks.readers.x": {"canopyblocks.workflows.y": 7},
         "canopyblocks.blocks.e": {"canopyblocks.waveforms.p": 3},
         "canopyblocks.workflows.y": {"canopyblocks.readers.x": 2},
         "canopyblocks.loose": {}}
    bad = upward(g)
    assert len(bad) == 3
    assert bad[0] == "canopyblocks.loose stands in no layer: add its room to LAYERS"
    assert bad[1].startswith("canopyblocks.blocks.e:3 imports canopyblocks.waveforms.p")
    assert bad[2].startswith("canopyblocks.readers.x:7 imports canopyblocks.workflows.y")


def test_a_made_up_door_bypass_is_found():
    g = {"canopyblocks.cli.x": {"canopyblocks.workflows.y": 1, "canopyblocks.errors": 2,
                                "canopyblocks.cli.common": 3, "canopyblocks.blocks.z": 4},
         "qgis_plugin.algorithms.a": {"canopyblocks.readers.r": 9, "qgis_plugin.base": 1},
         "canopyblocks.workflows.y": {"canopyblocks.blocks.z": 5}}
    assert around_the_door(g) == ["canopyblocks.cli.x:4 imports canopyblocks.blocks.z",
                                  "qgis_plugin.algorithms.a:9 imports canopyblocks.readers.r"]


def test_an_import_core_call_is_an_import(tmp_path):
    pkg = tmp_path / "core" / "canopyblocks"
    (pkg / "readers").mkdir(parents=True)
    (tmp_path / "qgis_plugin").mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "readers" / "__init__.py").write_text("")
    (pkg / "readers" / "las.py").write_text("")
    (tmp_path / "qgis_plugin" / "__init__.py").write_text("")
    (tmp_path / "qgis_plugin" / "alg.py").write_text(
        "def f():\n    x = 1\n    return import_core('canopyblocks.readers.las.read_las')\n")
    g = import_graph(modules(tmp_path))
    assert g["qgis_plugin.alg"] == {"canopyblocks.readers.las": 3}


def test_a_relative_import_is_resolved(tmp_path):
    pkg = tmp_path / "core" / "canopyblocks"
    (pkg / "readers").mkdir(parents=True)
    (tmp_path / "qgis_plugin").mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "errors.py").write_text("")
    (pkg / "readers" / "__init__.py").write_text("from . import las\n")
    (pkg / "readers" / "las.py").write_text("def f():\n    from ..errors import E\n")
    g = import_graph(modules(tmp_path))
    assert g["canopyblocks.readers"] == {"canopyblocks.readers.las": 1}
    assert g["canopyblocks.readers.las"] == {"canopyblocks.errors": 2}


# ---- the map (docs/ARCHITECTURE.md) states what the code is --------------------------------

def _doc() -> str:
    return (ROOT / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")


def test_every_file_the_map_names_exists():
    """A ``.py`` path in ARCHITECTURE.md is a file: from the package, the plugin, or the
    repository root (a bare name: somewhere in the package, the plugin or the tests)."""
    import re

    names = set(re.findall(r"`((?:[A-Za-z_0-9]+/)*[A-Za-z_0-9*]+\.py)`", _doc()))
    assert len(names) > 40, names
    bases = (ROOT / "core" / "canopyblocks", ROOT / "qgis_plugin", ROOT, ROOT / "core",
             ROOT / "core" / "canopyblocks" / "workflows")
    everywhere = {p.name for b in (ROOT / "core", ROOT / "qgis_plugin", ROOT / "tests")
                  for p in b.rglob("*.py")}
    missing = []
    for n in sorted(names):
        if "*" in n:  # a family, e.g. chain_*.py
            if not any(p.match(n) for b in bases for p in b.rglob("*.py")):
                missing.append(n)
        elif "/" in n:
            if not any((b / n).is_file() for b in bases):
                missing.append(n)
        elif n not in everywhere:
            missing.append(n)
    assert missing == [], f"ARCHITECTURE.md names files that do not exist: {missing}"


def test_the_map_draws_the_layers_of_this_test():
    """The diagram lists the rooms bottom-up in the order of :data:`LAYERS`."""
    doc = _doc()
    diagram = doc[doc.index("    cli/  |  qgis_plugin/"):doc.index("| Room |")]
    order = ["canopyblocks.errors", "canopyblocks.photons", "canopyblocks.readers",
             "canopyblocks.blocks", "canopyblocks.reference", "canopyblocks.validation",
             "canopyblocks.outputs", "canopyblocks.simulate", "canopyblocks.workflows",
             "canopyblocks.cli"]
    words = ["errors", "photons.py", "readers/", "blocks/", "reference/", "validation/",
             "outputs/", "simulate/", "workflows/", "cli/"]
    at = [diagram.rindex(w) for w in words]
    assert at == sorted(at, reverse=True), "the diagram's rooms are out of order"
    assert [place(m)[0] for m in order] == sorted(place(m)[0] for m in order)
    for room in LAYERS[0][1]:
        assert room.rpartition(".")[2] in diagram, f"{room} missing from the foundation"
    assert "DOOR_DEBT" in doc and "H5PY_DEBT" in doc
