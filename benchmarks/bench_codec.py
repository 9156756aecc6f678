"""CPU of writing and reading a result's ``gridstrain`` group, per state, by columns
(format 3) against value by value (format 2), and the HDF5 objects each leaves.

The results are measured records of one-frame states (``--size`` px, a growing uniaxial
strain), or a result file given with ``--file`` (e.g. the output of
``gridstrain measure record.tif --reference-frames 1``). The group is written into an
HDF5 file in memory (no disk), best of ``--repeat``; a state's cost is the difference
of the long and the short record over the difference of their numbers of states.

    PYTHONPATH=src python benchmarks/bench_codec.py [--states 100] [--short 10]
        [--size 64x80] [--repeat 5] [--file RESULT.h5]
"""

from __future__ import annotations

import argparse
import io
import time

import h5py
import numpy as np

from _common import machine
from gridstrain import Lattice
from gridstrain.kinematics import Measurement
from gridstrain.models import synthetic
from gridstrain.results import SeriesResult, _codec, load
from gridstrain.results._codec import _ROOT_FIELDS, _decode, _member
from gridstrain.results._layout import _write_group
from gridstrain.series import measure_series

WRITERS = {"value by value (format 2)": 10**12, "by columns (format 3)": _codec._MIN_ROWS}


def record(n_states: int, shape, seed: int = 0):
    lattice = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(seed)

    def frame(strain):
        disp = (lambda X, Y: (strain * X, 0.0 * Y)) if strain else None
        clean = synthetic.grid_image(shape, lattice, amplitude=2048.0, displacement=disp)
        return np.clip(synthetic.add_noise(clean, rng=rng), 0, 4095)[None]

    return measure_series(frame(0.0), [frame(2e-4 * (k + 1)) for k in range(n_states)],
                          lattice=lattice)


def maps_of(result):
    """What :func:`gridstrain.load` takes from the file's variables, from ``result``."""
    def fill(cls, group, values, row):
        if cls is SeriesResult:
            values.update({k: getattr(result, k) for k in _ROOT_FIELDS["SeriesResult"]})
        elif cls is Measurement:
            i = row if row is not None else int(group.name.rsplit("/", 1)[1])
            m = result.measurements[i]
            values.update({k: getattr(m, k) for k in _ROOT_FIELDS["Measurement"]},
                          reference=None, deformed=None)
        return values

    return fill


def timed(result, min_rows: int, repeat: int) -> dict:
    """CPU of writing and of reading the group, and its objects and attributes."""
    _codec._MIN_ROWS = min_rows
    write = read = np.inf
    try:
        for _ in range(repeat):
            buf = io.BytesIO()
            with h5py.File(buf, "w") as h5:
                c0 = time.process_time()
                _write_group(h5, result, {}, phase_maps=False)
                write = min(write, time.process_time() - c0)
            with h5py.File(buf, "r") as h5:
                c0 = time.process_time()
                _decode(_member(h5["gridstrain"], "result"), {}, maps_of(result))
                read = min(read, time.process_time() - c0)
                g = h5["gridstrain/result"]
                names: list[str] = []
                g.visit(names.append)
                attrs = len(g.attrs) + sum(len(g[n].attrs) for n in names)
    finally:
        _codec._MIN_ROWS = WRITERS["by columns (format 3)"]
    return {"write": write, "read": read, "objects": len(names), "attrs": attrs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=100)
    ap.add_argument("--short", type=int, default=10)
    ap.add_argument("--size", default="64x80")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--file", help="a result file instead of the measured records")
    args = ap.parse_args()
    print(machine())
    if args.file:
        results = {0: None, (r := load(args.file)).n_states: r}
        print(f"{args.file}: {r.n_states} states of {r.shape[0]} x {r.shape[1]} px")
    else:
        shape = tuple(int(v) for v in args.size.split("x"))
        results = {n: record(n, shape) for n in (args.short, args.states)}
    (short, a), (long_, b) = sorted(results.items())
    per = {}
    for name, rows in WRITERS.items():
        t = {n: timed(r, rows, args.repeat) if r is not None else
             {"write": 0.0, "read": 0.0, "objects": 0, "attrs": 0}
             for n, r in ((short, a), (long_, b))}
        per[name] = {k: (t[long_][k] - t[short][k]) / (long_ - short)
                     for k in ("write", "read")}
        print(f"{name}: write {per[name]['write'] * 1e3:.2f} ms/state, read "
              f"{per[name]['read'] * 1e3:.2f} ms/state; objects under gridstrain/result "
              + ", ".join(f"{t[n]['objects']} ({t[n]['attrs']} attributes) at {n} states"
                          for n in (short, long_) if n))
    old, new = per.values()
    print(f"by columns / value by value: write {new['write'] / old['write']:.3f}, read "
          f"{new['read'] / old['read']:.3f} (target: writing <= 2 ms per state)")


if __name__ == "__main__":
    main()
