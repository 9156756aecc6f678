"""Cost of the window's coupling correction against the transform it corrects.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_coupling.py [--sizes 250x400 1040x1376] \
        [--repeat 7] [--keep-freed] [--float32]

For each image size it prints the best CPU (and wall) times, ms, of

* ``wft``: :func:`gridstrain.wft` of a noisy grid image (the transform every state's
  maps come from);
* ``numpy``: :func:`gridstrain.phase.coupling_corrected` of its maps by the numpy path
  (``scipy.ndimage`` correlations of whole maps: what runs without numba);
* ``compiled``: the same by the compiled loops (numba, the ``fast`` extra), what
  runs by default where numba is installed;

and the ratios numpy / compiled and compiled / wft (the CPU ratios are the ones to
trust on a shared machine), with the largest differences between the two paths' maps.
``--keep-freed`` has glibc's malloc keep freed blocks for the next ones, as the
command line does (:func:`gridstrain._runtime.threads.keep_freed_memory`): without it, each
call's fresh output maps are faulted in and zeroed by the kernel, a cost both paths
pay and that grows the smaller the image. ``--float32`` transforms float32 images
(complex64 maps, as the series' float32 option gives).
"""

from __future__ import annotations

import argparse

import numpy as np

from _common import grid_test_image, interleaved, machine, phase_loops_off
from gridstrain import wft
from gridstrain._runtime.threads import keep_freed_memory
from gridstrain.phase import compiled_loops, coupling_corrected


def _numpy_path(maps):
    """:func:`coupling_corrected` with the compiled loops switched off."""
    with phase_loops_off():
        return coupling_corrected(maps)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["250x400", "1040x1376"])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--keep-freed", action="store_true",
                        help="keep freed memory for the next blocks, as the command line")
    parser.add_argument("--float32", action="store_true", help="float32 images and maps")
    args = parser.parse_args(argv)
    if args.keep_freed and not keep_freed_memory():
        parser.error("--keep-freed needs glibc's malloc")
    print(machine())
    compiled = compiled_loops() is not None
    print(f"compiled loops: {'numba' if compiled else 'not available (numba missing)'}; "
          f"freed memory {'kept' if args.keep_freed else 'returned (malloc default)'}; "
          f"{'float32' if args.float32 else 'float64'} images")
    print(f"{'size':>11}  {'wft':>7}  {'numpy':>7}  {'compiled':>8}  {'numpy/':>7}  "
          f"{'compiled/':>9}  {'wall':>21}  {'max |d phase|':>13}  {'max |d dphi|':>12}")
    print(f"{'':>11}  {'CPU ms':>7}  {'CPU ms':>7}  {'CPU ms':>8}  {'compiled':>7}  "
          f"{'wft':>9}  {'wft/numpy/compiled ms':>21}  {'rad':>13}  {'rad/px':>12}")
    for size in args.sizes:
        shape = tuple(int(n) for n in size.split("x"))
        lattice, img = grid_test_image(shape)
        img = img.astype(np.float32 if args.float32 else np.float64)
        maps = wft(img, lattice)
        funcs = {"wft": lambda img=img, lattice=lattice: wft(img, lattice),
                 "numpy": lambda maps=maps: _numpy_path(maps)}
        if compiled:
            funcs["compiled"] = lambda maps=maps: coupling_corrected(maps)
        t = interleaved(funcs, args.repeat)
        wall = {name: 1e3 * v[0] for name, v in t.items()}
        cpu = {name: 1e3 * v[2] for name, v in t.items()}
        if compiled:
            a, b = coupling_corrected(maps), _numpy_path(maps)
            dpsi = np.abs(np.angle(a.psi * np.conj(b.psi))).max()
            ddphi = np.nanmax(np.abs(a.dphi - b.dphi))
            print(f"{size:>11}  {cpu['wft']:7.1f}  {cpu['numpy']:7.1f}  {cpu['compiled']:8.1f}  "
                  f"{cpu['numpy'] / cpu['compiled']:7.2f}  {cpu['compiled'] / cpu['wft']:9.2f}  "
                  f"{wall['wft']:7.1f}/{wall['numpy']:6.1f}/{wall['compiled']:6.1f}  "
                  f"{dpsi:13.1e}  {ddphi:12.1e}")
        else:
            print(f"{size:>11}  {cpu['wft']:7.1f}  {cpu['numpy']:7.1f}  {'-':>8}  {'-':>7}  "
                  f"{'-':>9}  {wall['wft']:7.1f}/{wall['numpy']:6.1f}/{'-':>6}")


if __name__ == "__main__":
    main()
