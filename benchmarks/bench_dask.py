"""Method B on a local Dask cluster of 1 and 2 worker processes, against no cluster.

Run from the repository root (needs ``pip install "gridstrain[distributed]"``)::

    PYTHONPATH=src python benchmarks/bench_dask.py [--frames 100] [--size 1040x1376]
    PYTHONPATH=src python benchmarks/bench_dask.py --cli       # through the command line
    PYTHONPATH=src python benchmarks/bench_dask.py --quick     # small, under a minute

It writes a reference series and one loaded series of T uint16 TIFF frames each
(``_common.write_states``: a 12-bit grid, pitch 5 px, its own noise in every
frame, the loaded state translated by (0.3, -0.2) px and strained by 5e-4), then
measures them with :func:`gridstrain.measure_series` (``method="B"``, lattice
detected, the whole pipeline: screening, vibrations, noise floor, uncertainty
maps)

* in this process, without a scheduler (the transforms on threads, one per usable
  core);
* on a ``distributed.LocalCluster`` of 1 worker process of 1 thread, then of 2
  (``gridstrain.series.connect("local", n_workers=n)``: processes, loopback
  interface, dashboard on a free port), passed as ``scheduler=client``.

With ``--cli`` each run is instead ``gridstrain measure REF STATE -o out.h5 --method
B`` in a child process, given ``--scheduler tcp://127.0.0.1:PORT`` of the cluster
started here (its result read back with :func:`gridstrain.load`).

The clusters are started and every worker imports gridstrain before the clock
starts (the start-up is printed apart); the runs are interleaved, ``--repeat``
times, the best wall time kept. Parallelism is what is measured, so the
figure is the wall-clock time; the CPU time of this process (or of the command
line's child) and of the workers (``os.times`` on each) is printed beside it, with
the time each worker spent computing tasks (Dask's task stream: a worker busy
for a small part of the wall time waits for this process or for the machine), and
the load average before each run: on a machine shared with other work the wall
times of a 2-core run mean little when the load is above 0. Targets: 1 worker /
2 workers >= 1.7 (speed-up), in-process / 2 workers >= 1 (the cluster not slower
than threads). Every run's displacement is
compared with the in-process one (max |du| over the pixels valid in both: sums
added in another order: ~1e-15 px).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import inspect
import json
import os
import sys
import tempfile
import time
import warnings

import numpy as np

from _common import child_env, cli_command, load, machine, run_child, write_states
from bench_wft import parse_size


def _cpu_seconds() -> float:
    """User + system CPU time of the calling process (all its threads), s."""
    t = os.times()
    return t.user + t.system


@contextlib.contextmanager
def local_client(n_workers: int):
    """A client of a local cluster of ``n_workers`` single-threaded worker processes."""
    from gridstrain.series import _distributed as gd

    if "n_workers" in inspect.signature(gd.connect).parameters:
        with gd.connect("local", n_workers=n_workers) as client:
            yield client
        return
    import distributed  # the same settings, where connect() cannot size the cluster

    with distributed.LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client:
        yield client


def _import(name):
    importlib.import_module(name)


def _worker_cpu(client) -> float:
    """Sum of the workers' CPU times (user + system), s."""
    return sum(client.run(_cpu_seconds).values())


def timed_measure(ref, state, client=None, *, cli=None, out=None) -> dict:
    """One method-B measurement: through the API, or the command line when ``cli`` is given.

    The wall time, the CPU time here (this process, or the command line's child) and
    that of the workers, the time each worker spent computing tasks (Dask's task
    stream), the load before, and the result (read back from the output file for
    the command line).
    """
    before = load()
    w0 = _worker_cpu(client) if client is not None else 0.0
    stream = contextlib.nullcontext()
    if client is not None:
        from distributed import get_task_stream

        stream = get_task_stream(client=client)
    with stream as ts:
        wall, cpu, res = _measure(ref, state, client, cli, out)
    workers = _worker_cpu(client) - w0 if client is not None else 0.0
    busy = {}
    for task in getattr(ts, "data", None) or []:  # seconds each worker computed tasks
        for ss in task.get("startstops", ()):
            if ss.get("action") == "compute":
                busy[task["worker"]] = busy.get(task["worker"], 0.0) + ss["stop"] - ss["start"]
    return {"wall": wall, "cpu": cpu, "workers_cpu": workers, "load": before, "result": res,
            "busy": sorted(busy.values(), reverse=True)}


def _measure(ref, state, client, cli, out):
    import gridstrain

    if cli is None:
        kw = {"method": "B"}
        if client is not None:
            kw["scheduler"] = client
        c0, t0 = _cpu_seconds(), time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = gridstrain.measure_series(ref, state, **kw)
        wall, cpu = time.perf_counter() - t0, _cpu_seconds() - c0
    else:
        cmd = [*cli, "measure", ref, state, "-o", out, "--quiet", "--overwrite",
               "--method", "B"]
        if client is not None:
            cmd += ["--scheduler", client.scheduler.address]
        r = run_child(cmd, child_env())
        wall, cpu = r["wall"], r["cpu"]
        res = gridstrain.load(out)
    return wall, cpu, res


