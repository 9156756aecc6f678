"""Shared helpers of the benchmark scripts: machine description, timing, test images."""

from __future__ import annotations

import contextlib
import math
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy

from gridstrain import Lattice
from gridstrain.models import synthetic
from gridstrain.phase import _maps as _phase_loops


@contextlib.contextmanager
def phase_loops_off():
    """The phase folder's compiled loops switched off (its one switch,
    ``gridstrain.phase._maps._COMPILED``) while the block runs: the numpy paths a
    machine without numba runs, timed beside the compiled ones."""
    saved = _phase_loops._COMPILED
    _phase_loops._COMPILED = False
    try:
        yield
    finally:
        _phase_loops._COMPILED = saved


def machine() -> str:
    """One line naming the CPU, the cores this process may use and the load."""
    model = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = ""
    if hasattr(os, "getloadavg"):
        load = ", load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    return (f"{model}, {os.cpu_count()} logical cores ({usable} usable){load}; "
            f"Python {platform.python_version()}, numpy {np.__version__}, "
            f"scipy {scipy.__version__}")


def interleaved(funcs: dict, repeat: int) -> dict:
    """Wall and CPU times, s, of each callable, run in turn ``repeat`` times.

    Returns ``{name: (best wall, median wall, best CPU)}``. Interleaving spreads any
    slowdown of the machine over all the candidates, so that their ratios hold even
    when the absolute times drift; the CPU time of this process (all its threads)
    is what a single-threaded candidate would take on an idle machine, less the
    cache and memory contention of the other processes.
    """
    wall = {name: [] for name in funcs}
    cpu = {name: [] for name in funcs}
    for f in funcs.values():  # warm-up: plans, caches, first-touch of memory
        f()
    for _ in range(repeat):
        for name, f in funcs.items():
            c0, t0 = time.process_time(), time.perf_counter()
            f()
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    return {name: (min(wall[name]), float(np.median(wall[name])), min(cpu[name]))
            for name in funcs}


def issue_phases(shape):
    """Phase modulations of the paper's synthetic example (maxima 0.06 and 0.42 rad).

    Gaussian bumps whose width makes the largest phase derivative 0.005 rad/px,
    the values quoted in ``shared/paper/README.md``.
    """
    H, W = shape
    width = 0.42 * math.exp(-0.5) / 0.005  # px: max |d phi2/dx| = 0.005 rad/px

    def phases(X, Y):
        r2 = ((X - W / 2) ** 2 + (Y - H / 2) ** 2) / (2 * width**2)
        bump = np.exp(-r2)
        return 0.06 * bump, 0.42 * bump

    return phases


def grid_test_image(shape, *, pitch: float = 5.0, noisy: bool = True, seed: int = 0,
                    amplitude: float = 2048.0):
    """A 12-bit-like grid image of ``shape`` with the issue's phase fields."""
    lattice = Lattice.from_pitch(pitch)
    img = synthetic.grid_image(shape, lattice, amplitude=amplitude,
                               phases=issue_phases(shape))
    if noisy:
        img = synthetic.add_noise(img, rng=seed)
    return lattice, img


# --- series on disk and child processes, for the scripts that run the command line ---

ROOT = Path(__file__).resolve().parents[1]
# BLAS and OpenMP pools asked for one thread in the children timed by CPU time: their
# spinning threads would count as work (gridstrain's own threads are not affected)
ONE_THREAD = dict.fromkeys(("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                            "NUMEXPR_NUM_THREADS"), "1")


def child_env(*, one_thread: bool = False) -> dict:
    """This process's environment with the checkout's ``src`` first on PYTHONPATH."""
    env = dict(os.environ, **(ONE_THREAD if one_thread else {}))
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "src"),
                                                      env.get("PYTHONPATH")]))
    return env


def state_displacement(step: int, width: int):
    """Lagrangian displacement of loaded state ``step`` (1, 2, ...), ``(X, Y) -> (u_x, u_y)``.

    A translation of (0.3, -0.2) px and a strain e_xx = 5e-4 about the image centre
    per step: consecutive states differ by less than a pixel at 2048 px, well within
    the half period that lets the fringe order follow from one state to the next.
    """
    cx = (width - 1) / 2

    def field(X, Y):
        return step * (0.3 + 5e-4 * (X - cx)), step * (-0.2 + 0.0 * Y)

    return field


