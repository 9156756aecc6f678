"""The memory model of the budget check against the measured peaks of ``gridstrain measure``.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_budget.py                 # 512, 1024, 1536 px
    PYTHONPATH=src python benchmarks/bench_budget.py --sizes 2048 --frames 10

For each frame size and method it writes a reference and loaded series
(``_common.write_states``, ``--frames`` uint16 TIFFs each), runs ``gridstrain measure
REF STATE -o out.h5 --quiet --method M`` in a fresh interpreter and prints the peak
resident memory of the child (``VmHWM``) beside the estimate of
:func:`gridstrain._runtime.memory.measurement_bytes` plus the sums of the variance's harmonic
terms that ``--frames`` allows (:func:`gridstrain.stacks.accumulate.motion_sums_bytes`)
and the contrast-step bound's temporaries (:func:`gridstrain.uncertainty.contrast_step_bytes`),
as the budget check adds them, and their ratio (the estimate must lie
above the peak: the ratio is the margin of the refusal). With ``--held`` it adds runs
with ``--phase-maps`` and two states, whose maps are all held to the end.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from _common import cli_command, machine, run_child, write_states
from gridstrain._runtime.memory import measurement_bytes
from gridstrain.stacks.accumulate import motion_sums_bytes
from gridstrain.uncertainty import contrast_step_bytes

MiB = 2**20


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[512, 1024, 1536])
    ap.add_argument("--frames", type=int, default=4, help="frames per series")
    ap.add_argument("--methods", nargs="+", default=["A", "B", "C"])
    ap.add_argument("--held", action="store_true", help="also --phase-maps, two states")
    args = ap.parse_args(argv)
    cli = cli_command()
    print(f"machine: {machine()}")
    print(f"{'size':>6} {'method':>6} {'states':>6} {'held':>5} {'peak MiB':>9} "
          f"{'model MiB':>10} {'model/peak':>10}")
    for n in args.sizes:
        with tempfile.TemporaryDirectory() as tmp:
            folders = write_states(tmp, (n, n), args.frames, 2 if args.held else 1)
            runs = [(m, 1, False) for m in args.methods]
            if args.held:
                runs += [(m, 2, True) for m in args.methods]
            for method, states, held in runs:
                out = Path(tmp) / "out.h5"
                cmd = [*cli, "measure", str(folders[0]), *map(str, folders[1:1 + states]),
                       "-o", str(out), "--quiet", "--overwrite", "--method", method,
                       "--pitch", "5", "--memory-budget", "1T"]
                if held:
                    cmd.append("--phase-maps")
                peak = run_child(cmd, peak=True)["peak"]
                model = motion_sums_bytes((n, n), args.frames) + measurement_bytes(
                    (n, n), method=method, n_states=states, held_states=held) + \
                    contrast_step_bytes((n, n))
                print(f"{n:>6} {method:>6} {states:>6} {held!s:>5} {peak / MiB:>9.0f} "
                      f"{model / MiB:>10.0f} {model / peak:>10.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
