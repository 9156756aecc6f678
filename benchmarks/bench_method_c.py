"""Method C (vibration-compensated averaging) against methods A and B.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_method_c.py [--frames 100] [--size 1040x1376]

It makes T noisy 12-bit frames (uint16, in memory) of a grid shaken by sub-pixel
vibrations (``bench_stack.make_frames``), then runs :func:`gridstrain.stacks.method_a`,
:func:`~gridstrain.stacks.method_b` (one thread) and :func:`~gridstrain.stacks.method_c`
(shifts measured in the same pass) on them, in turn, and prints for each the
wall-clock time and the CPU time of the process (``time.process_time``: every
thread of the process, BLAS and FFT included), with the ratios C/A and C/B. On
a machine shared with other work the wall-clock times swing with the load; the
CPU times are the figures to compare. BLAS runs on one thread (set before numpy is
imported; ``--blas-threads`` to change): its threads busy-wait for each other, and
on a loaded machine that spinning alone multiplies the CPU time of method C's
narrow matrix products by 3 to 8 (measured: 1 ms on one thread, 2.5 to 8 ms on two,
for the (1040 x 1376) @ (1376 x 10) product of its shift probe).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

if __name__ == "__main__":  # before numpy loads OpenBLAS
    _n = sys.argv[sys.argv.index("--blas-threads") + 1] if "--blas-threads" in sys.argv else "1"
    os.environ.setdefault("OPENBLAS_NUM_THREADS", _n)

import numpy as np

from _common import machine
from bench_stack import make_frames
from bench_wft import parse_size
from gridstrain import Lattice
from gridstrain.stacks import method_a, method_b, method_c


def timed(func):
    c0, t0 = time.process_time(), time.perf_counter()
    out = func()
    return out, time.perf_counter() - t0, time.process_time() - c0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=100, help="T, frames in the stack")
    ap.add_argument("--size", type=parse_size, default=(1040, 1376), help="HxW")
    ap.add_argument("--pitch", type=float, default=5.0, help="grid pitch = sigma, px")
    ap.add_argument("--vibration", type=float, default=0.2, help="std of the shifts, px")
    ap.add_argument("--repeat", type=int, default=2, help="timed runs of methods A and C")
    ap.add_argument("--skip-b", action="store_true", help="do not run method B")
    ap.add_argument("--blas-threads", default="1", help="OpenBLAS threads (default 1)")
    args = ap.parse_args(argv)
    T = args.frames
    H, W = args.size
    print(f"machine: {machine()}")
    print(f"T = {T} frames of {H}x{W} (uint16 in memory), pitch {args.pitch:g} px = sigma, "
          f"vibrations {args.vibration:g} px std, OpenBLAS threads "
          f"{os.environ.get('OPENBLAS_NUM_THREADS')}")
    lattice = Lattice.from_pitch(args.pitch)
    t0 = time.perf_counter()
    frames = [f.astype(np.uint16) for f in make_frames((H, W), T, pitch=args.pitch,
                                                       vibration=args.vibration)]
    print(f"(made the frames in {time.perf_counter() - t0:.1f} s)")

    best: dict = {}
    for _ in range(args.repeat):  # interleaved: a change of load hits both
        for name, fn in (("A", method_a), ("C", method_c)):
            res, wall, cpu = timed(lambda fn=fn: fn(frames, lattice))
            old = best.get(name)
            best[name] = (res, min(wall, old[1]) if old else wall,
                          min(cpu, old[2]) if old else cpu)
    if not args.skip_b:
        best["B"] = timed(lambda: method_b(frames, lattice, workers=1))

    print()
    print(f"{'method':<58} {'wall s':>8} {'CPU s':>8}")
    print("-" * 76)
    labels = {"A": "A: mean, one wft (all cores)",
              "B": "B: one wft per frame (1 thread)",
              "C": "C: shifts + compensated sums, one wft_complex"}
    for name in ("A", "B", "C"):
        if name in best:
            _, wall, cpu = best[name]
            print(f"{labels[name]:<58} {wall:>8.2f} {cpu:>8.2f}")
    a, c = best["A"], best["C"]
    print(f"C / A: wall {c[1] / a[1]:.2f}, CPU {c[2] / a[2]:.2f}  (target <= 3)")
    if "B" in best:
        b = best["B"]
        print(f"C / B: wall {c[1] / b[1]:.3f}, CPU {c[2] / b[2]:.3f}  (target <= 0.1)")
    rc = c[0]
    print(f"method C: motion residual {rc.motion_residual:.2g} px, warnings {len(rc.warnings)}")
    v = a[0].maps.valid & rc.maps.valid
    mod = np.median(np.abs(rc.maps.psi[:, v]) / np.abs(a[0].maps.psi[:, v]), axis=1)
    print(f"modulus C / A (median): {mod[0]:.4f}, {mod[1]:.4f} (eq. 14's contrast loss "
          f"undone: 1 / (1 - (2 pi f s)^2 / 2) = "
          f"{1 / (1 - 0.5 * (2 * np.pi * args.vibration / args.pitch) ** 2):.4f})")
    return 0


if __name__ == "__main__":
    main()
