"""The command line end to end on a folder of TIFFs, against the floors of its work.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_cli.py [--frames 100] [--size 1040x1376]
    PYTHONPATH=src python benchmarks/bench_cli.py --quick      # small, under a minute

It writes a reference series and one loaded series of T uint16 TIFF frames each
(``_common.write_states``: a 12-bit grid, pitch 5 px, its own noise in every
frame, the loaded state translated by (0.3, -0.2) px and strained by 5e-4), then
runs, each in a fresh interpreter,

* ``gridstrain measure REF STATE -o out.h5 --quiet --overwrite --method A`` and
  ``--method B`` (lattice detected, window sigma = pitch, every check of the
  pipeline: screening, vibrations, noise floor, uncertainty maps, HDF5 output);
* floor A: a fresh interpreter that imports numpy and tifffile, reads every frame
  of both series and adds it to a float64 accumulator (``bench_stack.read_and_sum``)
  -- plus two FFT floors, for the two transforms of method A (one mean image per
  series);
* floor B: the number of frames (2T) times the FFT floor of one frame;
* ``gridstrain --help`` against ``python -c "import numpy"`` (start-up);
* the same ``measure`` commands on the first half of each series (T / 2 frames, the
  same paths through the pipeline), and the read-and-sum floor on them: the
  difference, per frame, is what each further frame costs, printed against what it
  adds to the floor (reading and summing it for method A, its FFT floor for method
  B). Floor A holds none of a measurement's fixed costs (imports, lattice, noise
  floor, kinematics, uncertainty maps, the output file: those of a single pair,
  about 2 s at 1040x1376), so the ratio of whole runs to it mostly measures those.

With ``--against SRC`` (the ``src`` folder of another checkout, e.g. one made by
``git worktree add /tmp/before COMMIT``), the same ``measure`` commands also run on
that code, interleaved with ours on the same files, and their figures are printed
beside ours: a change measured before and after in one run, whatever the load.

The FFT floor is ``bench_wft.floor``: one ``rfft2`` and two complex ``ifft2`` of the
padded size ``gridstrain.wft`` uses, one thread, best CPU time of ``--fft-repeat``
calls in this process. Children are timed by their CPU time (user + system of the
process and its threads, ``RUSAGE_CHILDREN``), the figure to trust on a machine
shared with other work; wall times are printed beside them. BLAS and OpenMP pools
are asked for one thread in the children (their spinning is not work); gridstrain's
own threads (method B transforms frames on every usable core) are left as they are.
Targets: method A <= 2 x floor A, method B <= 1.5 x floor B, ``gridstrain --help``
<= 0.5 s above ``import numpy``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import child_env, cli_command, cli_options, load, machine, run_child, write_states
from bench_wft import floor, floor_inputs, parse_size

# a fresh interpreter reading and summing every frame of the folders given
READ_AND_SUM = r"""
import sys
from pathlib import Path
import numpy as np
import tifffile
acc = None
for folder in sys.argv[1:]:
    for p in sorted(Path(folder).glob("*.tif")):
        a = tifffile.imread(p)
        if acc is None:
            acc = np.zeros(a.shape, dtype=np.float64)
        np.add(acc, a, out=acc)
