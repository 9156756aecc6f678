"""The layers of the package: the numerical core never imports its edges, and no import
cycle exists.

Read from the sources with ``ast`` (nothing is imported), so the checks hold for imports
inside functions too. A name imported from a package's ``__init__`` counts as imported
from the module that defines it (the package's face only re-exports). The layers
(docs/architecture.md):

- the core: one folder or module per concept of the method (``phase``: lattice, window,
  transform; ``stacks``: methods A/B/C, the streamed pass, vibrations, screening;
  ``kinematics``, the discontinuities included; ``uncertainty``; ``theory``; ``models``,
  the synthetic images and the analytic fields) and
  its private helpers. It computes on arrays and knows nothing of files, command lines,
  figures or clusters.
- the edges: reading and writing files (``io``, ``results``), the series measurement
  (``series``, Dask included), post-processing, figures and the report (``post``), the
  paper's experiment and the command line. They may import the core and each other, without a cycle.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import gridstrain

PACKAGE = Path(gridstrain.__file__).resolve().parent

# top-level parts of the package (a folder or a flat module) that form the core
CORE = {
    "conventions", "_validation", "_progress", "_runtime", "_stats",
    "phase", "stacks", "kinematics", "uncertainty", "theory", "models",
}

# private names still imported across parts, each for a reason a test pins down
SHARED_PRIVATE: set = set()


def _module_name(path: Path, root: Path) -> str:
    rel = path.relative_to(root).with_suffix("")
    parts = [p for p in rel.parts if p != "__init__"]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p, PACKAGE): p for p in sorted(PACKAGE.rglob("*.py"))}


def _part(name: str) -> str:
    return name.split(".")[0]


def _reexports(mods: dict[str, Path]) -> dict[str, dict[str, str]]:
    """For each package, the module each name of its ``__init__`` comes from."""
    out = {}
    for name, path in mods.items():
        if path.name != "__init__.py":
            continue
        table = {}
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
                src = f"{name}.{node.module}" if name else node.module
                for a in node.names:
                    table[a.asname or a.name] = src
        out[name] = table
    return out


def _resolve(target: str, imported: str, known: set[str], faces: dict) -> str:
    """The module a name ``imported`` from ``target`` is defined in."""
    sub = f"{target}.{imported}" if target else imported
    if sub in known:
        return sub
    seen = set()
    while target in faces and imported in faces[target] and target not in seen:
        seen.add(target)
        target = faces[target][imported]
    return target


def _imports(name: str, path: Path, known: set[str], faces: dict):
    """``(imported module, at top level, imported name)`` of ``gridstrain`` modules."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    pkg = name.split(".")[:-1] if path.name != "__init__.py" else name.split(".")
    pkg = [p for p in pkg if p]
    top = {id(n) for n in tree.body}
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [(a.name.removeprefix("gridstrain."), "") for a in node.names
                       if a.name.startswith("gridstrain.")]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - (node.level - 1)] if node.level > 1 else pkg
                mod = ".".join([*base, *([node.module] if node.module else [])])
            elif node.module and node.module.startswith("gridstrain"):
                mod = node.module.removeprefix("gridstrain").lstrip(".")
            else:
                continue
            targets = []
            for a in node.names:
                t = _resolve(mod, a.name, known, faces)
                # a module imported by name is the module, not a name of its package
                targets.append((t, "" if t == (f"{mod}.{a.name}" if mod else a.name) else a.name))
        else:
            continue
        for t, what in targets:
            if t in known:
                found.add((t, id(node) in top, what))
    return found


def _graph():
    mods = _modules()
    known = set(mods)
    faces = _reexports(mods)
    return {name: _imports(name, path, known, faces) for name, path in mods.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for t in sorted(graph.get(m, ())):
            if state.get(t) == 1:
                return [*stack[stack.index(t):], t]
            if t not in state:
                found = visit(t)
                if found:
                    return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def _edges(graph) -> dict[str, set[str]]:
    # the package's own __init__ loads its names on first use (PEP 562): submodules
    # importing names from it form no cycle, so it is left out of the walk
    edges = {m: {t for t, _, _ in deps if t != m} for m, deps in graph.items()}
    edges.pop("", None)
    for deps in edges.values():
        deps.discard("")
    return edges


def test_core_modules_exist():
    # the list above names real parts: a renamed part must be renamed here too
    assert {_part(m) for m in _modules() if m} >= CORE


def test_core_never_imports_the_edges():
    graph = _graph()
    bad = sorted((m, t) for m, deps in graph.items() if m and _part(m) in CORE
                 for t, _, _ in deps if t and _part(t) not in CORE)
    assert not bad, f"core modules importing edge modules: {bad}"


def test_no_import_cycles_function_level_imports_included():
    cycle = _cycle(_edges(_graph()))
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_no_private_name_is_shared_across_parts():
    # what one part shares with another has a public name (a private one is the part's
    # own business), the few listed above aside
    graph = _graph()
    shared = {(m, f"{t}.{what}") for m, deps in graph.items() for t, _, what in deps
              if what.startswith("_") and not what.startswith("__") and t
              and f"{t}.{what}" not in graph and _part(t) != _part(m)}
    assert shared <= SHARED_PRIVATE, f"private names used across parts: {shared - SHARED_PRIVATE}"


def _fake_package(tmp_path, files: dict[str, str]) -> Path:
    fake = tmp_path / "gridstrain"
    for name, text in {"__init__.py": "", **files}.items():
        (fake / name).parent.mkdir(parents=True, exist_ok=True)
        (fake / name).write_text(text)
    return fake


def test_the_check_sees_a_violation(tmp_path, monkeypatch):
    # the checker itself: a core module that imports io is caught
    fake = _fake_package(tmp_path, {"io.py": "", "lattice.py": "from .io import read\n"})
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    graph = _graph()
    assert ("io", True, "read") in graph["lattice"]


def test_the_check_sees_a_cycle_through_a_function_and_a_package_face(tmp_path, monkeypatch):
    # b imports a inside a function, a imports b's name through its package's face
    fake = _fake_package(tmp_path, {
        "p/__init__.py": "from .b import f\n", "p/b.py": "def f():\n    from ..a import g\n",
        "a.py": "from .p import f\ndef g():\n    pass\n"})
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    assert _cycle(_edges(_graph())) == ["a", "p.b", "a"]