def max_du(a, b) -> tuple[float, int]:
    """Max |u_a - u_b| over pixels valid in both, px, and the pixels valid in only one."""
    both = a.valid & b.valid
    du = np.abs(np.asarray(a.u, dtype=np.float64) - np.asarray(b.u, dtype=np.float64))
    worst = float(np.max(np.moveaxis(du, 1, 0)[:, both])) if both.any() else float("nan")
    return worst, int(np.count_nonzero(a.valid ^ b.valid))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=100, help="T, frames per series (default 100)")
    ap.add_argument("--size", type=parse_size, default=(1040, 1376), help="HxW (default 1040x1376)")
    ap.add_argument("--pitch", type=float, default=5.0, help="grid pitch, px (default 5)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                    help="local clusters to run, by number of worker processes (default 1 2)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="interleaved runs of each, best wall time kept (default 1; 3 on "
                         "a machine shared with other work)")
    ap.add_argument("--quick", action="store_true",
                    help="12 frames of 256x320 per series, to check the script")
    ap.add_argument("--cli", action="store_true",
                    help="run the command line in a child process instead of the API: "
                         "gridstrain measure REF STATE --method B [--scheduler ADDRESS of "
                         "the cluster started here]")
    ap.add_argument("--tmp", default=None, help="folder for the series (default: system temp)")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames, args.size = 12, (256, 320)
    try:
        import distributed  # noqa: F401
    except ImportError:
        print('needs Dask\'s distributed scheduler: pip install "gridstrain[distributed]"')
        return 1
    # the workers are fresh interpreters: they must import this checkout's gridstrain
    os.environ["PYTHONPATH"] = child_env()["PYTHONPATH"]
    from gridstrain import measure_series

    if "scheduler" not in inspect.signature(measure_series).parameters:
        print("this gridstrain's measure_series takes no scheduler")
        return 1
    cli = cli_command() if args.cli else None
    T, (H, W) = args.frames, args.size
    print(f"machine: {machine()}")
    print(f"{'gridstrain measure (child process)' if cli else 'measure_series'}: "
          f"method B, 2 series (reference, one loaded state) x {T} frames of {H}x{W} uint16 "
          f"TIFF, pitch {args.pitch:g} px")
    runs = {}
    with tempfile.TemporaryDirectory(prefix="gridstrain-bench-dask-", dir=args.tmp) as tmp:
        t0 = time.perf_counter()
        ref, state = (str(f) for f in write_states(tmp, args.size, T, 1, pitch=args.pitch))
        print(f"(wrote {2 * T} frames in {time.perf_counter() - t0:.1f} s)")
        out = os.path.join(tmp, "out.h5")
        # every cluster up at once (idle workers cost memory only), the runs interleaved
        # so that a change of the machine's load spreads over all of them
        with contextlib.ExitStack() as stack:
            clients = {"in-process (threads)": None}
            for n in args.workers:
                t0 = time.perf_counter()
                client = stack.enter_context(local_client(n))
                client.run(_import, "gridstrain.series")
                client.run(_import, "gridstrain.series")
                print(f"(cluster of {n} worker(s) x 1 thread started in "
                      f"{time.perf_counter() - t0:.1f} s)")
                clients[f"LocalCluster {n} x 1"] = client
            for _ in range(args.repeat):
                for name, client in clients.items():
                    runs.setdefault(name, []).append(
                        timed_measure(ref, state, client, cli=cli, out=out))

    best = {k: min(v, key=lambda r: r["wall"]) for k, v in runs.items()}
    base = best["in-process (threads)"]
    print()
    here = "CPU child s" if cli else "CPU here s"
    print(f"{'run':<24} {'wall s':>8} {here:>11} {'CPU workers s':>14} "
          f"{'max |du| px':>12} {'valid differ':>12}  load before")
    for k, r in best.items():
        du, nv = max_du(r["result"], base["result"])
        print(f"{k:<24} {r['wall']:>8.2f} {r['cpu']:>11.2f} {r['workers_cpu']:>14.2f} "
              f"{du:>12.1e} {nv:>12d}  {r['load']}")
    if args.repeat > 1:
        for k, v in runs.items():
            walls = ", ".join(f"{r['wall']:.1f}" for r in v)
            print(f"  {k}: wall of every run {walls} s")
    figures = {k: round(r["wall"], 3) for k, r in best.items()}
    for k, r in best.items():
        if r["workers_cpu"] > 0:
            # the part of the work no number of workers shortens: with it run alone, an
            # n-worker speed-up is at most (here + workers) / (here + workers / n)
            share = r["cpu"] / (r["cpu"] + r["workers_cpu"])
            print(f"{k}: {r['cpu']:.1f} s of CPU stay here, {100 * share:.0f} % of the "
                  "total; each worker computed tasks "
                  + ", ".join(f"{b:.1f} s ({100 * b / r['wall']:.0f} %)" for b in r["busy"])
                  + " of the wall time")
            if r["busy"]:
                # below ~90 %: the workers' tasks waited for a core (other processes,
                # this one): the machine, not the cluster, sets the wall time
                print(f"  the workers had a core for {100 * r['workers_cpu'] / sum(r['busy']):.0f} "
                      "% of their tasks' time")
    one, two = best.get("LocalCluster 1 x 1"), best.get("LocalCluster 2 x 1")
    if one:
        here, work = one["cpu"], one["workers_cpu"]
        print(f"speed-up bound of 2 workers if the work kept here does not overlap the "
              f"workers': {(here + work) / (here + work / 2):.2f}x")
    print()
    if one and two:
        print(f"speed-up 2 workers / 1 worker (wall): {one['wall'] / two['wall']:.2f}x "
              f"(target >= 1.7)")
        figures["speedup_2_over_1"] = round(one["wall"] / two["wall"], 3)
    if two:
        print(f"in-process / 2 workers (wall): {base['wall'] / two['wall']:.2f} "
              f"(target >= 1: the cluster not slower)")
        figures["inprocess_over_2"] = round(base["wall"] / two["wall"], 3)
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
