"""How often a state is measured wrong, and how often wrong and confirmed, on grids that
a steep gradient or an opening leaves hard to follow.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_trust.py [--spots SEED] [--quick] [--list]

The images come from the numpy-only generator of ``tests/test_torn_grid.py``: a
checkerboard or a cross grid of lines (pitch 6 to 10 px, turned 0, 30 or 45 degrees),
160 x 256 px, noise 0.5 % of white. Two families of pairs:

- steep: u_x rising by 1 to 3 lattice periods over 2 to 4 periods (10 to 90 %, a tanh),
  the grid intact (the rises whose largest gradient is under 0.9: no fold);
- open: the specimen parted along a row, its sides moved apart by 2 to 6 px (the
  opening shows the dark background), a smooth strain of 1e-3 over both.

Each pair goes through :func:`gridstrain.measure` and :func:`gridstrain.series.
measure_series` with the default options. A state is wrong when more than 1 % of its
valid pixels are a quarter period off or more; the table counts the wrong ones and those
of them whose fringe order is confirmed (which must be none). ``--spots``: printed dark
spots on the specimen (the features that can tell one period from the next).
"""

from __future__ import annotations

import argparse
import itertools
import sys
import warnings
import zlib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_torn_grid as torn
from gridstrain import measure
from gridstrain.series import measure_series


def _period(p, pattern):
    return p * np.sqrt(2) if pattern == "checker" else p


def cases(quick: bool):
    pitches = (6.0,) if quick else (6.0, 10.0)
    for pattern, p, angle, rise, over in itertools.product(
            ("checker", "cross"), pitches, (0.0, 30.0, 45.0), (1, 2, 3), (2, 3, 4)):
        if 1.1 * rise / over < 0.9 and not (quick and angle == 30.0):
            yield "steep", (p, angle, rise, over, pattern)
    for pattern, p, angle, opening in itertools.product(
            ("cross", "checker"), (6.0,) if quick else (6.0, 8.0), (0.0, 45.0),
            (2.0, 3.0, 4.5, 6.0)):
        yield "open", (p, angle, opening, pattern)


def pair(kind, args, spots):
    if kind == "steep":
        p, angle, rise, over, pattern = args
        seed = zlib.crc32(repr(args).encode()) % 1000
        ref, cur, disp, _ = torn.steep_pair(p, angle, rise * _period(p, pattern), seed,
                                            (160, 256), pattern=pattern, spots=spots,
                                            over=over)
    else:
        p, angle, opening, pattern = args
        ref, cur, disp, _ = torn.torn_pair(p, angle, opening, 0.0, int(opening * 10) + int(p),
                                           (160, 224), pattern=pattern, spots=spots)
    return ref, cur, disp, _period(args[0], args[-1] if kind == "open" else args[4])


def wrong_share(res, disp, period) -> float:
    err = torn._errors(res, disp)
    if err.shape[1] == 0:
        return 0.0
    return float(np.mean(np.any(np.abs(err) > period / 4, axis=0)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spots", type=int, default=None, help="seed of printed spots")
    ap.add_argument("--quick", action="store_true", help="pitch 6 px only")
    ap.add_argument("--list", action="store_true", help="one line per case")
    a = ap.parse_args()
    totals: dict = {}
    for kind, args in cases(a.quick):
        ref, cur, disp, period = pair(kind, args, a.spots)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = measure(ref, cur)
        s = measure_series(ref, cur)
        wp, ws = wrong_share(m, disp, period), wrong_share(s, disp, period)
        cp, cs = m.fringe_order.confirmed, s.fringe_orders[0].confirmed
        t = totals.setdefault(kind, [0, 0, 0, 0, 0])
        t[0] += 1
        t[1] += wp > 0.01
        t[2] += wp > 0.01 and cp
        t[3] += ws > 0.01
        t[4] += ws > 0.01 and cs
        if a.list:
            print(f"{kind:5} {args!s:34} pair {wp:6.1%} {'confirmed' if cp else '-':9} | "
                  f"series {ws:6.1%} {'confirmed' if cs else '-':9} "
                  f"cut {len(s.discontinuities[0])}", flush=True)
    print(f"{'family':8} {'cases':>5} | {'pair wrong':>10} {'and confirmed':>13} | "
          f"{'series wrong':>12} {'and confirmed':>13}")
    for kind, t in totals.items():
        print(f"{kind:8} {t[0]:5d} | {t[1]:10d} {t[2]:13d} | {t[3]:12d} {t[4]:13d}")


if __name__ == "__main__":
    main()
