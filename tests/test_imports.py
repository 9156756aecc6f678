"""What importing the package and asking the command line for help load.

Checked in a fresh interpreter through ``sys.modules``, not timed: the start-up
figure itself lives in benchmarks/bench_pair.py.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import gridstrain
from gridstrain import cli

SRC = str(Path(gridstrain.__file__).resolve().parents[1])
HEAVY = ("matplotlib", "h5py", "dask", "distributed", "skimage", "scipy", "tifffile")


def _loaded_after(code: str) -> set[str]:
    script = (f"{code}\nimport sys\n"
              f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))\n")
    env = dict(os.environ, PYTHONPATH=SRC)
    res = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    return set(res.stdout.split())


def test_import_loads_no_heavy_dependency():
    assert _loaded_after("import gridstrain") == set()


def test_help_loads_no_heavy_dependency():
    code = ("import contextlib, io\nfrom gridstrain.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n        main(['--help'])\n    except SystemExit:\n        pass")
    assert _loaded_after(code) == set()


def test_public_names_resolve_on_first_use():
    code = "import gridstrain\nassert gridstrain.measure.__name__ == 'measure'"
    assert "skimage" in _loaded_after(code)


@pytest.mark.parametrize("first", ["import gridstrain.kinematics",
                                   "from gridstrain import wft",
                                   "import gridstrain.phase",
                                   "from gridstrain.phase import wft",
                                   "import gridstrain.phase._transform"])
def test_wft_is_the_function_whichever_loads_first(first):
    # the old module path gridstrain.wft is bound to the package when it loads; the
    # package's wft must stay the function, the one gridstrain.phase._transform implements
    code = (f"{first}\nimport gridstrain, warnings\nfrom gridstrain import wft\n"
            "assert callable(wft) and wft.__name__ == 'wft', wft\n"
            "assert gridstrain.wft is wft\n"
            "with warnings.catch_warnings(record=True) as caught:\n"
            "    warnings.simplefilter('always')\n"
            "    from gridstrain.wft import wft as w0\n"
            "assert w0 is wft and gridstrain.wft is wft, (w0, gridstrain.wft)\n"
            "assert [w.category for w in caught] == [DeprecationWarning], caught\n"
            "assert 'gridstrain.phase' in str(caught[0].message)\n"
            "from gridstrain.phase import wft as w2, PhaseMaps, wft_complex, transfer_function\n"
            "import gridstrain.phase._transform as impl\n"
            "assert w2 is wft is impl.wft and PhaseMaps is gridstrain.PhaseMaps\n"
            "assert wft_complex is impl.wft_complex\n"
            "assert transfer_function is impl.transfer_function")
    _loaded_after(code)


def test_every_public_name_resolves():
    for name in gridstrain.__all__:
        assert getattr(gridstrain, name) is not None
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = gridstrain.nope


def test_help_summaries_are_those_of_the_sub_command_parsers():
    full = cli.build_parser()
    (sub,) = [a for a in full._actions if a.dest == "command"]
    declared = {a.dest: a.help for a in sub._choices_actions}
    assert declared == {n: s for n, s in cli._COMMANDS.items() if n in declared}
    assert set(declared) == set(cli._COMMANDS)


def test_only_the_sub_command_run_is_built():
    parser = cli.build_parser(["reproduce"])
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    assert set(sub.choices) == set(cli._COMMANDS)
    # the others are summaries without arguments
    assert [a.dest for a in sub.choices["measure"]._actions] == []


def test_measure_command_loads_matplotlib_only_for_figures():
    assert "matplotlib" not in _loaded_after("import gridstrain.cli.measure")
