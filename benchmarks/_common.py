"""Shared helpers of the benchmark scripts: machine description, timing, test images."""

from __future__ import annotations

import math
import os
import platform
import time

import numpy as np
import scipy

from gridstrain import Lattice, synthetic


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
