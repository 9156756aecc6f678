"""Per-frame cost of gridstrain.wft against the FFT floor and a naive reference.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_wft.py [--sizes 1040x1376 2048x2048] [--repeat 7]

For each image size and precision it prints the per-frame time of

* ``exact``: :func:`gridstrain.wft`, both phases and the four exact phase derivatives;
* ``fast``: ``gridstrain.wft(..., derivatives="fast")`` in numpy (the compiled
  loops switched off), one inverse transform per wave vector and the derivatives
  from ``Psi`` by a least-squares differentiator (their difference from the exact
  ones is printed below);
* ``compiled``: the same filter in the compiled loops of ``gridstrain.phase._kernels``
  (numba, the ``fast`` extra): what ``wft`` does by default when numba is
  installed (skipped, ``-``, without numba). The first call of a process loads
  numba and compiles the loops, or loads them from numba's disk cache: both are
  timed apart, each in a fresh interpreter, and printed before the table; the
  table's runs follow a warm-up call;
* ``floor``: one ``rfft2`` and two complex ``ifft2`` of the padded size wft uses,
  with the same library (scipy.fft) -- the least any FFT implementation of the
  window needs for the two phase maps, derivatives not included;
* ``naive``: the way the MATLAB toolbox does it, in float64 -- zero-padded linear
  convolution with the window truncated at 4 sigma through full complex FFTs,
  phases by ``np.angle``, derivatives by ``np.gradient`` of the unwrapped phases;

as the best wall time of interleaved runs (median in brackets) and the ratios of
the best wall times and of the best CPU times (the CPU ratio is the one to trust on
a machine shared with other work), and the peak of memory allocated through numpy
during one call (tracemalloc). ``--study`` adds the accuracy, against the exact
derivatives, of central differences of orders 2 to 8 on the demodulated maps, and
their cost in numpy.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import subprocess
import sys
import tempfile
import tracemalloc
from functools import partial
from pathlib import Path

if __name__ == "__main__":  # before numpy loads OpenBLAS: its idle threads spin after a
    # matrix product (the numpy fast path's differentiator), and their CPU time would
    # land on whichever candidate runs next
    for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_name, "1")

import numpy as np
from scipy import fft as sfft

from _common import grid_test_image, interleaved, machine, phase_loops_off
from gridstrain import wft
from gridstrain.phase import compiled_loops
from gridstrain.phase._transform import _PAD_SIGMAS, _wft

_fft = importlib.import_module("gridstrain._runtime.fft")
_impl = importlib.import_module("gridstrain.phase._transform")


def numpy_fast(img, lattice, workers):
    """``derivatives="fast"`` with the compiled loops switched off."""
    with phase_loops_off():
        return _wft(img, lattice, derivatives="fast", workers=workers)


_FIRST_CALL = """
import time
t0 = time.perf_counter()
import numpy as np
from gridstrain import Lattice
from gridstrain.phase._transform import _wft
lat = Lattice.from_pitch(5.0, angle=3.0)
img = np.random.default_rng(0).random((96, 112))
t1 = time.perf_counter()
_wft(img, lat, derivatives="fast")
_wft(img.astype(np.float32), lat, derivatives="fast")
t2 = time.perf_counter()
_wft(img, lat, derivatives="fast")
_wft(img.astype(np.float32), lat, derivatives="fast")
print(t2 - t1 - (time.perf_counter() - t2))
"""


def first_call_seconds(cache_dir: str) -> float:
    """Seconds that the first compiled transforms (float64 and float32) of a fresh
    interpreter take beyond the same calls warm: numba's import, and compiling the
    loops (empty cache) or loading them (``cache_dir`` filled by an earlier run)."""
    src = str(Path(_impl.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=src, NUMBA_CACHE_DIR=cache_dir)
    out = subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env, check=True,
                         capture_output=True, text=True)
    return float(out.stdout.split()[-1])


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


def floor(real, cplx, workers=1):
    """One rfft2 and two ifft2, on the FFT implementation wft uses (gridstrain._runtime.fft)."""
    _fft.call("rfft2", real, workers=workers)
    _fft.call("ifft2", cplx, workers=workers)
    _fft.call("ifft2", cplx, workers=workers)


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


def difference_derivatives(psi, order):
    """Phase derivatives of ``psi`` (H, W) by central differences of ``order`` (2, 4...).

    Coefficients of the maximally flat antisymmetric filter; edges wrap (the study
    looks at valid pixels only).
    """
    m = order // 2
    n = np.arange(1, m + 1)
    a = np.linalg.solve(np.array([2.0 * n ** (2 * j + 1) for j in range(m)]), np.eye(m)[0])
    power = np.abs(psi) ** 2
    out = []
    for axis in (1, 0):
        d = np.zeros_like(psi)
        for i, an in enumerate(a, start=1):
            d += an * (np.roll(psi, -i, axis=axis) - np.roll(psi, i, axis=axis))
        out.append(np.imag(np.conj(psi) * d) / power)
    return out


def study(shape, repeat):
    print()
    print(f"derivatives by central differences of the demodulated maps, {shape[0]}x{shape[1]}, "
          "against the exact ones (max over valid pixels, rad/px):")
    print(f"{'order':>6} {'noise-free':>12} {'noisy':>12} {'numpy ms (4 maps)':>18}")
    maps = {}
    for noisy in (False, True):
        lattice, img = grid_test_image(shape, noisy=noisy)
        maps[noisy] = wft(img, lattice)
    for order in (2, 4, 6, 8):
        errs = []
        for noisy in (False, True):
            res = maps[noisy]
            worst = 0.0
            for j in range(2):
                dx, dy = difference_derivatives(res.psi[j], order)
                for axis, d in enumerate((dx, dy)):
                    worst = max(worst, float(np.max(np.abs(d - res.dphi[j, axis])[res.valid])))
            errs.append(worst)
        psi = np.ascontiguousarray(maps[True].psi)
        t = interleaved({"fd": lambda psi=psi, order=order: [difference_derivatives(p, order)
                                                             for p in psi]}, repeat)["fd"]
        print(f"{order:>6} {errs[0]:>12.1e} {errs[1]:>12.1e} {t[2] * 1e3:>18.1f}")
    print("(order 2 needs no FFT beyond the phases' but misses the 1e-7 rad/px "
          "derivative bound that the exact and fast paths meet)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", nargs="+", type=parse_size, default=[(1040, 1376), (2048, 2048)],
                    help="image sizes HxW (default: 1040x1376 2048x2048)")
    ap.add_argument("--pitch", type=float, default=5.0, help="grid pitch = sigma, px")
    ap.add_argument("--repeat", type=int, default=7, help="timed runs of each candidate")
    ap.add_argument("--workers", type=int, default=1,
                    help="threads for ours (wft's workers) and for the floor's FFTs; the naive "
                         "reference runs on numpy.fft, single-threaded (default 1)")
    ap.add_argument("--no-naive", action="store_true", help="skip the naive reference")
    ap.add_argument("--study", action="store_true",
                    help="accuracy and cost of difference derivatives (first size)")
    args = ap.parse_args(argv)

    print(f"machine: {machine()}")
    compiled = compiled_loops() is not None
    if compiled:
        with tempfile.TemporaryDirectory() as cache:
            cold = first_call_seconds(cache)
            warm = first_call_seconds(cache)
        print(f"compiled loops (numba): first call of a process {cold:.2f} s with an empty "
              f"cache (import and compile), {warm:.2f} s from numba's disk cache; not in the "
              "timings below")
    else:
        print("compiled loops: numba is not installed (pip install \"gridstrain[fast]\"); "
              "the compiled column is skipped")
    print(f"FFT implementation: {_fft.name()} (GRIDSTRAIN_FFT); threads: {args.workers} "
          "(wft's workers, the floor's FFT workers); "
          f"pitch = sigma = {args.pitch:g} px; "
          f"best of {args.repeat} interleaved runs")
    names = (["exact", "fast"] + (["compiled"] if compiled else []) + ["floor"]
             + ([] if args.no_naive else ["naive"]))
    header = (f"{'size':>10} {'dtype':>8} " + " ".join(f"{n + ' ms':>16}" for n in names)
              + f" {'exact/floor':>12} {'fast/floor':>12} {'compiled/floor':>14} "
              f"{'naive/exact':>12} {'peak MiB':>9}"
              + (f" {'compiled MiB':>12}" if compiled else ""))
    print(header)
    print(f"{'':>19} ratios: best wall (best CPU)")
    print("-" * len(header))
    notes = []
    for shape in args.sizes:
        lattice, img64 = grid_test_image(shape, pitch=args.pitch)
        sigma = lattice.pitch
        for dtype in (np.float64, np.float32):
            img = img64.astype(dtype)
            real, cplx = floor_inputs(shape, sigma, dtype)
            funcs = {"exact": partial(_wft, img, lattice, derivatives="exact",
                                      workers=args.workers),
                     "fast": partial(numpy_fast, img, lattice, args.workers),
                     "floor": partial(floor, real, cplx, args.workers)}
            if compiled:
                funcs["compiled"] = partial(_wft, img, lattice, derivatives="fast",
                                            workers=args.workers)
            if not args.no_naive:
                funcs["naive"] = partial(naive_wft, img64, lattice, sigma)
            t = interleaved(funcs, args.repeat)
            peak = peak_mib(funcs["exact"])
            if compiled:
                peak_c = peak_mib(funcs["compiled"])

            def ratio(a, b, t=t):
                return f"{t[a][0] / t[b][0]:5.2f} ({t[a][2] / t[b][2]:4.2f})"

            cells = " ".join(f"{t[n][0] * 1e3:7.1f} ({t[n][1] * 1e3:6.1f})" for n in names)
            naive = ratio("naive", "exact") if "naive" in t else "-"
            comp = ratio("compiled", "floor") if compiled else "-"
            print(f"{shape[0]:>4}x{shape[1]:<5} {np.dtype(dtype).name:>8} {cells} "
                  f"{ratio('exact', 'floor'):>12} {ratio('fast', 'floor'):>12} "
                  f"{comp:>14} "
                  f"{naive:>12} {peak:>9.0f}" + (f" {peak_c:>12.0f}" if compiled else ""))
        res = _wft(img64, lattice, derivatives="exact")
        v = res.valid
        fast = {dt: numpy_fast(img64.astype(dt), lattice, 1) for dt in (np.float64, np.float32)}
        ex32 = _wft(img64.astype(np.float32), lattice, derivatives="exact")
        notes.append(f"{shape[0]}x{shape[1]}, max |d phi| difference from exact on valid "
                     f"pixels, rad/px: fast {_worst(fast[np.float64], res):.1e} (float64), "
                     f"{_worst(fast[np.float32], ex32):.1e} (float32, against float32 exact), ")
        if compiled:
            comp = {dt: _wft(img64.astype(dt), lattice, derivatives="fast")
                    for dt in (np.float64, np.float32)}
            notes[-1] += (f"compiled {_worst(comp[np.float64], res):.1e} (float64), "
                          f"{_worst(comp[np.float32], ex32):.1e} (float32), "
                          f"{_worst(comp[np.float32], res):.1e} (float32 against float64 "
                          "exact), ")
        if not args.no_naive:
            _, dphi = naive_wft(img64, lattice, sigma)
            notes[-1] += f"naive {np.max(np.abs(dphi - res.dphi)[:, :, v]):.1e} rad/px"
    for line in notes:
        print(line)
    print("peak MiB (compiled MiB): memory allocated through numpy during one call of "
          "exact (compiled) (tracemalloc), outputs included; the floor's own outputs take "
          f"{_floor_mib(args):.0f} MiB "
          f"at {args.sizes[0][0]}x{args.sizes[0][1]} float64")
    if args.study:
        study(args.sizes[0], args.repeat)


def _worst(a, b) -> float:
    """Largest |d phi| difference between two transforms on b's valid pixels, rad/px."""
    return float(np.max(np.abs(a.dphi.astype(float) - b.dphi)[:, :, b.valid]))


def _floor_mib(args) -> float:
    real, cplx = floor_inputs(args.sizes[0], args.pitch, np.float64)
    return peak_mib(partial(floor, real, cplx))


if __name__ == "__main__":
    main()
