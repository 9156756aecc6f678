"""Peak memory of ``gridstrain measure`` against the number of loaded states.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_states.py               # 50 frames of 2048x2048
    PYTHONPATH=src python benchmarks/bench_states.py --method A B  # both methods
    PYTHONPATH=src python benchmarks/bench_states.py --quick       # small, under a minute

It writes a reference series and as many loaded series as the largest of
``--states`` (default 1 and 3), ``--frames`` uint16 TIFF frames each
(``_common.write_states``: a 12-bit grid, pitch 5 px, its own noise in every frame,
each state translated by (0.3, -0.2) px and strained by 5e-4 more than the
previous one), in a temporary folder (``--tmp``; 50 frames of 2048x2048 are 0.42
GB a series, 1.7 GB for four series; removed at the end). Then, for each method
and each number of states n, it runs ``gridstrain measure REF STATE1 ... STATEn -o
out.h5 --quiet --overwrite --method M`` in a fresh interpreter and prints its
peak resident memory (``VmHWM`` of the child: Python, the libraries, every
thread's scratch arrays, the HDF5 writing), its CPU and wall times, and the ratio
of the peak with the most states to the peak with the fewest (target: within 10 %,
i.e. <= 1.10, and every peak <= 1.5 GB). The start-up peak (``gridstrain measure
--help``: interpreter and imports) is printed as a baseline. gridstrain's threads
are left as they are (method B transforms frames on every usable core, and its
memory grows with the threads).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from _common import child_env, cli_command, cli_options, load, machine, run_child, write_states
from bench_wft import parse_size

GB = 1e9
MIB = 2**20


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=50, help="frames per series (default 50)")
    ap.add_argument("--size", type=parse_size, default=(2048, 2048), help="HxW (default 2048x2048)")
    ap.add_argument("--states", type=int, nargs="+", default=[1, 3],
                    help="numbers of loaded states to compare (default 1 3)")
    ap.add_argument("--method", nargs="+", default=["A"], choices=["A", "B", "C"],
                    help="methods (default A)")
    ap.add_argument("--pitch", type=float, default=5.0, help="grid pitch, px (default 5)")
    ap.add_argument("--dtype", choices=("float64", "float32"), default=None,
                    help="passed as --dtype when the command line has that option")
    ap.add_argument("--quick", action="store_true",
                    help="8 frames of 512x640 per series, to check the script")
    ap.add_argument("--tmp", default=None, help="folder for the series (default: system temp)")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames, args.size = 8, (512, 640)
    states = sorted(set(args.states))
    if states[0] < 1:
        ap.error(f"--states must be at least 1, got {states}")
    T, (H, W) = args.frames, args.size

    cli = cli_command()
    extra = []
    if args.dtype is not None:
        if "--dtype" in cli_options(cli):
            extra = ["--dtype", args.dtype]
        else:
            print(f"note: this gridstrain's measure has no --dtype option; --dtype "
                  f"{args.dtype} ignored")
    env = child_env()
    n_series = states[-1] + 1
    need = n_series * T * H * W * 2
    tmp_parent = args.tmp or tempfile.gettempdir()
    free = shutil.disk_usage(tmp_parent).free
    print(f"machine: {machine()}")
    print(f"{T} frames of {H}x{W} uint16 TIFF per series, {n_series} series "
          f"({need / GB:.2f} GB in {tmp_parent}, {free / GB:.0f} GB free), pitch "
          f"{args.pitch:g} px, {len(os.sched_getaffinity(0))} usable cores")
    if need > 0.8 * free:
        print("not enough free disk space for the series: pass --tmp DIR or fewer --frames")
        return 1

    with tempfile.TemporaryDirectory(prefix="gridstrain-bench-states-", dir=args.tmp) as tmp:
        t0 = time.perf_counter()
        folders = [str(f) for f in write_states(tmp, args.size, T, states[-1],
                                                pitch=args.pitch)]
        print(f"(wrote {n_series * T} frames in {time.perf_counter() - t0:.0f} s)")
        out = str(Path(tmp) / "out.h5")
        base = run_child([*cli, "measure", "--help"], env, peak=True)
        print(f"start-up peak (gridstrain measure --help): {base['peak'] / MIB:.0f} MiB")
        print()
        print(f"{'method':>6} {'states':>6} {'peak MiB':>9} {'peak GB':>8} {'CPU s':>8} "
              f"{'wall s':>8}  load before")
        figures = {}
        for m in args.method:
            for n in states:
                before = load()
                r = run_child([*cli, "measure", *folders[:n + 1], "-o", out, "--quiet",
                               "--overwrite", "--method", m, *extra], env, peak=True)
                figures[(m, n)] = r
                print(f"{m:>6} {n:>6} {r['peak'] / MIB:>9.0f} {r['peak'] / GB:>8.2f} "
                      f"{r['cpu']:>8.1f} {r['wall']:>8.1f}  {before}", flush=True)
    print()
    lo, hi = states[0], states[-1]
    summary = {}
    for m in args.method:
        p_lo, p_hi = figures[(m, lo)]["peak"], figures[(m, hi)]["peak"]
        worst = max(figures[(m, n)]["peak"] for n in states)
        print(f"method {m}: peak with {hi} states / with {lo}: {p_hi / p_lo:.3f} "
              f"(target <= 1.10); largest peak {worst / GB:.2f} GB (target <= 1.5 GB)")
        summary[m] = {"peak_MiB": {n: round(figures[(m, n)]["peak"] / MIB) for n in states},
                      "ratio": round(p_hi / p_lo, 3)}
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
