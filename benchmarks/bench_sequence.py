"""CPU per one-frame state of a record measured with ``gridstrain measure --each-frame``,
against the FFT floor of one frame; peak memory for a short and a long record.

The record is one multi-page TIFF of 250 x 400 px frames (12-bit grid at pitch 5,
Poisson-Gaussian noise), frame ``t`` displaced by ``t / 20`` of
:func:`_common.state_displacement`'s step: a first frame taken as the reference
(``--reference-frames 1``) and every later frame a state. A state's CPU time is the
difference of two runs (``--short`` and ``--states`` states) over the difference of
their numbers of states, so that imports, the reference and the lattice cancel; each
run ``--repeat`` times, interleaved, its least CPU time taken (on a shared machine one
run of each can be 30 % off, and their difference more). Both
runs must be long records (more than twice ``SAMPLE_EVERY``, 20 states), where the
expensive checks are sampled: a short run of 20 states or fewer checks every state in
full, and its difference with a long one would take those checks off the light
states' cost (the script refuses it).
Two FFT floors of a frame are printed, one thread each, and the ratio to both: the
issue's floor, the least any implementation could do (one ``rfft2`` of the real frame
and two complex ``ifft2``, float32: what a one-frame state of 12-bit frames now
computes, :mod:`gridstrain.conventions`), against which the target of 20 times is
set; and, for comparison with earlier rounds, the floor of the transforms in float64
(one complex ``fft2`` and two ``ifft2``, as the pipeline computed such states
before), 1.6 to 2 times as long. Then the CPU of each stage of a state
(:data:`gridstrain.series._stages.STAGES`, and the pass's own steps), measured in this
process between the progress messages that name them, over the ``--states`` record.

With ``--alone``, the main computations of a state (its frame's pass, the carrier's
search, the transform, the coupling correction, the kinematics, the summary's median
modulus, the local noise, the uncertainty maps and the store) are timed inside the
measurement (the median and the least over its states) and again alone, two states'
calls re-run on their inputs (:func:`parts_alone`); their sums are printed over the
float32 floor.

    python benchmarks/bench_sequence.py [--states 130] [--short 30] [--repeat 3]
        [--memory 1000] [--alone]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.fft as sfft
import tifffile

from _common import cli_command, machine, run_child, state_displacement
from gridstrain import Lattice
from gridstrain.models import synthetic
from gridstrain.series._stages import SAMPLE_EVERY

SHAPE = (250, 400)


def write_record(path: Path, n: int, seed: int = 0) -> None:
    lattice = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(seed)
    step = state_displacement(1, SHAPE[1])
    with tifffile.TiffWriter(path) as tif:
        for t in range(n):
            disp = (lambda X, Y, t=t: tuple(v * t / 20 for v in step(X, Y))) if t else None
            clean = synthetic.grid_image(SHAPE, lattice, amplitude=2048.0, displacement=disp)
            frame = np.clip(synthetic.add_noise(clean, rng=rng), 0, 4095).astype(np.uint16)
            tif.write(frame, photometric="minisblack", contiguous=False)


def fft_floor(repeat: int = 50, *, least: bool = False) -> float:
    """Best CPU time of a frame's transforms: float64 ``fft2`` + two ``ifft2``, or
    with ``least`` float32 ``rfft2`` + two complex ``ifft2``; one thread."""
    img = np.random.default_rng(0).normal(size=SHAPE)
    if least:
        img = img.astype(np.float32)
    # each wave vector's windowed spectrum, full size (complex64 with least)
    full = sfft.fft2(img, workers=1)
    best = np.inf
    for _ in range(repeat):
        c0 = time.process_time()
        if least:
            sfft.rfft2(img, workers=1)
        else:
            sfft.fft2(img, workers=1)
        sfft.ifft2(full, workers=1)
        sfft.ifft2(full, workers=1)
        best = min(best, time.process_time() - c0)
    return best


def stage_cpu(record: Path, out: Path, n: int) -> dict:
    """CPU seconds per state of each named step of the measurement (in this process):
    the time between a progress message and the one before is its step's."""
    from gridstrain.series import measure_series

    cpu: dict[str, float] = {}
    last = [time.process_time()]

    def progress(fraction, message):
        now = time.process_time()
        name = message.split(": ")[-1].rstrip("0123456789/ ") if ": " in message else message
        cpu[name] = cpu.get(name, 0.0) + now - last[0]
        last[0] = now

    measure_series(None, str(record), reference_frames=1, output=str(out), progress=progress)
    return {k: v / n for k, v in cpu.items()}


