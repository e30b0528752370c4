"""The package's layers, read from its source (ast, no import): every import between its modules —
at the top of a module or inside a function, which runs later but is an arrow all the same — goes
down the layer order or stays in its layer, and no modules import each other in a circle.

The order: scene < core < dynamics < engine < runtime < ros < recording, batch < view < the
adapters (node, replay, plot, sweep, bench, programs), which import anything below them and not
each other; two folders of one rank do not import each other. The package's
own ``__init__`` (the version) is below every layer. A new top-level folder must be given its
place in `LAYERS` (an unplaced one is reported, not skipped).

Beside the arrows, one owner per fact, checked as a grep would: a literal that restates what an
owner module holds (a node parameter's range, the arm's offsets in q and u, a frame name, an
error type or an error matched by its name) is reported anywhere outside that owner.

And the engine's positional bookkeeping reads one way: a name bound by a family of indices
(``A, B = range(n)``, or a tuple of integer literals) is bound at the top of no other module, so
``KP`` cannot mean a wheel gain here and an arm gain there (`family_clashes`). And every module
has one job, at most MAX_LINES lines long (`long_modules`).

The checkers are tested on small fake trees that hold each kind of violation, so a check that
cannot fail would show here.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "mobile_manip_sim"
ADAPTERS = 8
# batch/ (many runs stepped together) builds on the engine and the runtime, and sweep/ and
# bench/ use it: below the adapters, beside recording/ (neither imports the other)
# bench/ measures every other program (a sweep among them): the top floor
# core/ (the compiled C++ core and its Python face) sits under dynamics/, which wraps it
# view/ (the browser view) reads recorded runs and is shown by simulate, replay and the node
LAYERS = {"scene": 0, "core": 1, "dynamics": 2, "engine": 3, "runtime": 4, "ros": 5,
          "recording": 6, "batch": 6, "view": 7, "node": ADAPTERS, "replay": ADAPTERS,
          "plot": ADAPTERS, "sweep": ADAPTERS, "bench": ADAPTERS + 1, "programs": ADAPTERS}


def modules(root: Path, package: str) -> dict[str, Path]:
    """Dotted module name → source file, for every module of the package under ``root``."""
    found = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports(name: str, path: Path, known: dict[str, Path], package: str) -> list[tuple[str, int]]:
    """(imported module of the package, line) for every import statement of one module,
    wherever it stands; ``from X import y`` names the module X.y when y is one, else X."""
    here = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = here.split(".")[:len(here.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base
                       for alias in node.names]
        else:
            continue
        found += [(target, node.lineno) for target in targets
                  if target == package or target.startswith(package + ".")]
    return found


def graph(root: Path, package: str) -> dict[str, list[tuple[str, int]]]:
    known = modules(root, package)
    return {name: imports(name, path, known, package) for name, path in known.items()}


def layer(name: str) -> str | None:
    """The layer folder of a dotted name (None: the package itself)."""
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else None


def arrows_up(root: Path, package: str, layers: dict[str, int]) -> list[str]:
    """One line per import that goes up the order or sideways between two adapters, and per
    module in a folder that has no place in the order."""
    found = []
    for name, targets in graph(root, package).items():
        source = layer(name)
        if source is not None and source not in layers:
            found.append(f"{name}: folder {source!r} has no place in the layer order")
            continue
        rank = -1 if source is None else layers[source]
        for target, line in targets:
            into = layer(target)
            if into is None or into == source:
                continue
            if into not in layers:
                found.append(f"{name}:{line} imports {target} (folder {into!r} has no place)")
            elif layers[into] > rank or (layers[into] == rank and source != into):
                found.append(f"{name}:{line} imports {target}: {source} may not import {into}")
    return found


def circles(root: Path, package: str) -> list[list[str]]:
    """The import circles: strongly connected components of more than one module (or a module
    that imports itself), by Tarjan's algorithm."""
    edges = {name: sorted({target for target, _ in targets})
             for name, targets in graph(root, package).items()}
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in edges.get(node, ()):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1 or node in edges.get(node, ()):
                found.append(sorted(component))

    for node in sorted(edges):
        if node not in index:
            visit(node)
    return found


# --- the package ------------------------------------------------------------------------------

def test_every_folder_of_the_package_has_a_place_in_the_order():
    folders = {p.name for p in (ROOT / PACKAGE).iterdir() if (p / "__init__.py").is_file()}
    assert folders - set(LAYERS) == set()


def test_no_import_goes_up_the_layers():
    assert arrows_up(ROOT, PACKAGE, LAYERS) == []


def test_no_import_circle():
    assert circles(ROOT, PACKAGE) == []


def test_the_graph_sees_the_imports_inside_functions():
    """recording/bag_format.py reads a scene through a function-level import."""
    targets = {t for t, _ in graph(ROOT, PACKAGE)[f"{PACKAGE}.recording.bag_format"]}
    assert f"{PACKAGE}.scene.loading" in targets


