"""Methods A and B on a series of T frames read from TIFF files.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_stack.py [--frames 100] [--size 1040x1376]

It writes T noisy 12-bit frames of a grid shaken by sub-pixel vibrations (the
paper's setting, section 3.2) as single-page TIFFs in a temporary folder, then
prints:

* method A -- ``open_series(folder).mean()`` and one :func:`gridstrain.wft` of the
  mean on every usable core, as :func:`gridstrain.stacks.method_a` does -- against
  the read-and-sum floor (tifffile reads each file and adds it to a
  float64 accumulator, nothing else);
* method B -- :func:`gridstrain.stacks.method_b` over the frames streamed from
  the files, with 1 and with all usable threads, averaging phases (the paper) or
  phasors -- against ``T x`` the per-frame FFT floor (one rfft2 and two complex
  ifft2 of the padded size) plus the read-and-sum floor;
* the peak of memory allocated through numpy by method B (tracemalloc), which must
  not grow with T.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import tifffile

from _common import issue_phases, machine
from bench_wft import floor, floor_inputs, parse_size
from gridstrain import Lattice, wft
from gridstrain.io import open_series, write_tiff_series
from gridstrain.models import synthetic
from gridstrain.stacks import method_b


def make_frames(shape, T, *, pitch=5.0, vibration=0.05, seed=0):
    """T noisy 12-bit frames of a grid translated by N(0, vibration^2) px each."""
    rng = np.random.default_rng(seed)
    lattice = Lattice.from_pitch(pitch)
    base = issue_phases(shape)
    for _ in range(T):
        ux, uy = rng.normal(0.0, vibration, size=2)

        # a rigid translation u of an axis-aligned grid shifts its phases by
        # -2 pi k.u (eq. 34); the slow phase fields barely move over 0.05 px
        def phases(X, Y, ux=ux, uy=uy):
            p1, p2 = base(X, Y)
            return (p1 - 2 * np.pi * (lattice.k1[0] * ux + lattice.k1[1] * uy),
                    p2 - 2 * np.pi * (lattice.k2[0] * ux + lattice.k2[1] * uy))

        clean = synthetic.grid_image(shape, lattice, amplitude=2048.0, phases=phases)
        yield np.clip(synthetic.add_noise(clean, rng=rng), 0, 4095)


def read_and_sum(paths) -> np.ndarray:
    acc = None
    for p in paths:
        a = tifffile.imread(p)
        if acc is None:
            acc = np.zeros(a.shape, dtype=np.float64)
        np.add(acc, a, out=acc)
    return acc


def best(func, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        func()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=100, help="T, frames in the series")
    ap.add_argument("--size", type=parse_size, default=(1040, 1376), help="HxW")
    ap.add_argument("--pitch", type=float, default=5.0, help="grid pitch = sigma, px")
    ap.add_argument("--dtype", choices=("float64", "float32"), default="float64",
                    help="precision of the transforms")
    ap.add_argument("--repeat", type=int, default=2, help="timed runs of method A and floors")
    ap.add_argument("--memory-frames", type=int, default=10,
                    help="frames of the run that measures method B's peak memory")
    args = ap.parse_args(argv)
    dtype = np.dtype(args.dtype)
    T = args.frames
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"machine: {machine()}")
    print(f"T = {T} frames of {args.size[0]}x{args.size[1]}, 12-bit in uint16 TIFFs, pitch "
          f"{args.pitch:g} px = sigma, transforms in {dtype.name}")

    with tempfile.TemporaryDirectory() as tmp:
        lattice = Lattice.from_pitch(args.pitch)
        t0 = time.perf_counter()
        write_tiff_series(tmp, make_frames(args.size, T, pitch=args.pitch), dtype=np.uint16,
                          digits=max(4, len(str(T))))
        print(f"(wrote the frames in {time.perf_counter() - t0:.1f} s)")
        paths = sorted(Path(tmp).glob("*.tif"))
        series = open_series(tmp)

        # the floors
        t_read = best(lambda: read_and_sum(paths), args.repeat)
        real, cplx = floor_inputs(args.size, args.pitch, dtype)
        floor(real, cplx)
        t_fft = best(lambda: floor(real, cplx), 5)

        # method A
        t_mean = best(lambda: series.mean(dtype=dtype), args.repeat)
        mean = series.mean(dtype=dtype)
        t_wft = best(lambda: wft(mean, lattice, workers=cores), 3)
        t_a = t_mean + t_wft

        # method B
        t_b = {}
        for w in sorted({1, cores}):
            c0, t0 = time.process_time(), time.perf_counter()
            res_b = method_b(series.frames(dtype=dtype), lattice, workers=w).maps
            t_b[w] = (time.perf_counter() - t0, time.process_time() - c0)
        n_mem = min(args.memory_frames, T)
        tracemalloc.start()
        method_b(series.frames(dtype=dtype, stop=n_mem), lattice, workers=cores)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()

    res_a = wft(mean, lattice)
    H, W = args.size
    frame_mib = H * W * dtype.itemsize / 2**20
    print()
    print(f"{'quantity  / reference of the ratio':<66} {'time s':>8} {'ratio':>8}")
    print("-" * 84)
    rows = [
        ("read-and-sum floor (tifffile + float64 add), T frames", t_read, None),
        ("per-frame FFT floor (rfft2 + 2 ifft2), one frame", t_fft, None),
        ("method A: open_series().mean()  / read-and-sum floor", t_mean, t_mean / t_read),
        (f"method A: wft of the mean ({cores} threads)  / per-frame FFT floor", t_wft,
         t_wft / t_fft),
        ("method A total  / read-and-sum floor", t_a, t_a / t_read),
    ]
    floor_b = T * t_fft + t_read
    for w, (wall, cpu) in t_b.items():
        rows.append((f"method B, {w} thread(s)  / (T x FFT floor + read)", wall,
                     wall / floor_b))
        rows.append(("   same, CPU time of all threads  / (T x FFT floor + read)", cpu,
                     cpu / floor_b))
    rows.append(("method B (1 thread)  / method A", t_b[1][0], t_b[1][0] / t_a))
    for name, t, r in rows:
        print(f"{name:<66} {t:>8.3f} {'' if r is None else f'{r:8.2f}':>8}")
    if cores > 1:
        print(f"thread speed-up of method B on {cores} cores: "
              f"{t_b[1][0] / t_b[cores][0]:.2f}x")
    print(f"method B peak memory ({n_mem} frames, {cores} threads): {peak:.0f} MiB "
          f"(one {dtype.name} frame is {frame_mib:.1f} MiB, its PhaseMaps "
          f"{frame_mib * 8:.0f} MiB)")
    v = res_a.valid & res_b.valid
    diff = np.max(np.abs(res_a.dphi - res_b.dphi)[:, :, v])
    print(f"method A vs B, max |d phi| difference on valid pixels: {diff:.2e} rad/px "
          f"(noise and vibrations: the paper's eqs. 27 and the section 2.3 equation)")
    return 0


if __name__ == "__main__":
    main()
