"""The benchmark scripts and the examples reach only names gridstrain has.

They are run by hand, not by the suite (benchmarks/README.md), so a name renamed in the
package would break one unseen until someone times it. Read with ``ast``: every name
imported from gridstrain, and every attribute read from a gridstrain module a script
holds by name (``import gridstrain.phase._transform as impl; impl.compiled_loops()``,
or through ``importlib.import_module``), must exist.
"""

from __future__ import annotations

import ast
import importlib
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted([*ROOT.glob("benchmarks/*.py"), *ROOT.glob("examples/*.py")])


def _imported(value) -> str | None:
    """The gridstrain module of ``importlib.import_module("gridstrain...")``, or None."""
    if isinstance(value, ast.Call) and isinstance(value.func, ast.Attribute) \
            and value.func.attr == "import_module" and len(value.args) == 1 \
            and isinstance(value.args[0], ast.Constant) \
            and str(value.args[0].value).split(".")[0] == "gridstrain":
        return value.args[0].value
    return None


def _missing(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    modules: dict[str, types.ModuleType] = {}  # local name -> the gridstrain module
    missing = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "gridstrain" and a.asname:
                    modules[a.asname] = importlib.import_module(a.name)
        elif isinstance(node, ast.Assign) and len(node.targets) == 1 \
                and isinstance(node.targets[0], ast.Name) and (name := _imported(node.value)):
            modules[node.targets[0].id] = importlib.import_module(name)  # importlib's
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] == "gridstrain":
            mod = importlib.import_module(node.module)
            for a in node.names:
                if not hasattr(mod, a.name):
                    try:  # a submodule not imported by its package
                        importlib.import_module(f"{node.module}.{a.name}")
                    except ImportError:
                        missing.append(f"{node.module}.{a.name}")
                        continue
                obj = getattr(mod, a.name)
                if isinstance(obj, types.ModuleType):
                    modules[a.asname or a.name] = obj
    for node in ast.walk(tree):
        # read or assigned: a switch set on a module that no longer has it (a flag
        # moved elsewhere) creates an attribute nothing reads, and the script silently
        # runs what it meant to switch off
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id in modules:
            mod = modules[node.value.id]
            if not hasattr(mod, node.attr):
                missing.append(f"{mod.__name__}.{node.attr} (line {node.lineno})")
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id == "setattr" and len(node.args) >= 2 \
                and isinstance(node.args[0], ast.Name) and node.args[0].id in modules \
                and isinstance(node.args[1], ast.Constant) \
                and isinstance(node.args[1].value, str):
            mod = modules[node.args[0].id]
            if not hasattr(mod, node.args[1].value):
                missing.append(f"{mod.__name__}.{node.args[1].value} (line {node.lineno})")
    return missing


def test_there_are_scripts_to_check():
    assert any(p.parent.name == "benchmarks" for p in SCRIPTS)


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_gridstrain_name_a_script_reaches_exists(path):
    assert _missing(path) == []


def test_a_renamed_name_is_caught(tmp_path):
    script = tmp_path / "bench_old.py"
    script.write_text("import importlib\n"
                      "from gridstrain.phase import _transform\n"
                      "import gridstrain.phase._transform as impl\n"
                      "from gridstrain.stacks import _PhaseMean\n"
                      "_impl = importlib.import_module('gridstrain.phase._transform')\n"
                      "def main():\n"
                      "    return _transform._kernels(), impl.compiled_loops(), _impl._kernels\n"
                      "def numpy_path():\n"
                      "    _impl._SWITCH = False\n"
                      "    setattr(impl, '_SWITCH', False)\n")
    assert sorted(_missing(script)) == sorted([
        "gridstrain.stacks._PhaseMean",
        "gridstrain.phase._transform._kernels (line 7)",
        "gridstrain.phase._transform._kernels (line 7)",
        "gridstrain.phase._transform._SWITCH (line 9)",
        "gridstrain.phase._transform._SWITCH (line 10)"])
