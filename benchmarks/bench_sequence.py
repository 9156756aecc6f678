"""CPU per one-frame state of a record measured with ``gridstrain measure --each-frame``,
against the FFT floor of one frame; peak memory for a short and a long record.

The record is one multi-page TIFF of 250 x 400 px frames (12-bit grid at pitch 5,
Poisson-Gaussian noise), frame ``t`` displaced by ``t / 20`` of
:func:`_common.state_displacement`'s step: a first frame taken as the reference
(``--reference-frames 1``) and every later frame a state. A state's CPU time is the
difference of two runs (``--short`` and ``--states`` states) over the difference of
their numbers of states, so that imports, the reference and the lattice cancel.
The floor is one frame's ``rfft2`` and two ``ifft2`` (one per wave vector), float64.

    python benchmarks/bench_sequence.py [--states 100] [--short 10] [--memory 1000]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.fft as sfft
import tifffile

from _common import cli_command, machine, run_child, state_displacement
from gridstrain import Lattice
from gridstrain.models import synthetic

SHAPE = (250, 400)


def write_record(path: Path, n: int, seed: int = 0) -> None:
    lattice = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(seed)
    step = state_displacement(1, SHAPE[1])
    with tifffile.TiffWriter(path) as tif:
        for t in range(n):
            disp = (lambda X, Y, t=t: tuple(v * t / 20 for v in step(X, Y))) if t else None
            clean = synthetic.grid_image(SHAPE, lattice, amplitude=2048.0, displacement=disp)
            frame = np.clip(synthetic.add_noise(clean, rng=rng), 0, 4095).astype(np.uint16)
            tif.write(frame, photometric="minisblack", contiguous=False)


def fft_floor(repeat: int = 50) -> float:
    img = np.random.default_rng(0).normal(size=SHAPE)
    best = np.inf
    for _ in range(repeat):
        c0 = time.process_time()
        f = sfft.fft2(img)
        sfft.ifft2(f)
        sfft.ifft2(f)
        best = min(best, time.process_time() - c0)
    return best


def run(cli, record: Path, out: Path, *, peak: bool = False) -> dict:
    return run_child([*cli, "measure", str(record), "--reference-frames", "1", "-o",
                      str(out), "--quiet", "--overwrite"], peak=peak)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=100)
    ap.add_argument("--short", type=int, default=10)
    ap.add_argument("--memory", type=int, default=0,
                    help="also the peak memory of a record of this many states against "
                    "--states (e.g. 1000)")
    args = ap.parse_args()
    print(machine())
    cli = cli_command()
    floor = fft_floor()
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        runs = {}
        write_record(d / "warm.tif", 3)
        run(cli, d / "warm.tif", d / "warm.h5")  # numba's first compilation, caches
        for n in sorted({args.short, args.states, args.memory} - {0}):
            write_record(d / f"rec{n}.tif", n + 1)
            runs[n] = run(cli, d / f"rec{n}.tif", d / f"out{n}.h5", peak=True)
            print(f"{n:5d} states: CPU {runs[n]['cpu']:.2f} s, wall {runs[n]['wall']:.2f} s, "
                  f"peak {runs[n]['peak'] / 2**20:.0f} MiB")
    per = (runs[args.states]["cpu"] - runs[args.short]["cpu"]) / (args.states - args.short)
    print(f"CPU per one-frame state of {SHAPE[0]} x {SHAPE[1]} px: {per * 1e3:.1f} ms; "
          f"FFT floor of a frame {floor * 1e3:.2f} ms; ratio {per / floor:.0f} "
          "(target 0.10 s, goal 0.03 s)")
    if args.memory:
        a, b = runs[args.states]["peak"], runs[args.memory]["peak"]
        print(f"peak memory {args.memory} states / {args.states} states: {b / a:.3f} "
              "(target within 10 %)")


if __name__ == "__main__":
    main()
