"""Cost of the window's coupling correction against the transform it corrects.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_coupling.py [--sizes 1040x1376 2048x2048] [--repeat 5]

For each image size it prints the best wall and CPU times of

* ``wft``: :func:`gridstrain.wft` of a noisy grid image (the transform every state's
  maps come from);
* ``coupling``: :func:`gridstrain.phase.coupling_corrected` of its maps, which the
  measurement applies to the reference's and to each state's transform;

and their ratio (the CPU ratio is the one to trust on a shared machine).
"""

from __future__ import annotations

import argparse

from _common import grid_test_image, interleaved, machine
from gridstrain import wft
from gridstrain.phase import coupling_corrected


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["1040x1376"])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    print(machine())
    print(f"{'size':>11}  {'wft (s)':>8}  {'coupling (s)':>12}  {'wall ratio':>10}  "
          f"{'CPU ratio':>9}")
    for size in args.sizes:
        shape = tuple(int(n) for n in size.split("x"))
        lattice, img = grid_test_image(shape)
        maps = wft(img, lattice)
        t = interleaved({"wft": lambda img=img, lattice=lattice: wft(img, lattice),
                         "coupling": lambda maps=maps: coupling_corrected(maps)},
                        args.repeat)
        (w0, _, c0), (w1, _, c1) = t["wft"], t["coupling"]
        print(f"{size:>11}  {w0:8.3f}  {w1:12.3f}  {w1 / w0:10.2f}  {c1 / c0:9.2f}")


if __name__ == "__main__":
    main()
