"""Every script in ``examples/`` runs to the end and prints what it promises.

The scripts are what a reader opens first; they run here as a reader runs them, in a
fresh interpreter from a scratch folder, against this checkout's sources.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

import gridstrain

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCRIPTS = sorted(EXAMPLES.glob("*.py"))
# what each script must print: a line that only a run to the end produces
EXPECTED = {
    "00_plate_with_hole.py": "RMS error of exx",
    "01_pair.py": "with sensor noise",
    "02_vibrated_stack.py": "theory sqrt(T)",
    "03_noise_and_uncertainty.py": "measured  std of exx",
    "04_load_steps.py": "mean exx",
    "05_dask.py": "largest difference Dask - in process",
    "06_share_results.py": "report written",
    "07_choosing_sigma.py": "theory -2",
    "08_high_speed_sequence.py": "peak strain rate",
    "09_tensile_coupon.py": "intervals from the",
    "10_impact_stress_gauge.py": "95 % interval",
    "11_virtual_fields.py": "uniform shear: the measured fields cannot separate",
}


def test_every_example_is_listed():
    assert {p.name for p in SCRIPTS} == set(EXPECTED)


# the longest examples run in the slow run only; what each does is tested in the
# default one: Dask by tests/test_distributed.py (the example starts a cluster of its
# own), a result's exports and report by tests/test_results.py, a high-speed record by
# tests/test_sequences.py and tests/test_camera.py, a tensile coupon's E and nu by
# tests/test_post_constants.py
_SLOW_EXAMPLES = {"05_dask.py", "06_share_results.py", "08_high_speed_sequence.py",
                  "09_tensile_coupon.py"}


@pytest.mark.parametrize("script", [
    pytest.param(p, marks=pytest.mark.slow) if p.name in _SLOW_EXAMPLES else p
    for p in SCRIPTS], ids=[p.name for p in SCRIPTS])
def test_example_runs(script, tmp_path):
    if "dask" in script.name and importlib.util.find_spec("distributed") is None:
        pytest.skip("needs the distributed extra")
    src = str(Path(gridstrain.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=src, MPLBACKEND="Agg")
    args = [sys.executable, str(script)]
    if script.name in ("04_load_steps.py", "09_tensile_coupon.py"):
        args.append(str(tmp_path / "series"))
    res = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert EXPECTED[script.name] in res.stdout