# --- one owner per fact -----------------------------------------------------------------------

NUMBER = r"-?\d[\d_]*\.?\d*(?:e[+-]?\d+)?"
# (what, owner module (a path under the package, or a folder of it), pattern, files it scans)
OWNERS = [
    ("a node parameter's range", "scene/limits.py",
     re.compile(rf"\(\s*{NUMBER}\s*,\s*{NUMBER}\s*\)"), "node/parameters.py"),
    ("the arm's size or offset in q and u", "scene/coordinates.py",
     re.compile(r"\bn_?u\s*-\s*2\b|\b2\s*\*\s*(?:[a-z_]+\.)*n_links\b|\b2\s*\+\s*j\b"
                r"|\b2\s*\*\s*k\s*[-+]\s*[12]\b|len\([\w.]*names\)\s*-\s*2"), None),
    ("a frame name", "ros/frames.py",
     re.compile(r"[\"'](?:odom|base_footprint|base_link)[\"']"), None),
    ("an error type", "scene/errors.py", re.compile(r"^class \w+Error\("), None),
    ("an error matched by its name", "scene/errors.py",
     re.compile(r"\btype\([^)]*\)\.__name__\s*(?:==|!=|in\b|not in\b)|__name__ for \w+ in"
                r"|[\"'](?:User|Simulation|StepLimit)Error[\"']"), None),
]


def restated(root: Path, package: str, owners=OWNERS) -> list[str]:
    """One line per literal of an owner's fact found outside the owner."""
    found = []
    for what, owner, pattern, only in owners:
        for path in sorted((root / package).rglob("*.py")):
            relative = path.relative_to(root / package).as_posix()
            if relative == owner or (only is not None and relative != only):
                continue
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if pattern.search(line):
                    found.append(f"{relative}:{number}: {what} belongs to {owner}: "
                                 f"{line.strip()}")
    return found


def test_each_fact_is_written_by_its_owner_only():
    assert restated(ROOT, PACKAGE) == []


def test_the_owner_check_finds_planted_literals(tmp_path):
    fake_tree(tmp_path, {"node/parameters.py": 'RATE = Parameter(1.0, "Hz", (0.001, 1e5))\n'
                                               'PORT = Parameter(0, "port", limits.PORT)\n',
                         "engine/arm.py": "n_arm = nu - 2\nout[2 * k - 1] = f\n"
                                          "z = np.zeros(2 * robot.n_links)\nQ[2 + j] = tau\n"
                                          "arm = len(self.names) - 2\n",
                         "ros/messages.py": 'def odometry(frame="odom"):\n',
                         "node/loop.py": 'ours = type(error).__name__ in ("UserError",)\n',
                         "engine/run.py": "class RunError(RuntimeError):\n    pass\n",
                         "scene/coordinates.py": "def u_size(n):\n    return 2 + 2 * n\n"})
    found = restated(tmp_path, "pkg")
    assert [line.split(": ")[0:2] for line in found] == [
        ["node/parameters.py:1", "a node parameter's range belongs to scene/limits.py"],
        ["engine/arm.py:1", "the arm's size or offset in q and u belongs to scene/coordinates.py"],
        ["engine/arm.py:2", "the arm's size or offset in q and u belongs to scene/coordinates.py"],
        ["engine/arm.py:3", "the arm's size or offset in q and u belongs to scene/coordinates.py"],
        ["engine/arm.py:4", "the arm's size or offset in q and u belongs to scene/coordinates.py"],
        ["engine/arm.py:5", "the arm's size or offset in q and u belongs to scene/coordinates.py"],
        ["ros/messages.py:1", "a frame name belongs to ros/frames.py"],
        ["engine/run.py:1", "an error type belongs to scene/errors.py"],
        ["node/loop.py:1", "an error matched by its name belongs to scene/errors.py"],
    ]


# --- positional families ------------------------------------------------------------------------

def is_family(value: ast.expr) -> bool:
    """``range(n)``, a tuple of integer literals, or a generator of ids: positions in an array."""
    if isinstance(value, ast.Call):
        return isinstance(value.func, ast.Name) and value.func.id == "range"
    if isinstance(value, ast.Tuple):
        return all(isinstance(e, ast.Constant) and type(e.value) is int for e in value.elts)
    return isinstance(value, ast.GeneratorExp)


def top_level_names(path: Path) -> list[tuple[str, int, bool]]:
    """(name, line, bound by a positional family) for every name a module binds at its top."""
    found = []
    for node in ast.parse(path.read_text(encoding="utf-8"), str(path)).body:
        if isinstance(node, ast.Assign):
            targets, value = node.targets, node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            targets, value = [node.target], node.value
        else:
            continue
        for target in targets:
            if isinstance(target, ast.Name):
                found.append((target.id, node.lineno, False))
            elif isinstance(target, ast.Tuple):
                family = is_family(value)
                found += [(e.id, node.lineno, family) for e in target.elts
                          if isinstance(e, ast.Name)]
    return found


