"""Bytes of a result file over the bytes of the record's own frames, with the default
storage (float32 maps rounded to a tenth of their std, compressed) and the lossless one
(the maps as measured, as gridstrain wrote them before).

The record is a coupon under a growing uniaxial strain with a rigid drift, one frame per
state, drawn by :mod:`gridstrain.models.synthetic` through a 12-bit Poisson-Gaussian
camera; its frames take 2 bytes a pixel (12-bit levels stored as uint16). Every state is
measured with ``measure_series``'s defaults, and the result written by ``save_result``
with its defaults and with ``lossless=True`` (a file written state by state,
``output=ResultFile(...)`` as ``gridstrain measure`` does, holds the same bytes:
``tests/test_compact_results.py``); the CPU of the write is printed per state. The frame
bytes counted are the states' (``n_states x H x W x 2``), the reference frame's left out.

    PYTHONPATH=src python benchmarks/bench_result_size.py [--states 20] [--size 250x400]
        [--repeat 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from _common import machine
from gridstrain import Lattice
from gridstrain.models import synthetic
from gridstrain.results import save_result
from gridstrain.series import measure_series


def record(n_states: int, shape, *, seed: int = 0):
    """The reference frame and ``n_states`` deformed frames, (1, H, W) uint16 each:
    strain up to 2e-3 along x, Poisson 0.3, a drift of 0.03 px a state."""
    lattice = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(seed)
    H, W = shape

    def frame(k):
        e = 2e-3 * k / max(n_states, 1)

        def disp(X, Y):
            return 0.03 * k + e * (X - W / 2), -0.3 * e * (Y - H / 2)

        clean = synthetic.grid_image(shape, lattice, amplitude=1500.0,
                                     displacement=disp if k else None)
        noisy = synthetic.add_noise(clean, rng=rng)
        return np.clip(np.round(noisy), 0, 4095).astype(np.uint16)[None]

    return frame(0), [frame(k + 1) for k in range(n_states)]


def per_variable(path, shape) -> dict[str, int]:
    """Bytes each per-state map, ``(state, H, W)``, takes in the file."""
    with h5py.File(path, "r") as h5:
        return {k: ds.id.get_storage_size() for k, ds in h5.items()
                if isinstance(ds, h5py.Dataset) and ds.ndim == 3 and ds.shape[1:] == shape}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--states", type=int, default=20)
    ap.add_argument("--size", default="250x400", help="H x W of a frame, px")
    ap.add_argument("--repeat", type=int, default=3, help="writes of each file (best CPU)")
    args = ap.parse_args()
    shape = tuple(int(v) for v in args.size.lower().split("x"))
    ref, states = record(args.states, shape)
    frame_bytes = sum(s.nbytes for s in states)
    print(machine())
    print(f"record: {args.states} one-frame states of {shape[0]} x {shape[1]} px, 12-bit "
          f"frames as uint16: {frame_bytes / 1e6:.2f} MB")
    held = measure_series(ref, states)  # the defaults; maps in memory, float64
    with tempfile.TemporaryDirectory() as d:
        sizes = {}
        for name, lossless in (("lossless (as before)", True), ("default (rounded)", False)):
            path = Path(d) / f"{lossless}.h5"
            cpu = []
            for _ in range(args.repeat):
                t0 = time.process_time()
                save_result(held, path, lossless=lossless, overwrite=True)
                cpu.append(time.process_time() - t0)
            sizes[name] = path.stat().st_size
            print(f"{name:22s} {sizes[name] / 1e6:8.2f} MB  {sizes[name] / frame_bytes:6.2f}x "
                  f"the frames; written in {1e3 * min(cpu) / args.states:.1f} ms CPU a state")
            if not lossless:
                with h5py.File(path, "r") as h5:
                    worst = max(float(np.nanmax(h5[k].attrs["rounding_max_error_over_std"]))
                                for k in h5 if "rounding_max_error_over_std" in h5[k].attrs)
                print(f"  largest rounding error over the std, any map, state, pixel: "
                      f"{worst:.3f}")
                for k, b in sorted(per_variable(path, shape).items(), key=lambda kv: -kv[1]):
                    print(f"  {k:10s} {b / frame_bytes:6.3f}x the frames")
        a, b = sizes.values()
        print(f"lossless / default: {a / b:.1f}x")

if __name__ == "__main__":
    main()
