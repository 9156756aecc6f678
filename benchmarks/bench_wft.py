"""Per-frame cost of gridstrain.wft against the FFT floor and a naive reference.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_wft.py [--sizes 1040x1376 2048x2048] [--repeat 7]

For each image size and precision it prints the per-frame wall time of

* ``ours``: :func:`gridstrain.wft`, both phases and the four exact phase derivatives;
* ``floor``: one ``rfft2`` and two complex ``ifft2`` of the same padded size with the
  same library (scipy.fft) -- the least any FFT implementation of the window needs
  for two phase maps, derivatives not included;
* ``naive``: the way the MATLAB toolbox does it, in float64 -- zero-padded linear
  convolution with the window truncated at 4 sigma through full complex FFTs,
  phases by ``np.angle``, derivatives by ``np.gradient`` of the unwrapped phases;

their ratios (measured in one run, interleaved), and the peak of memory allocated
through numpy during one call (tracemalloc). The last lines compare the naive
derivatives with ours: they differ by the truncation and the finite differences.
"""

from __future__ import annotations

import argparse
import math
import tracemalloc
from functools import partial

import numpy as np
from scipy import fft as sfft

from _common import grid_test_image, interleaved, machine
from gridstrain import wft
from gridstrain.wft import _PAD_SIGMAS


def naive_wft(img, lattice, sigma):
    """Phases and derivatives as the MATLAB toolbox computes them, in numpy float64.

    Returns ``psi (2, H, W)`` and ``dphi (2, 2, H, W)``.
    """
    img = np.asarray(img, dtype=np.float64)
    H, W = img.shape
    v = img - img.mean()
    half = math.ceil(4 * sigma)  # window truncated at 4 sigma
    d = np.arange(-half, half + 1, dtype=float)
    g = np.exp(-(d**2) / (2 * sigma**2))
    window = np.outer(g, g)
    window /= window.sum()
    shape = (H + 2 * half, W + 2 * half)  # full linear convolution, no wrap-around
    spectrum = np.fft.fft2(v, s=shape)
    y = np.arange(H, dtype=float)[:, None]
    x = np.arange(W, dtype=float)[None, :]
    psi = np.empty((2, H, W), dtype=complex)
    dphi = np.empty((2, 2, H, W))
    for j, k in enumerate((lattice.k1, lattice.k2)):
        # Psi(x) = sum v(xi) g(xi - x) exp(-2 i pi k xi): convolution with the
        # flipped Gabor kernel g(d) exp(+2 i pi k d), then the carrier at x
        kernel = window * np.exp(2j * np.pi * (k[0] * d[None, :] + k[1] * d[:, None]))
        conv = np.fft.ifft2(spectrum * np.fft.fft2(kernel, s=shape))
        psi[j] = conv[half:half + H, half:half + W] * np.exp(-2j * np.pi * (k[0] * x + k[1] * y))
        phase = np.angle(psi[j])
        dphi[j, 0] = np.gradient(np.unwrap(phase, axis=1), axis=1)
        dphi[j, 1] = np.gradient(np.unwrap(phase, axis=0), axis=0)
    return psi, dphi


def floor_inputs(shape, sigma, dtype):
    """Arrays of the padded size that wft uses, for one rfft2 and two ifft2."""
    H, W = shape
    pad = math.ceil(_PAD_SIGMAS * sigma)
    ny = sfft.next_fast_len(H + pad, real=True)
    nx = sfft.next_fast_len(W + pad, real=True)
    rng = np.random.default_rng(1)
    real = np.zeros((ny, nx), dtype=dtype)
    real[:H, :W] = rng.random((H, W))
    cplx = (rng.standard_normal((ny, nx)) + 1j * rng.standard_normal((ny, nx))).astype(
        np.complex64 if dtype == np.float32 else np.complex128)
    return real, cplx


def floor(real, cplx):
    sfft.rfft2(real)
    sfft.ifft2(cplx)
    sfft.ifft2(cplx)


def peak_mib(func) -> float:
    """Peak of the memory allocated by ``func()`` through numpy (and Python), MiB."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    func()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return (peak - base) / 2**20


def parse_size(text: str) -> tuple[int, int]:
    h, w = text.lower().split("x")
    return int(h), int(w)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", nargs="+", type=parse_size, default=[(1040, 1376), (2048, 2048)],
                    help="image sizes HxW (default: 1040x1376 2048x2048)")
    ap.add_argument("--pitch", type=float, default=5.0, help="grid pitch = sigma, px")
    ap.add_argument("--repeat", type=int, default=7, help="timed runs of each candidate")
    ap.add_argument("--workers", type=int, default=1,
                    help="scipy.fft workers for ours and the floor alike (default 1)")
    ap.add_argument("--no-naive", action="store_true", help="skip the naive reference")
    args = ap.parse_args(argv)

    print(f"machine: {machine()}")
    print(f"scipy.fft workers: {args.workers}; times are the best of {args.repeat} "
          "interleaved runs (median in brackets)")
    header = (f"{'size':>10} {'dtype':>8} {'ours ms':>16} {'floor ms':>16} {'naive ms':>16} "
              f"{'ours/floor':>10} {'naive/ours':>10} {'peak MiB':>9}")
    print(header)
    print("-" * len(header))
    notes = []
    for shape in args.sizes:
        lattice, img64 = grid_test_image(shape, pitch=args.pitch)
        sigma = lattice.pitch
        for dtype in (np.float64, np.float32):
            img = img64.astype(dtype)
            real, cplx = floor_inputs(shape, sigma, dtype)
            funcs = {"ours": partial(wft, img, lattice), "floor": partial(floor, real, cplx)}
            if not args.no_naive:
                funcs["naive"] = partial(naive_wft, img64, lattice, sigma)
            with sfft.set_workers(args.workers):
                t = interleaved(funcs, args.repeat)
                peak = peak_mib(funcs["ours"])
            ours, fl = t["ours"][0], t["floor"][0]
            nv = t["naive"][0] if "naive" in t else float("nan")
            cell = {k: f"{v[0] * 1e3:7.1f} ({v[1] * 1e3:6.1f})" for k, v in t.items()}
            cell.setdefault("naive", "-")
            print(f"{shape[0]:>4}x{shape[1]:<5} {np.dtype(dtype).name:>8} {cell['ours']:>16} "
                  f"{cell['floor']:>16} {cell['naive']:>16} {ours / fl:>10.2f} "
                  f"{nv / ours:>10.2f} {peak:>9.0f}")
        if not args.no_naive:
            res = wft(img64, lattice)
            _, dphi = naive_wft(img64, lattice, sigma)
            v = res.valid
            notes.append(f"{shape[0]}x{shape[1]}: naive - ours, max |d phi/dx| difference on valid "
                         f"pixels: {np.max(np.abs(dphi - res.dphi)[:, :, v]):.2e} rad/px")
    for line in notes:
        print(line)
    print("peak MiB: memory allocated through numpy during one call of ours (tracemalloc), "
          "outputs included")


if __name__ == "__main__":
    main()
