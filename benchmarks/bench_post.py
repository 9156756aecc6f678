"""Peak memory and CPU of the commands that read a record's result file, for a short
and a long record, against the memory its maps take once read.

A record of 250 x 400 px frames (``bench_sequence.write_record``) is measured with
``gridstrain measure RECORD --reference-frames 1`` for ``--short`` and ``--states``
states; then ``gridstrain gauge``, ``history``, ``plot`` and ``report`` read each result
file in a fresh interpreter (imports included). Each command's peak resident memory
(``VmHWM``) and CPU time are printed for both records, beside the bytes of the per-state
maps of the file (what reading them into memory takes, at least): a command that reads
the record state by state keeps its peak as the record grows.

    python benchmarks/bench_post.py [--states 300] [--short 30]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import h5py

from _common import cli_command, machine, run_child
from bench_sequence import run, write_record

COMMANDS = {
    "gauge": ["gauge", "{result}", "-o", "{dir}/gauge.csv", "--overwrite"],
    "history": ["history", "{result}", "--loads", "{dir}/times.csv", "-o",
                "{dir}/history.csv", "--overwrite"],
    "plot": ["plot", "{result}", "-o", "{dir}/figures", "--overwrite"],
    "report": ["report", "{result}", "-o", "{dir}/report.html", "--overwrite"],
}


def map_bytes(path: Path) -> int:
    """Bytes of the file's (state, y, x) variables once read."""
    with h5py.File(path, "r") as h5:
        return sum(h5[k].size * h5[k].dtype.itemsize for k in h5
                   if isinstance(h5[k], h5py.Dataset) and h5[k].ndim == 3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=300)
    ap.add_argument("--short", type=int, default=30)
    args = ap.parse_args()
    print(machine())
    cli = cli_command()
    rows = {}
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        for n in (args.short, args.states):
            write_record(d / f"rec{n}.tif", n + 1)
            result = d / f"rec{n}.h5"
            run(cli, d / f"rec{n}.tif", result)
            (d / "times.csv").write_text("load [kN],time [s]\n" + "".join(
                f"{0.01 * k},{0.5 * k}\n" for k in range(n)))
            rows[n] = {"maps": map_bytes(result)}
            for name, argv in COMMANDS.items():
                cmd = [a.format(result=result, dir=d) for a in argv]
                rows[n][name] = run_child([*cli, *cmd], peak=True)
    print(f"{'':>10}" + "".join(f"{f'{n} states':>30}" for n in rows))
    print(f"{'maps':>10}" + "".join(f"{r['maps'] / 2**20:>26.0f} MiB" for r in rows.values()))
    for name in COMMANDS:
        print(f"{name:>10}" + "".join(
            f"{r[name]['peak'] / 2**20:>14.0f} MiB, CPU {r[name]['cpu']:6.2f} s"
            for r in rows.values()))
    a, b = rows[args.short], rows[args.states]
    print("peak memory, long record / short record: " + ", ".join(
        f"{name} {b[name]['peak'] / a[name]['peak']:.2f}" for name in COMMANDS)
        + f" (maps {b['maps'] / a['maps']:.1f})")


if __name__ == "__main__":
    main()
