"""The layers of the package: the numerical core never imports its edges.

Read from the sources with ``ast`` (nothing is imported), so the check holds for
imports inside functions too. The layers (docs/architecture.md):

- the core: one module per concept of the method (lattice, transform, kinematics,
  stacks, vibration, noise, uncertainty, theory, synthetic data) and its private
  helpers. It computes on arrays and knows nothing of files, command lines,
  figures or clusters.
- the edges: reading and writing files, the series workflow, figures, the paper's
  experiment, Dask and the command line. They may import the core and each other.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import gridstrain

PACKAGE = Path(gridstrain.__file__).resolve().parent

CORE = {
    "conventions", "_validation", "_progress", "_fft", "lattice", "phase", "phase.lattice",
    "phase._transform", "phase._kernels", "wft", "kinematics",
    "stacks", "stacks._methods", "stacks.vibration", "stacks.screening", "stacks.accumulate",
    "vibration", "screening", "accumulate", "noise", "uncertainty", "theory",
    "synthetic", "uncertainty._maps", "uncertainty._biases", "uncertainty._noise",
    "uncertainty._noise_image",
    "kirsch", "kinematics._deformation", "kinematics._fringe_order", "kinematics._spline_kernels",
    "_threads", "_stats",
}


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE).with_suffix("")
    parts = [p for p in rel.parts if p != "__init__"]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _imports(name: str, path: Path, known: set[str]) -> set[tuple[str, bool]]:
    """(imported module, at top level) pairs of ``gridstrain`` modules."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    pkg = name.split(".")[:-1] if path.name != "__init__.py" else name.split(".")
    pkg = [p for p in pkg if p]
    top = {id(n) for n in tree.body}
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names if a.name.startswith("gridstrain.")]
            targets = [t.removeprefix("gridstrain.") for t in targets]
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
                sub = f"{mod}.{a.name}" if mod else a.name
                targets.append(sub if sub in known else mod)
        else:
            continue
        for t in targets:
            if t and t in known:
                found.add((t, id(node) in top))
    return found


def _graph():
    mods = _modules()
    known = set(mods)
    return {name: _imports(name, path, known) for name, path in mods.items()}


def test_core_modules_exist():
    # the list above names real modules: a renamed module must be renamed here too
    assert set(_modules()) >= CORE


def test_core_never_imports_the_edges():
    graph = _graph()
    bad = sorted((m, t) for m in CORE for t, _ in graph[m] if t not in CORE)
    assert not bad, f"core modules importing edge modules: {bad}"


def test_no_import_cycles_at_module_level():
    graph = {m: {t for t, top in deps if top and t != m} for m, deps in _graph().items()}
    # the package's __init__ re-exports; submodules importing names from it form no
    # cycle once it has finished importing the core, so it is left out of the walk
    graph.pop("", None)
    for deps in graph.values():
        deps.discard("")
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for t in sorted(graph.get(m, ())):
            if state.get(t) == 1:
                raise AssertionError("import cycle: " + " -> ".join([*stack[stack.index(t):], t]))
            if t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_the_check_sees_a_violation(tmp_path, monkeypatch):
    # the checker itself: a core module that imports io is caught
    fake = tmp_path / "gridstrain"
    fake.mkdir()
    (fake / "__init__.py").write_text("")
    (fake / "io.py").write_text("")
    (fake / "lattice.py").write_text("from .io import read\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    graph = _graph()
    assert ("io", True) in graph["lattice"]