"""


def fft_floor_cpu(shape, sigma: float, dtype, repeat: int) -> float:
    """Best CPU time, s, of one FFT floor (rfft2 + two ifft2, one thread)."""
    real, cplx = floor_inputs(shape, sigma, dtype)
    floor(real, cplx)  # plans, first touch
    times = []
    for _ in range(repeat):
        c0 = time.process_time()
        floor(real, cplx)
        times.append(time.process_time() - c0)
    return min(times)


def profile(cli, measure_args, env, n: int, tmp: str, label: str) -> None:
    """Run ``measure`` under cProfile and print its ``n`` heaviest gridstrain functions."""
    import pstats

    stats_file = str(Path(tmp) / "measure.prof")
    module = cli[cli.index("-m") + 1]
    run_child([sys.executable, "-m", "cProfile", "-o", stats_file, "-m", module, "measure",
               *measure_args], env)
    stats = pstats.Stats(stats_file)
    rows = [(v[3], v[2], v[1], k) for k, v in stats.stats.items()
            if "gridstrain" in k[0] and "/cli/" not in k[0]]
    rows.sort(reverse=True)
    print()
    print(f"profile of measure {label} (main thread; total "
          f"{stats.total_tt:.2f} s):")
    print(f"{'cumulative s':>12} {'own s':>8} {'calls':>7}  function")
    for cum, own, calls, (path, line, func) in rows[:n]:
        where = path.split("gridstrain/", 1)[-1]
        print(f"{cum:>12.2f} {own:>8.2f} {calls:>7}  {func} ({where}:{line})")


def best(runs: list[dict]) -> dict:
    return {"cpu": min(r["cpu"] for r in runs), "wall": min(r["wall"] for r in runs)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=100, help="T, frames per series (default 100)")
    ap.add_argument("--size", type=parse_size, default=(1040, 1376), help="HxW (default 1040x1376)")
    ap.add_argument("--pitch", type=float, default=5.0, help="grid pitch, px (default 5)")
    ap.add_argument("--methods", nargs="+", default=["A", "B"], choices=["A", "B", "C"],
                    help="methods to run (default A B)")
    ap.add_argument("--dtype", choices=("float64", "float32"), default=None,
                    help="passed to measure as --dtype when it has that option (the "
                         "precision of the stored maps; the floors stay as they are)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="runs of each measurement, best kept (default 1)")
    ap.add_argument("--startup-repeat", type=int, default=5,
                    help="runs of the start-up candidates, best kept (default 5)")
    ap.add_argument("--fft-repeat", type=int, default=7, help="calls of the FFT floor")
    ap.add_argument("--quick", action="store_true",
                    help="10 frames of 256x320 per series, to check the script")
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="also run each method under cProfile and print its N gridstrain "
                         "functions of largest cumulative time (main thread only)")
    ap.add_argument("--tmp", default=None, help="folder for the series (default: system temp)")
    ap.add_argument("--against", default=None, metavar="SRC",
                    help="also run measure on the gridstrain package in the folder SRC (the "
                         "src folder of another checkout), interleaved with this one")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames, args.size, args.startup_repeat, args.fft_repeat = 10, (256, 320), 2, 3
    T, (H, W) = args.frames, args.size

    cli = cli_command()
    options = cli_options(cli)
    extra = []
    dtype = np.dtype("float64")  # the transforms of integer frames
    if args.dtype is not None:
        if "--dtype" in options:
            extra = ["--dtype", args.dtype]
        else:
            print(f"note: this gridstrain's measure has no --dtype option; --dtype "
                  f"{args.dtype} ignored")
    env = child_env(one_thread=True)
    variants = {"": env}
    if args.against is not None:
        src = Path(args.against).resolve()
        if not (src / "gridstrain" / "__init__.py").is_file():
            ap.error(f"--against must be a folder holding the gridstrain package, got {src}")
        variants[" (against)"] = dict(env, PYTHONPATH=str(src))
    print(f"machine: {machine()}")
    print(f"command line: {' '.join(Path(c).name if i == 0 else c for i, c in enumerate(cli))}")
    print(f"2 series (reference, one loaded state) x {T} frames of {H}x{W} uint16 TIFF, "
          f"pitch {args.pitch:g} px, floor in {dtype.name}"
          + (f", measure {' '.join(extra)}" if extra else ""))

    with tempfile.TemporaryDirectory(prefix="gridstrain-bench-cli-", dir=args.tmp) as tmp:
        t0 = time.perf_counter()
        ref, state = write_states(tmp, args.size, T, 1, pitch=args.pitch)
        print(f"(wrote {2 * T} frames in {time.perf_counter() - t0:.1f} s; they are read "
              "from the page cache)")
        out = str(Path(tmp) / "out.h5")
        # the first half of each series: the same run on T / 2 frames (the same
        # paths: temporal noise, vibrations regressed out), so that what a frame adds
        # can be told apart from the fixed costs (imports, lattice, kinematics, noise
        # floor, output)
        half = T // 2
        halves = []
        for folder in (ref, state):
            h = Path(tmp) / f"{Path(folder).name}_half"
            h.mkdir()
            for p in sorted(Path(folder).glob("*.tif"))[:half]:
                (h / p.name).symlink_to(p)
            halves.append(str(h))

        t_fft = fft_floor_cpu(args.size, args.pitch, dtype, args.fft_repeat)
        # method B transforms uint16 frames in float32 (gridstrain.conventions): the
        # float32 floor is printed beside the float64 one
        t_fft32 = fft_floor_cpu(args.size, args.pitch, np.float32, args.fft_repeat)
        print(f"before the runs: {load()}")
        read = best([run_child([sys.executable, "-c", READ_AND_SUM, str(ref), str(state)],
                               env) for _ in range(max(args.repeat, 2))])
        read_half = best([run_child([sys.executable, "-c", READ_AND_SUM, *halves], env)
                          for _ in range(max(args.repeat, 2))])
        runs = {}
        for _ in range(args.repeat):  # interleaved: a slowdown of the machine hits all
            for m in args.methods:
                for series, label in (((str(ref), str(state)), ""), (halves, " half")):
                    cmd = [*cli, "measure", *series, "-o", out, "--quiet",
                           "--overwrite", "--method", m, *extra]
                    for tag, e in variants.items():
                        runs.setdefault(m + tag + label, []).append(run_child(cmd, e))
        start = {"python -c 'import numpy'": [sys.executable, "-c", "import numpy"],
                 "gridstrain --help": [*cli, "--help"]}
        st = {name: [] for name in start}
        for _ in range(args.startup_repeat):
            for name, cmd in start.items():
                st[name].append(run_child(cmd, env))
        print(f"after the runs:  {load()}")
        if args.profile:
            for m in args.methods:
                profile(cli, [str(ref), str(state), "-o", out, "--quiet", "--overwrite",
                              "--method", m, *extra], env, args.profile, tmp,
                        f"--method {m}")

    floor_a = read["cpu"] + 2 * t_fft
    floor_b = 2 * T * t_fft
    targets = {"A": (floor_a, "floor A", 2.0), "B": (floor_b, "floor B", 1.5),
               "C": (floor_a, "floor A", None)}
    print()
    print(f"{'quantity':<58} {'CPU s':>8} {'wall s':>8} {'ratio':>7} {'target':>7}")
    print("-" * 92)
    print(f"{'FFT floor, one frame (rfft2 + 2 ifft2, 1 thread)':<58} {t_fft:>8.3f}")
    print(f"{f'read and sum {2 * T} frames (fresh interpreter)':<58} {read['cpu']:>8.2f} "
          f"{read['wall']:>8.2f}")
    print(f"{'floor A = read and sum + 2 FFT floors':<58} {floor_a:>8.2f}")
    print(f"{f'floor B = {2 * T} x FFT floor':<58} {floor_b:>8.2f}")
    print(f"{'FFT floor in float32, one frame':<58} {t_fft32:>8.3f}")
    print(f"{'read and sum, each further frame, ms':<58} "
          f"{1e3 * (read['cpu'] - read_half['cpu']) / (2 * (T - T // 2)):>8.2f}")
    figures = {"fft_floor": t_fft, "fft_floor_float32": t_fft32, "read_and_sum": read["cpu"],
               "floor_a": floor_a, "floor_b": floor_b}
    for m in args.methods:
        for tag in variants:
            r = best(runs[m + tag])
            ref_floor, name, target = targets[m]
            ratio = r["cpu"] / ref_floor
            tgt = f"<= {target:g}" if target else ""
            print(f"{f'gridstrain measure --method {m}{tag}  / {name}':<58} {r['cpu']:>8.2f} "
                  f"{r['wall']:>8.2f} {ratio:>7.2f} {tgt:>7}")
            key = f"method_{m}" + ("_against" if tag else "")
            figures[key] = r["cpu"]
            figures[f"{key}_ratio"] = ratio
            if m == "B":
                r32 = r["cpu"] / (2 * T * t_fft32)
                print(f"{f'   the same / {2 * T} x the float32 FFT floor':<58} {'':>8} "
                      f"{'':>8} {r32:>7.2f}")
                figures[f"{key}_ratio_float32_floor"] = r32
            # what a frame adds: the run less the half-series run, per further frame,
            # against what it adds to the floor (reading and summing it; method B
            # transforms it too)
            rh = best(runs[m + tag + " half"])
            per = (r["cpu"] - rh["cpu"]) / (2 * (T - half))
            read_per = (read["cpu"] - read_half["cpu"]) / (2 * (T - half))
            floor_per, fname = (t_fft, "an FFT floor") if m == "B" else (read_per,
                                                                         "read and sum")
            print(f"{f'   the same on {half} + {half} frames':<58} {rh['cpu']:>8.2f} "
                  f"{rh['wall']:>8.2f}")
            print(f"{f'   each further frame / {fname}, ms':<58} {1e3 * per:>8.2f} "
                  f"{'':>8} {per / floor_per:>7.2f}")
            figures[f"{key}_half"] = rh["cpu"]
            figures[f"{key}_per_frame"] = per
            figures[f"{key}_per_frame_ratio"] = per / floor_per
    sb = {name: best(v) for name, v in st.items()}
    for name, r in sb.items():
        print(f"{name:<58} {r['cpu']:>8.2f} {r['wall']:>8.2f}")
    names = list(sb)
    above = sb[names[1]]["cpu"] - sb[names[0]]["cpu"]
    print(f"{'start-up: gridstrain --help above import numpy (CPU)':<58} {above:>8.2f} "
          f"{sb[names[1]]['wall'] - sb[names[0]]['wall']:>8.2f} {'':>7} {'<= 0.5':>7}")
    figures["startup_above_numpy"] = above
    print(json.dumps({k: round(v, 4) for k, v in figures.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
