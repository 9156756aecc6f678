"""CPU time and size of the HTML report of a long sequence of states.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_report.py                         # 200 states
    PYTHONPATH=src python benchmarks/bench_report.py --baseline OTHER/src    # and another
    PYTHONPATH=src python benchmarks/bench_report.py --states 20 --size 64x80

It measures a reference and ``--states`` loaded states of ``--frames`` frames of
``--size`` px (a grid of pitch 5 px, each state strained by 2e-5 more than the
previous one, its own noise in every frame) with :func:`gridstrain.measure_series`
and saves the result file, then runs ``gridstrain report RESULT -o REPORT.html`` in a
fresh interpreter (imports included) for this checkout and, with ``--baseline``, for
another checkout's ``src`` on the same file. It prints each one's CPU time (the
child's user + system), wall time, the size of the page and the height of its tallest
embedded image, then the ratios (targets for 200 states of 64x80 px: <= 15 s CPU,
<= 5 MB, no image taller than 4000 px).
"""

from __future__ import annotations

import argparse
import base64
import os
import re
import struct
import sys
import tempfile
from pathlib import Path

import numpy as np

from _common import child_env, machine, run_child
from bench_wft import parse_size
from gridstrain import Lattice, measure_series
from gridstrain.models import synthetic

MB = 1e6


def write_result(path: Path, n_states: int, shape, frames: int) -> Path:
    """A result file of ``n_states`` small states (see the module docstring)."""
    lattice = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(0)
    cx = (shape[1] - 1) / 2

    def series(strain):
        clean = synthetic.grid_image(shape, lattice, amplitude=1500.0,
                                     displacement=lambda X, Y: (strain * (X - cx), 0.0 * Y))
        return np.array([synthetic.add_noise(clean + 200.0, rng=rng) for _ in range(frames)])

    states = [series(2e-5 * (k + 1)) for k in range(n_states)]
    result = measure_series(series(0.0), states, lattice=lattice, order="independent",
                            guess=(0.0, 0.0))
    return result.save(path, pixel_size=0.02, unit="mm")


def tallest_image(html: str) -> int:
    """Height, px, of the tallest PNG embedded in the page (read from its header)."""
    tallest = 0
    for data in re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", html):
        head = base64.b64decode(data[:32])
        tallest = max(tallest, struct.unpack(">I", head[20:24])[0])
    return tallest


def report(src: Path, result: Path, out: Path) -> dict:
    env = child_env()
    env["PYTHONPATH"] = os.pathsep.join([str(src), env["PYTHONPATH"]])
    times = run_child([sys.executable, "-m", "gridstrain.cli", "report", str(result), "-o",
                       str(out)], env)
    html = out.read_text(encoding="utf-8")
    return dict(times, size=out.stat().st_size, tallest=tallest_image(html))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--states", type=int, default=200, help="loaded states (default 200)")
    ap.add_argument("--size", type=parse_size, default=(64, 80), help="HxW (default 64x80)")
    ap.add_argument("--frames", type=int, default=2, help="frames per series (default 2)")
    ap.add_argument("--baseline", type=Path, help="another checkout's src/ to compare")
    args = ap.parse_args(argv)
    print(machine())
    here = Path(__file__).resolve().parents[1] / "src"
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        result = write_result(tmp / "r.h5", args.states, args.size, args.frames)
        H, W = args.size
        print(f"{args.states} states of {H}x{W} px, {args.frames} frames a series; result "
              f"file {result.stat().st_size / MB:.1f} MB")
        runs = {"gridstrain": report(here, result, tmp / "ours.html")}
        if args.baseline:
            runs["baseline"] = report(args.baseline.resolve(), result, tmp / "base.html")
        for name, r in runs.items():
            print(f"{name:>10}: CPU {r['cpu']:6.1f} s, wall {r['wall']:6.1f} s, page "
                  f"{r['size'] / MB:6.2f} MB, tallest image {r['tallest']} px")
        if args.baseline:
            ours, base = runs["gridstrain"], runs["baseline"]
            print(f"     ratio: CPU {base['cpu'] / ours['cpu']:.1f}x less, page "
                  f"{base['size'] / ours['size']:.1f}x smaller")


if __name__ == "__main__":
    main()
