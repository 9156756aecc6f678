"""Peak memory of methods A and B on a long series of large frames read from disk.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_memory.py [--frames 1000] [--size 2048x2048]

It writes T uint16 TIFF files of ``size`` (a 12-bit grid with Poisson-Gaussian
noise; to keep the writing short the files cycle through 8 distinct noisy frames,
which changes nothing to the memory or to the work per frame), then runs, each in
a fresh Python process so that the peaks do not mix:

* method A: ``open_series(folder).mean()`` streamed in float64, then one
  :func:`gridstrain.wft` of the mean;
* method B: :func:`gridstrain.stacks.method_b` over the frames streamed from the
  files, on every usable core;

and prints, for each, the wall time, the peak resident memory of the process
(``VmHWM`` on Linux: everything, Python, numpy, scipy.fft's buffers, the library
itself) and that peak less the peak after the imports and the opening of the
series, in MB (1e6 bytes) and MiB.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import machine
from bench_wft import parse_size
from gridstrain import Lattice
from gridstrain.io import write_tiff_series
from gridstrain.models import synthetic

CHILD = r"""
import json, resource, sys, time
import numpy as np
from gridstrain import Lattice, wft
from gridstrain.io import open_series
from gridstrain.stacks import method_b

def rss():
    # peak resident set of this process, bytes: VmHWM belongs to the address space,
    # which exec replaces (ru_maxrss would keep the parent's peak across exec)
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
folder, method, pitch = sys.argv[1], sys.argv[2], float(sys.argv[3])
lattice = Lattice.from_pitch(pitch)
series = open_series(folder)
base = rss()
t0 = time.perf_counter()
if method == "A":
    maps = wft(series.mean(), lattice)
else:
    maps = method_b(series.frames(), lattice).maps
wall = time.perf_counter() - t0
print(json.dumps({"wall": wall, "peak": rss(), "base": base,
                  "valid": float(maps.valid.mean())}))
"""


def write_frames(folder, shape, T, pitch):
    rng = np.random.default_rng(0)
    lattice = Lattice.from_pitch(pitch)
    clean = synthetic.grid_image(shape, lattice, amplitude=2048.0)
    distinct = [np.clip(synthetic.add_noise(clean, rng=rng), 0, 4095).astype(np.uint16)
                for _ in range(8)]
    write_tiff_series(folder, (distinct[i % 8] for i in range(T)), dtype=np.uint16,
                      digits=max(4, len(str(T))))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=1000, help="T, frames in the series")
    ap.add_argument("--size", type=parse_size, default=(2048, 2048), help="HxW")
    ap.add_argument("--pitch", type=float, default=5.0, help="grid pitch = sigma, px")
    ap.add_argument("--methods", nargs="+", default=["A", "B"], choices=["A", "B"])
    args = ap.parse_args(argv)
    H, W = args.size
    print(f"machine: {machine()}")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        write_frames(tmp, args.size, args.frames, args.pitch)
        on_disk = sum(p.stat().st_size for p in Path(tmp).iterdir())
        print(f"T = {args.frames} frames of {H}x{W} uint16, {on_disk / 1e9:.2f} GB on disk "
              f"(written in {time.perf_counter() - t0:.0f} s); pitch = sigma = "
              f"{args.pitch:g} px; {len(os.sched_getaffinity(0))} usable cores")
        print(f"{'method':>8} {'wall s':>8} {'peak RSS MB':>12} {'peak MiB':>9} "
              f"{'above imports MB':>17}")
        env = dict(os.environ)
        src = str(Path(__file__).resolve().parent.parent / "src")
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [src, env.get("PYTHONPATH")]))
        for method in args.methods:
            out = subprocess.run([sys.executable, "-c", CHILD, tmp, method, str(args.pitch)],
                                 capture_output=True, text=True, env=env, check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{method:>8} {r['wall']:>8.1f} {r['peak'] / 1e6:>12.0f} "
                  f"{r['peak'] / 2**20:>9.0f} {(r['peak'] - r['base']) / 1e6:>17.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
