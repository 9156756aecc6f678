"""The systematic-error bounds of one reference at real size: the aliasing bound
(:func:`gridstrain.uncertainty.aliasing_bias`) and the smoothing bound
(:func:`gridstrain.uncertainty.smoothing_bias`), against another checkout's.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_bounds.py [--baseline OTHER/src] [--repeat 3]

A 1040 x 1376 checkerboard (pitch 6 px at 12 degrees, square profile, a reflectance
defect, Poisson-Gaussian noise), its aliasing bound without a mask and with a
100 x 100 px hole in the measured crop (the window then no product of two
profiles), and the smoothing bound of three strain maps carrying a feature at the
valid region's edge, over a valid rectangle and with a round hole. Each candidate runs
in a fresh interpreter with BLAS on one thread (as in a measurement), the CPU time of
each call taken as the best of ``--repeat``; the ratio is the baseline's over ours.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from _common import machine

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
import numpy as np
from gridstrain import Lattice
from gridstrain.models import synthetic
from gridstrain.uncertainty import aliasing_bias, smoothing_bias

H, W = 1040, 1376
repeat = int(sys.argv[1])
lat = Lattice.from_pitch(6.0, angle=12.0)


def R(X, Y):
    return 1 + 0.1 * np.exp(-((X - 0.25 * W) ** 2 + (Y - 0.4 * H) ** 2) / (2 * 60**2))


img = synthetic.grid_image((H, W), lat, kind="checkerboard", profile="square",
                           reflectance=R, oversample=3, amplitude=2000.0)
img = synthetic.add_noise(img, rng=np.random.default_rng(1))
hole = np.ones((H, W), bool)
hole[400:500, 600:700] = False
y, x = np.mgrid[0:H, 0:W]
rng = np.random.default_rng(0)
e = np.stack([1e-3 * np.exp(-((x - 100 - 50 * k) ** 2 + (y - 40) ** 2) / (2 * 15**2))
              + 1e-5 * rng.standard_normal((H, W)) for k in range(3)])
rect = np.zeros((H, W), bool)
rect[20:-20, 20:-20] = True
round_hole = rect & ((x - 600) ** 2 + (y - 500) ** 2 >= 80**2)
cases = {
    "aliasing, no mask": lambda: aliasing_bias(img, lat, sigma=6.0),
    "aliasing, a hole in the crop": lambda: aliasing_bias(img, lat, sigma=6.0, mask=hole),
    "smoothing, valid rectangle": lambda: smoothing_bias(e, rect, sigma=6.0),
    "smoothing, a round hole": lambda: smoothing_bias(e, round_hole, sigma=6.0),
}
out = {}
for name, f in cases.items():
    f()  # caches and first-call costs aside
    best = float("inf")
    for _ in range(repeat):
        t = time.process_time()
        f()
        best = min(best, time.process_time() - t)
    out[name] = best
print(json.dumps(out))
"""


def run(src: str, repeat: int) -> dict:
    env = dict(os.environ, PYTHONPATH=src, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               MKL_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", CHILD, str(repeat)], env=env, check=True,
                          capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="calls of each case (best taken)")
    ap.add_argument("--baseline", metavar="SRC", help="another checkout's src/ to compare")
    args = ap.parse_args(argv)
    print(f"machine: {machine()}")
    ours = run(str(ROOT / "src"), args.repeat)
    base = run(args.baseline, args.repeat) if args.baseline else None
    print(f"{'case':<32} {'ours s':>8}" + (f" {'baseline s':>11} {'ratio':>6}" if base else ""))
    for name, t in ours.items():
        line = f"{name:<32} {t:>8.3f}"
        if base:
            line += f" {base[name]:>11.3f} {base[name] / t:>6.2f}"
        print(line)


if __name__ == "__main__":
    main()
