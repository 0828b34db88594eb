"""The runtime's import graph (issue 27): no import circle, no module over ~800 lines, light imports at the top.

Each rule is a pure function over a folder of Python files, run on runtime/ and on a small tree made here
that breaks it (so each rule is shown to fail)."""
from __future__ import annotations

import ast
import functools
import sys
from pathlib import Path
from typing import Iterable

from conftest import REPO

PKG = "mosaicthinker.runtime"
MAX_LINES = 800
ALLOWED_CIRCLES: list[set[str]] = []
ALLOWED_LONG: set[str] = set()
# third-party libraries with an import cost (numpy, OpenCV, SciPy, onnxruntime, Pillow, tqdm), optional ones (the
# VLM runtime) and the host tools may be imported where they are used, so the CLI's first line and a saved-map
# question stay fast; the standard library and the runtime's own modules are imported at the top
LIGHT_THIRD_PARTY: set[str] = set()
# the one deliberate exception: the CLI entry point prints its first line before anything but argument parsing
# loads (importlib.metadata, psutil, a command's module: `benchmarks/first_line.py`)
DEFERRED_MODULES = {"cli"}


def modules(root: Path, pkg: str = PKG) -> dict[str, Path]:
    """Dotted name (relative to `pkg`, '' for the package itself) -> file, for every .py under root."""
    out = {}
    for p in sorted(root.rglob("*.py")):
        parts = list(p.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _is_package(name: str, mods: dict[str, Path]) -> bool:
    return name == "" or mods[name].name == "__init__.py"


def _targets(node: ast.AST, name: str, mods: dict[str, Path], pkg: str) -> list[str]:
    """The runtime modules an import statement of module `name` loads (relative to `pkg`)."""
    here = name.split(".") if _is_package(name, mods) else name.split(".")[:-1]
    here = [h for h in here if h]
    found: list[str] = []
    if isinstance(node, ast.ImportFrom):
        if node.level:
            base = here[:len(here) - node.level + 1] if node.level > 1 else here
            mod = ".".join(base + ([node.module] if node.module else []))
        elif node.module and (node.module == pkg or node.module.startswith(pkg + ".")):
            mod = node.module[len(pkg):].lstrip(".")
        else:
            return []
        for a in node.names:  # `from . import x` where x is a module
            sub = f"{mod}.{a.name}" if mod else a.name
            found.append(sub if sub in mods else mod)
    elif isinstance(node, ast.Import):
        for a in node.names:
            if a.name == pkg or a.name.startswith(pkg + "."):
                found.append(a.name[len(pkg):].lstrip("."))
    return [f for f in found if f in mods]


def import_graph(root: Path, pkg: str = PKG) -> dict[str, set[str]]:
    """module -> the runtime modules it imports (anywhere in the file). Importing a.b.c also runs the __init__ of
    a and a.b, unless the importer is inside them (then they are already being imported)."""
    mods = modules(root, pkg)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, path in mods.items():
        inside = name.split(".")
        for node in ast.walk(ast.parse(path.read_text())):
            for t in _targets(node, name, mods, pkg):
                parts = t.split(".") if t else []
                for k in range(1, len(parts) + 1):
                    anc = ".".join(parts[:k])
                    if anc == t or inside[:k] != parts[:k]:
                        graph[name].add(anc)
    for m in graph:
        graph[m].discard(m)
    return graph


def circles(graph: dict[str, set[str]]) -> list[set[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[set[str]] = []
    sys.setrecursionlimit(max(10000, sys.getrecursionlimit()))

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def long_modules(root: Path, limit: int = MAX_LINES) -> dict[str, int]:
    return {m: n for m, p in modules(root).items() if (n := len(p.read_text().splitlines())) > limit}


def inner_light_imports(root: Path, pkg: str = PKG, skip: Iterable[str] = (),
                        deferred: Iterable[tuple[str, str]] = ()) -> list[str]:
    """'module:line name' of every import inside a function or class body of a light module: the runtime's own
    modules, numpy or the standard library. Imports inside a `try` (an optional or platform module), the modules in
    `skip` and the (module, target) pairs in `deferred` are left out."""
    mods = modules(root, pkg)
    out = []
    for name, path in mods.items():
        if name in set(skip):
            continue
        tree = ast.parse(path.read_text())
        top = set(map(id, tree.body))
        guarded = {id(m) for n in ast.walk(tree) if isinstance(n, ast.Try) for m in ast.walk(n)}
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)) or id(node) in top or id(node) in guarded:
                continue
            if _top_level_try(tree, node):
                continue
            targets = _targets(node, name, mods, pkg)
            if targets and all((name, t) in set(deferred) for t in targets):
                continue
            light = bool(targets) or (isinstance(node, ast.ImportFrom) and node.level > 0)
            for mod in ([node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level
                        else [a.name for a in node.names] if isinstance(node, ast.Import) else []):
                first = mod.split(".")[0]
                light |= first in LIGHT_THIRD_PARTY or first in sys.stdlib_module_names
            if light:
                out.append((name, node.lineno, f"{name}:{node.lineno} {ast.unparse(node)}"))
    return [x for _, _, x in sorted(out)]


def _top_level_try(tree: ast.Module, node: ast.AST) -> bool:
    """An import in a module-level try/if (an optional dependency, a Python-version switch) is a top import."""
    for stmt in tree.body:
        if isinstance(stmt, (ast.Try, ast.If)) and any(n is node for n in ast.walk(stmt)):
            return not any(isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and
                           any(m is node for m in ast.walk(n)) for n in ast.walk(stmt))
    return False


# ----------------------------------------------------------------------------- the runtime


@functools.lru_cache(maxsize=1)
def runtime_graph() -> dict[str, frozenset[str]]:
    """The runtime's import graph, built once for the tests that read it."""
    return {m: frozenset(t) for m, t in import_graph(REPO / "runtime").items()}


def test_no_import_circle_but_the_two_issue_30_removes():
    graph = {m: set(t) for m, t in runtime_graph().items()}
    assert len(graph) > 50 and sum(map(len, graph.values())) > 100  # the runtime was read, not an empty glob
    found = circles(graph)
    assert [c for c in found if c not in ALLOWED_CIRCLES] == []


# the stage packages and modules (README, "How a question is answered") and what wires them
STAGES = {"frames", "scan", "grounding", "query", "keyframes", "perceive", "align", "map", "prompt", "answer",
          "detectable", "pipeline", "budget", "commands", "cli"}


def stage_imports(graph: dict[str, set[str]], below: str = "models") -> dict[str, list[str]]:
    """module of package `below` -> the stage modules it imports (only modules that import one)."""
    out = {m: sorted(t for t in ts if t.split(".")[0] in STAGES) for m, ts in graph.items()
           if m.split(".")[0] == below}
    return {m: t for m, t in out.items() if t}


def test_model_adapters_import_no_stage():
    """runtime/models/ sits below every stage: what an adapter borrows lives in geometry, planes, types or infra."""
    assert stage_imports({m: set(t) for m, t in runtime_graph().items()}) == {}


def script_graph(root: Path) -> dict[str, set[str]]:
    """Scripts beside each other (benchmarks/, tests/) that import one another by plain name: stem -> the sibling
    stems it imports (anywhere in the file)."""
    files = {p.stem: p for p in sorted(root.glob("*.py"))}
    graph: dict[str, set[str]] = {m: set() for m in files}
    for name, path in files.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and not node.level and node.module:
                graph[name].add(node.module.split(".")[0])
            elif isinstance(node, ast.Import):
                graph[name] |= {a.name.split(".")[0] for a in node.names}
        graph[name] = {t for t in graph[name] if t in files and t != name}
    return graph


def test_no_import_circle_anywhere_in_the_repository():
    """host/ and export/ as packages, benchmarks/ and tests/ as scripts importing their siblings (the runtime has its
    own test above); none of them is imported by the runtime, so no circle can pass through it."""
    graphs = {"host": import_graph(REPO / "host", "mosaicthinker.host"),
              "export": import_graph(REPO / "export", "mosaicthinker.export"),
              "benchmarks": script_graph(REPO / "benchmarks"), "tests": script_graph(REPO / "tests")}
    assert len(graphs["benchmarks"]) > 20 and {"make_holdout10", "check_holdout10"} <= set(graphs["benchmarks"])
    assert "make_holdout10" in graphs["benchmarks"]["check_holdout10"]  # the scan sees sibling imports
    assert {k: circles(g) for k, g in graphs.items() if circles(g)} == {}


def test_a_circle_between_scripts_is_found(tmp_path):
    (tmp_path / "make_a.py").write_text("def main():\n    from check_a import run\n")
    (tmp_path / "check_a.py").write_text("from make_a import main\nimport json\n")
    assert script_graph(tmp_path) == {"check_a": {"make_a"}, "make_a": {"check_a"}}
    assert circles(script_graph(tmp_path)) == [{"check_a", "make_a"}]


def test_no_module_over_800_lines_but_the_query_work():
    assert set(long_modules(REPO / "runtime")) <= ALLOWED_LONG


def test_light_modules_are_imported_at_the_top():
    assert inner_light_imports(REPO / "runtime", skip=ALLOWED_LONG | DEFERRED_MODULES) == []


# ----------------------------------------------------------------------------- each rule can fail


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "runtime"
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return root


def test_a_circle_is_found_through_a_package_and_a_function_body(tmp_path):
    root = _tree(tmp_path, {
        "__init__.py": "",
        "a.py": "from .pkg.b import x\n",
        "pkg/__init__.py": "from .b import x\n",
        "pkg/b.py": "x = 1\n",
        "pkg/c.py": "def f():\n    from ..a import y\n",
        "pkg/d.py": "from . import c\n",   # inside pkg: no edge back to pkg's own __init__
    })
    g = import_graph(root)
    assert g["pkg.b"] == set() and g["pkg.d"] == {"pkg.c"}
    assert circles(g) == []
    (root / "pkg" / "b.py").write_text("from ..a import z\nx = 1\n")  # a -> pkg -> pkg.b -> a
    assert circles(import_graph(root)) == [{"a", "pkg", "pkg.b"}]


def test_a_model_adapter_importing_a_stage_is_found(tmp_path):
    root = _tree(tmp_path, {"__init__.py": "", "geometry.py": "", "map/__init__.py": "", "map/floor.py": "",
                            "models/__init__.py": "", "models/depth.py": "from ..geometry import x\n"})
    assert stage_imports(import_graph(root)) == {}
    (root / "models" / "depth.py").write_text("from ..map.floor import fit_floor_plane\n")
    assert stage_imports(import_graph(root)) == {"models.depth": ["map", "map.floor"]}


def test_a_long_module_is_found(tmp_path):
    root = _tree(tmp_path, {"__init__.py": "", "short.py": "x = 1\n" * 10, "long.py": "x = 1\n" * 801})
    assert long_modules(root) == {"long": 801}


def test_an_inner_import_of_a_light_module_is_found(tmp_path):
    root = _tree(tmp_path, {
        "__init__.py": "",
        "a.py": "import numpy as np\ntry:\n    import tomllib\nexcept ImportError:\n    tomllib = None\n"
                "def f():\n    import cv2\n    from mosaicthinker.host import x\n",
        "b.py": "def g():\n    from .a import f\n    import json\n\nclass C:\n    def h(self):\n        import numpy\n"
                "def k():\n    try:\n        import resource\n    except ImportError:\n        pass\n"
                "    from . import a\n",
    })
    assert inner_light_imports(root) == ["b:2 from .a import f", "b:3 import json", "b:13 from . import a"]
    assert inner_light_imports(root, deferred={("b", "a")}) == ["b:3 import json"]
    assert inner_light_imports(root, skip={"b"}) == []