def write_states(root, shape, frames: int, n_states: int, *, pitch: float = 5.0,
                 seed: int = 0) -> list[Path]:
    """Write a reference series and ``n_states`` loaded series of uint16 TIFF frames.

    Folders ``root/ref``, ``root/state1``... each of ``frames`` single-page TIFFs:
    a 12-bit grid (pitch ``pitch`` px, mean 2048 grey levels, peaks below 3000, no
    saturation) displaced by :func:`state_displacement`, each frame with its own
    Poisson-Gaussian noise (:func:`gridstrain.models.synthetic.add_noise`). Returns the
    folders, reference first.
    """
    from gridstrain.io import write_tiff_series

    root = Path(root)
    lattice = Lattice.from_pitch(pitch)
    rng = np.random.default_rng(seed)
    folders = []
    for step in range(n_states + 1):
        disp = state_displacement(step, shape[1]) if step else None
        clean = synthetic.grid_image(shape, lattice, amplitude=2048.0, displacement=disp)
        folder = root / ("ref" if step == 0 else f"state{step}")
        folder.mkdir(parents=True, exist_ok=True)
        noisy = (np.clip(synthetic.add_noise(clean, rng=rng), 0, 4095) for _ in range(frames))
        write_tiff_series(folder, noisy, dtype=np.uint16, digits=max(4, len(str(frames))))
        folders.append(folder)
    return folders


def cli_command() -> list[str]:
    """The argv prefix that runs the ``gridstrain`` command line from this checkout."""
    for module in ("gridstrain.cli", "gridstrain"):
        out = subprocess.run([sys.executable, "-m", module, "--help"], env=child_env(),
                             capture_output=True, text=True)
        if out.returncode == 0:
            return [sys.executable, "-m", module]
    raise RuntimeError(f"cannot run the gridstrain command line: {out.stderr.strip()}")


def cli_options(cli: list[str], command: str = "measure") -> set[str]:
    """The long options that ``gridstrain COMMAND --help`` lists (``{"--method", ...}``)."""
    out = subprocess.run([*cli, command, "--help"], env=child_env(), capture_output=True,
                         text=True, check=True)
    return set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", out.stdout))


# Runs ``python -m MODULE ARGS...`` as ``python -m`` does, then writes the peak resident
# memory of this process (VmHWM: it belongs to the address space, which exec makes
# afresh; ru_maxrss would start from the parent's peak when the child is spawned by
# vfork) to the file named first.
_PEAK_WRAPPER = r"""
import atexit, resource, runpy, sys
out = sys.argv[1]
def _peak():
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
def _write():
    with open(out, "w") as f:
        f.write(str(_peak()))
atexit.register(_write)
assert sys.argv[2] == "-m", "the wrapper runs modules only"
sys.argv = [sys.argv[3], *sys.argv[4:]]
runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
"""


def run_child(cmd: list[str], env: dict | None = None, *, peak: bool = False,
              quiet: bool = True) -> dict:
    """Run ``cmd`` (``[python, ...]``) to completion; its CPU time, wall time and peak.

    Returns ``{"cpu": user + system s, "wall": s, "peak": bytes or None}``; the CPU
    time is that of the child and of the processes it waited for
    (``RUSAGE_CHILDREN``), imports and file reading and writing included. With
    ``peak`` (``cmd`` must be ``[python, "-m", module, ...]``) the child is run through
    a wrapper that records its peak resident memory (``VmHWM``). A failing child
    raises ``RuntimeError`` with the end of its error output.
    """
    env = child_env() if env is None else env
    peak_file = None
    if peak:
        if len(cmd) < 3 or cmd[1] != "-m":
            raise ValueError(f"peak memory needs a [python, '-m', module, ...] command, got {cmd}")
        fd, peak_file = tempfile.mkstemp(prefix="peak-", suffix=".txt")
        os.close(fd)
        cmd = [cmd[0], "-c", _PEAK_WRAPPER, peak_file, *cmd[1:]]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    try:
        out = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL if quiet else None,
                             stderr=subprocess.PIPE, text=True)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if out.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd[:6])}... exited with {out.returncode}: "
                               f"{out.stderr.strip()[-2000:]}")
        value = None
        if peak_file is not None:
            with open(peak_file, encoding="utf-8") as f:
                value = int(f.read().strip() or 0) or None
    finally:
        if peak_file is not None:
            os.unlink(peak_file)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"cpu": cpu, "wall": wall, "peak": value}


def load() -> str:
    """The load average now, one line."""
    if not hasattr(os, "getloadavg"):
        return "load average unknown"
    return "load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