def parts_alone(record: Path, out: Path, n: int, *,
                repeat: int = 7) -> list[tuple[str, float, float, float, float]]:
    """The main computations of a state, timed inside the measurement of ``record``
    (``n`` states) and alone: ``(name, calls a state, ms a state inside (median), ms a
    state inside (least), ms a state alone)``.

    Inside: each call's CPU once the first third of its calls have run (at most 40:
    numba's compilations and the reference's first calls are over), its median and
    its least over the record, times its calls a state (the reference's calls
    counted with the states'). Alone: two of its later calls (a third and two thirds
    of the way through the rest) run again ``repeat`` times at once on the same
    arguments, the least taken, times its calls a state: the cost of those two
    states' calls with their inputs warm in the caches and nothing else running. A
    guess field handed over to the kinematics is handed over anew to each run. A part
    the measurement does not call through the name patched here, or calls too few
    times to be timed, is an error, not a row left out.
    """
    from gridstrain.kinematics import _deformation, tracking
    from gridstrain.results import _file
    from gridstrain.series import _floors, _loop, _passes, _records, measure_series

    parts = (("the frame's pass (read, probe)", _loop, _loop._run_pass),
             ("the carrier's search", _passes, _passes.state_carrier),
             ("transform", _passes, _passes.transform),
             ("coupling correction", _loop, _loop.coupling_corrected),
             ("kinematics", tracking, tracking.deformation),
             ("the summary's median modulus", _records, _records._median_modulus),
             ("local noise", _floors._ReferenceFloor, _floors._ReferenceFloor._local),
             ("uncertainty maps", _floors, _floors.std_from_phase_variance),
             ("store", _file, _file._put_state))
    for _, owner, f in parts:  # each replaced where the measurement looks it up
        if getattr(owner, f.__name__, None) is not f:
            raise RuntimeError(f"{owner.__name__} holds no {f.__name__} of its own to time")
    after = min(40, n // 3)
    picks = (after + (n - after) // 3, after + 2 * (n - after) // 3)
    inside: dict[str, list] = {}
    alone: dict[str, list] = {}
    calls: dict[str, int] = {}

    def timed(name, f):
        def run(*a, **k):
            guess = k.get("guess")
            field = guess.take() if isinstance(guess, _deformation._Handover) else None
            if field is not None:
                k["guess"] = _deformation._Handover(field)
            c0 = time.process_time()
            r = f(*a, **k)
            dt = time.process_time() - c0
            calls[name] = i = calls.get(name, 0) + 1
            if i > after:
                inside.setdefault(name, []).append(dt)
            if i in picks:
                best = np.inf
                for _ in range(repeat):
                    if field is not None:
                        k["guess"] = _deformation._Handover(field)
                    c0 = time.process_time()
                    f(*a, **k)
                    best = min(best, time.process_time() - c0)
                alone.setdefault(name, []).append(best)
            return r
        return run

    saved = []
    try:
        for name, owner, f in parts:
            saved.append((owner, f.__name__, f))
            setattr(owner, f.__name__, timed(name, f))
        measure_series(None, str(record), reference_frames=1, output=str(out))
    finally:
        for owner, attr, f in saved:
            setattr(owner, attr, f)
    rows = []
    for name, _, _ in parts:
        if len(alone.get(name, ())) < len(picks):
            raise RuntimeError(f"{name}: called {calls.get(name, 0)} times over {n} states, "
                               f"too few to be timed (its calls {picks} re-run alone)")
        per = calls[name] / n
        rows.append((name, per, float(np.median(inside[name])) * per,
                     min(inside[name]) * per, min(alone[name]) * per))
    return rows


def run(cli, record: Path, out: Path, *, peak: bool = False) -> dict:
    return run_child([*cli, "measure", str(record), "--reference-frames", "1", "-o",
                      str(out), "--quiet", "--overwrite"], peak=peak)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=130)
    ap.add_argument("--short", type=int, default=30)
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs of each record, interleaved; the least CPU time is taken")
    ap.add_argument("--alone", action="store_true",
                    help="also the main computations of a state timed alone, against "
                    "their time inside the measurement (parts_alone)")
    ap.add_argument("--memory", type=int, default=0,
                    help="also the peak memory of a record of this many states against "
                    "--states (e.g. 1000)")
    args = ap.parse_args()
    if min(args.short, args.states) <= 2 * SAMPLE_EVERY or args.short >= args.states:
        ap.error(f"--short and --states must exceed {2 * SAMPLE_EVERY} (a long record, "
                 "its checks sampled) and --states the larger")
    print(machine())
    cli = cli_command()
    floor = fft_floor()
    least = fft_floor(least=True)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        runs = {}
        write_record(d / "warm.tif", 3)
        run(cli, d / "warm.tif", d / "warm.h5")  # numba's first compilation, caches
        sizes = sorted({args.short, args.states, args.memory} - {0})
        for n in sizes:
            write_record(d / f"rec{n}.tif", n + 1)
        for rep in range(max(args.repeat, 1)):
            for n in sizes:
                if n == args.memory and rep:  # the long record's memory: once
                    continue
                r = run(cli, d / f"rec{n}.tif", d / f"out{n}.h5", peak=True)
                best = runs.setdefault(n, r)
                runs[n] = {"cpu": min(best["cpu"], r["cpu"]), "wall": min(best["wall"], r["wall"]),
                           "peak": max(best["peak"], r["peak"])}
        for n in sizes:
            print(f"{n:5d} states: CPU {runs[n]['cpu']:.2f} s, wall {runs[n]['wall']:.2f} s "
                  f"(least of {1 if n == args.memory else args.repeat}), "
                  f"peak {runs[n]['peak'] / 2**20:.0f} MiB")
        stages = stage_cpu(d / f"rec{args.states}.tif", d / "stages.h5", args.states)
        parts = parts_alone(d / f"rec{args.states}.tif", d / "alone.h5", args.states) \
            if args.alone else []
    per = (runs[args.states]["cpu"] - runs[args.short]["cpu"]) / (args.states - args.short)
    print(f"CPU per one-frame state of {SHAPE[0]} x {SHAPE[1]} px: {per * 1e3:.1f} ms; "
          f"FFT floor of a frame (float32 rfft2 + 2 ifft2): {least * 1e3:.2f} ms, ratio "
          f"{per / least:.1f} (target 20); in float64 (fft2 + 2 ifft2, earlier rounds' "
          f"figure): {floor * 1e3:.2f} ms, ratio {per / floor:.1f}")
    print(f"CPU per state by stage, ms (in process, {args.states} states; the pass's "
          "steps included):")
    for name, t in sorted(stages.items(), key=lambda kv: -kv[1]):
        if t * 1e3 >= 0.05:
            print(f"  {name:<24} {t * 1e3:7.1f}")
    if parts:
        print("the main computations of a state, ms a state: inside the measurement (the "
              "median and the least of its states), and alone (two states' calls re-run "
              "at once on their inputs, the least of 7)")
        print(f"  {'':<30} {'calls':>5} {'median':>7} {'least':>7} {'alone':>7}")
        for name, calls, t_med, t_least, t_alone in parts:
            print(f"  {name:<30} {calls:5.2f} {t_med * 1e3:7.2f} {t_least * 1e3:7.2f} "
                  f"{t_alone * 1e3:7.2f}")
        sums = [sum(p[k] for p in parts) for k in (2, 3, 4)]
        print(f"  {'together':<30} {'':5} " + " ".join(f"{t * 1e3:7.2f}" for t in sums))
        print("  over the float32 floor:" + " " * 14
              + " ".join(f"{t / least:7.1f}" for t in sums))
    if args.memory:
        a, b = runs[args.states]["peak"], runs[args.memory]["peak"]
        print(f"peak memory {args.memory} states / {args.states} states: {b / a:.3f} "
              "(target within 10 %)")


if __name__ == "__main__":
    main()