def family_clashes(root: Path, package: str) -> list[str]:
    """One line per name that a positional family binds in one module and another module binds
    at its top too (in a family or not)."""
    bound: dict[str, list[tuple[str, int, bool]]] = {}
    for path in sorted((root / package).rglob("*.py")):
        relative = path.relative_to(root / package).as_posix()
        for name, line, family in top_level_names(path):
            bound.setdefault(name, []).append((relative, line, family))
    found = []
    for name, where in sorted(bound.items()):
        if len({module for module, _, _ in where}) > 1 and any(f for _, _, f in where):
            found.append(f"{name}: " + ", ".join(f"{module}:{line}" for module, line, _ in where))
    return found


def test_no_two_modules_share_a_positional_name():
    assert family_clashes(ROOT, PACKAGE) == []


def test_the_family_check_finds_a_shared_name(tmp_path):
    fake_tree(tmp_path, {"engine/system.py": "MODE, KP, KI = range(3)\nSIZE = 3\n",
                         "engine/arm.py": "KP, KD = 0, 1\nLIMIT = (0.0, 1.0)\n",
                         "scene/limits.py": "KI = (0.0, 1e6)\nSIZE = 4\nLIMIT = 2\n",
                         "bench/runs.py": "DT, DURATION = 0.01, 2.0\nMODE = 'x'\n"})
    assert family_clashes(tmp_path, "pkg") == [
        "KI: engine/system.py:1, scene/limits.py:1",
        "KP: engine/arm.py:1, engine/system.py:1",
        "MODE: bench/runs.py:2, engine/system.py:1"]


# --- module size --------------------------------------------------------------------------------

MAX_LINES = 450


def long_modules(root: Path, package: str, limit: int = MAX_LINES) -> list[str]:
    """One line per module of more than ``limit`` lines."""
    found = []
    for path in sorted((root / package).rglob("*.py")):
        lines = len(path.read_text(encoding="utf-8").splitlines())
        if lines > limit:
            found.append(f"{path.relative_to(root / package).as_posix()}: {lines} lines")
    return found


def test_every_module_is_at_most_450_lines():
    assert long_modules(ROOT, PACKAGE) == []


def test_the_size_check_finds_a_long_module(tmp_path):
    fake_tree(tmp_path, {"engine/long.py": "x = 1\n" * 451, "engine/short.py": "x = 1\n" * 450})
    assert long_modules(tmp_path, "pkg") == ["engine/long.py: 451 lines"]


# --- the checker on planted violations --------------------------------------------------------

def fake_tree(root: Path, files: dict[str, str]) -> None:
    for relative, text in files.items():
        path = root / "pkg" / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    for folder in {(root / "pkg" / r).parent for r in files} | {root / "pkg"}:
        (folder / "__init__.py").touch()


FAKE_LAYERS = {"scene": 0, "engine": 1, "node": 2, "plot": 2}


def test_the_checker_finds_an_arrow_up_even_inside_a_function(tmp_path):
    fake_tree(tmp_path, {"scene/model.py": "def f():\n    from pkg.engine import run\n",
                         "engine/run.py": "from pkg.scene import model\n"})
    assert arrows_up(tmp_path, "pkg", FAKE_LAYERS) == [
        "pkg.scene.model:2 imports pkg.engine.run: scene may not import engine"]


def test_the_checker_finds_relative_imports_and_sideways_adapters(tmp_path):
    fake_tree(tmp_path, {"node/shell.py": "from ..plot import figures\n",
                         "plot/figures.py": "from ..scene import model\n",
                         "scene/model.py": "from . import coordinates\n",
                         "scene/coordinates.py": ""})
    assert arrows_up(tmp_path, "pkg", FAKE_LAYERS) == [
        "pkg.node.shell:1 imports pkg.plot.figures: node may not import plot"]


def test_the_checker_reports_a_folder_without_a_place(tmp_path):
    fake_tree(tmp_path, {"batch/lanes.py": "import pkg.engine.run\n", "engine/run.py": ""})
    assert arrows_up(tmp_path, "pkg", FAKE_LAYERS) == [
        "pkg.batch: folder 'batch' has no place in the layer order",
        "pkg.batch.lanes: folder 'batch' has no place in the layer order"]


def test_the_checker_finds_a_circle(tmp_path):
    fake_tree(tmp_path, {"scene/a.py": "from pkg.scene import b\n",
                         "scene/b.py": "def f():\n    import pkg.scene.c\n",
                         "scene/c.py": "from pkg.scene.a import x\n",
                         "scene/d.py": "from pkg.scene import a\n"})
    assert circles(tmp_path, "pkg") == [["pkg.scene.a", "pkg.scene.b", "pkg.scene.c"]]
    assert arrows_up(tmp_path, "pkg", FAKE_LAYERS) == []
