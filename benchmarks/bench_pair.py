"""One image pair end to end through the command line, against OpenLSA when installed.

Run from the repository root::

    PYTHONPATH=src python benchmarks/bench_pair.py [--size 1040x1376] [--repeat 3]

A real-size pair is written as two 16-bit TIFF files: a rotated checkerboard (pitch
6 px, 12 degrees, square profile) with printing/reflectance defects, 12-bit
Poisson-Gaussian noise, deformed by a rigid translation of about 11 px plus a
homogeneous strain (exx = 2e-3, eyy = -3e-3, exy = 0.5e-3). Each candidate runs in a
fresh interpreter, in turn ``--repeat`` times, and is timed by the CPU time of that
child process (``resource.getrusage(RUSAGE_CHILDREN)``: user + system, imports,
reading and writing included), the figure to trust on a machine shared with other
work; the wall time is printed beside it. Two cases, each with its ratio: *tuned*,
the displacement given (see below) and the FFT and BLAS libraries asked for one thread
(``OMP_NUM_THREADS=1`` and the like) so that CPU time is work, not spinning; and
*defaults*, gridstrain with no guess (the lattice detected, the fringe order found by
itself) and the threads a user gets (``--tuned-only`` leaves it out).

* ``gridstrain``: ``python -m gridstrain.cli measure REF DEF -o out.h5 --quiet``, the
  lattice detected, the fringe order from the cross-correlation, the
  large-displacement correction on;
* ``openlsa``: OpenLSA (Grédiac, Blaysat & Sur's localized spectrum analysis; GPL,
  never a gridstrain dependency: install it yourself, in its own environment since it
  pins numpy < 2, and pass ``--openlsa-python olsa/bin/python``),
  following its README: lattice from the reference, phases of both images with the
  Gaussian kernel of standard deviation the pitch, temporal unwrapping, fixed-point
  displacement (``min_iter=6``). Its automatic pairing follows the brightest
  blurred point; on this pair it chose one near the border and paired it a period
  away (279 px RMS error), so it is given the point to follow (the centre of the
  brighter defect) and where that point went (from the imposed field). In the
  *tuned* case gridstrain is told the same (``--guess``, the displacement there), so
  that both do the same work; it does not need it: in the *defaults* case its
  fringe order comes from the images, from the content below the grid's frequency
  and the grid's modulus (the defects are reflectance blobs broader than the pitch,
  which the correlation at the pitch cannot see), and the answer is the same
  (3.35e-3 px RMS at full size), not confirmed: a lamp's hot spot moved with the
  specimen would read the same (``--auto`` drops the guess from the tuned case too);
* ``start-up``: ``gridstrain --help`` against ``python -c "import numpy"``.

``--stages`` adds one more run of each case with each part's CPU time taken inside
the process (``time.process_time``, all threads), the process set up as the command
sets up its own (BLAS, huge pages, malloc): the imports, the series pass (reading,
screening, transforms), the coupling correction, the noise floor, the window, the
states' carriers, the aliasing bound, and every stage of
:data:`gridstrain.series._stages.STAGES` by name; what is left is the rest
(arguments, the file's opening and closing, the findings).

Each run's displacement is compared with the imposed field (RMS over the pixels
both declare valid, 5 sigma away from the borders), so that the speed is that of a
right answer.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile

from _common import machine
from gridstrain import Lattice
from gridstrain.models import synthetic

ROOT = Path(__file__).resolve().parents[1]
PITCH, ANGLE = 6.0, 12.0
SHIFT = (8.0, -7.5)  # px, |u| = 11 px
STRAIN = (2e-3, -3e-3, 0.5e-3)
# centre of the brighter reflectance defect, as fractions of (width, height)
FEATURE = (0.25, 0.4)
ONE_THREAD = dict.fromkeys(("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                            "NUMEXPR_NUM_THREADS"), "1")

# OpenLSA 0.9.88 pins numpy < 2. Under numpy 2 its input asserts reject complex
# arrays (they compare dtypes with np.complexfloating), so it runs under python -O
# (asserts are its input checks only), and its phase module's one test
# ``dtype == np.complexfloating`` gets numpy 1's meaning back (true for complex128).
OPENLSA_SCRIPT = """
import sys, types, numpy as np, tifffile
from openlsa import OpenLSA
import openlsa.phase
shim = types.ModuleType("numpy")
shim.__dict__.update(np.__dict__)
shim.complexfloating = np.dtype(np.complex128)
openlsa.phase.np = shim
img_0 = tifffile.imread(sys.argv[1]).astype(float)
img_t = tifffile.imread(sys.argv[2]).astype(float)
lsa = OpenLSA(img_0, verbose=False, display=False)
kernel = lsa.compute_kernel(std=lsa.pitch().max())
phi_0, _ = lsa.compute_phases_mod(img_0, kernel)
phi_t, _ = lsa.compute_phases_mod(img_t, kernel)
# the point followed, (row, col), and where it went: given, see the module's notes
p1 = np.array([int(sys.argv[4]), int(sys.argv[5])])
p2 = np.array([float(sys.argv[6]), float(sys.argv[7])])
phi_t, _ = lsa.temporal_unwrap(img_0, img_t, phi_0, phi_t, point1=p1, point2=p2)
u_xy = lsa.compute_displacement(phi_0, phi_t, min_iter=6)
# real part along x (columns), imaginary part along y (rows): checked against the
# imposed field (its README states the opposite)
np.save(sys.argv[3], np.stack([u_xy.real, u_xy.imag]))
"""

# the command with each part timed inside the process (see --stages); the
# private modules are the benchmark's business, the package never imports them so
STAGES_SCRIPT = """
import dataclasses, json, resource, sys, time
t0 = time.process_time()
import gridstrain.cli
# what the command sets in its own process before numpy loads (without it, huge pages
# and a heap given back to the system cost the parts up to half a second of system
# time that the timed command does not spend)
gridstrain.cli._own_process()
from gridstrain.series import _floors, _loop, _stages
import gridstrain.cli.measure
from gridstrain.cli import main
cpu = {"imports": time.process_time() - t0}

def timed(name, fn):
    def run(*args, **kwargs):
        t = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            cpu[name] = cpu.get(name, 0.0) + time.process_time() - t
    return run

_stages.STAGES = tuple(dataclasses.replace(s, run=timed("stage " + s.name, s.run))
                       for s in _stages.STAGES)
_loop._one_series = timed("series pass", _loop._one_series)
_floors._Noise.complete = timed("noise floor", _floors._Noise.complete)
_loop._window = timed("window", _loop._window)
_loop._carriers = timed("carriers", _loop._carriers)
_loop.aliasing_bias = timed("aliasing bound", _loop.aliasing_bias)
_loop.coupling_corrected = timed("coupling correction", _loop.coupling_corrected)
main(sys.argv[2:])
ru = resource.getrusage(resource.RUSAGE_SELF)
cpu["total"] = ru.ru_utime + ru.ru_stime
with open(sys.argv[1], "w") as f:
    json.dump(cpu, f)
"""


def field(shape):
    """The imposed Lagrangian displacement ``(u_x, u_y)`` as a function of ``(X, Y)``."""
    H, W = shape
    cx, cy = (W - 1) / 2, (H - 1) / 2
    exx, eyy, exy = STRAIN

    def U(X, Y):
        return (SHIFT[0] + exx * (X - cx) + exy * (Y - cy),
                SHIFT[1] + exy * (X - cx) + eyy * (Y - cy))

    return U


def write_pair(folder: Path, shape) -> None:
    lat = Lattice.from_pitch(PITCH, angle=ANGLE)
    H, W = shape

    def R(X, Y):  # printing and reflectance defects, attached to the specimen
        fx, fy = FEATURE
        return (1 + 0.1 * np.exp(-((X - fx * W) ** 2 + (Y - fy * H) ** 2) / (2 * 60**2))
                - 0.08 * np.exp(-((X - 0.65 * W) ** 2 + (Y - 0.6 * H) ** 2) / (2 * 40**2)))

    kw = {"kind": "checkerboard", "profile": "square", "reflectance": R, "oversample": 3,
          "amplitude": 2000.0}
    rng = np.random.default_rng(2015)
    for name, disp in (("ref", None), ("def", field(shape))):
        img = synthetic.grid_image(shape, lat, displacement=disp, **kw)
        img = synthetic.add_noise(img, rng=rng)
        tifffile.imwrite(folder / f"{name}.tif", np.clip(np.rint(img), 0, 4095).astype(np.uint16))


def run_child(cmd, env) -> tuple[float, float, float]:
    """CPU time (user + system), wall time and user time of one child process, s."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    user = after.ru_utime - before.ru_utime
    cpu = user + (after.ru_stime - before.ru_stime)
    return cpu, wall, user


def rms_error(u, shape, valid) -> float:
    H, W = shape
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    truth = np.array(field(shape)(xx, yy))
    border = math.ceil(5 * PITCH)
    inner = np.zeros(shape, bool)
    inner[border:-border, border:-border] = True
    ok = valid & inner & np.all(np.isfinite(u), axis=0)
    return float(np.sqrt(np.mean((u[:, ok] - truth[:, ok]) ** 2)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="1040x1376", help="image size HxW (default 1040x1376)")
    ap.add_argument("--repeat", type=int, default=3, help="interleaved runs of each candidate")
    ap.add_argument("--baseline", metavar="SRC",
                    help="also run gridstrain from this source folder (another checkout's "
                         "src/), interleaved with this one")
    ap.add_argument("--auto", action="store_true",
                    help="let gridstrain fix the fringe order by itself in the tuned case "
                         "too (from the defects' content below the grid's frequency)")
    ap.add_argument("--openlsa-python", metavar="PYTHON",
                    help="the interpreter of a virtual environment holding OpenLSA (it pins "
                         "numpy < 2: keep it out of gridstrain's environment, e.g. "
                         "python -m venv olsa && olsa/bin/pip install openlsa tifffile)")
    ap.add_argument("--tuned-only", dest="both", action="store_false",
                    help="only the tuned case (the displacement given, one thread), not "
                         "also the defaults case (the fringe order found by gridstrain, "
                         "threads as a user gets them)")
    ap.add_argument("--stages", action="store_true",
                    help="also time the tuned case's parts inside one run (imports, series "
                         "pass, noise floor, each stage)")
    args = ap.parse_args(argv)
    shape = tuple(int(v) for v in args.size.lower().split("x"))

    print(f"machine: {machine()}")
    print(f"pair {shape[0]}x{shape[1]}, checkerboard pitch {PITCH:g} px at {ANGLE:g} deg, "
          f"u = {SHIFT} px + strain {STRAIN}; best of {args.repeat} interleaved runs, each "
          "in a fresh interpreter")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_pair(tmp, shape)
        # both programs are told where the defect went (see the module's notes)
        row, col = round(FEATURE[1] * shape[0]), round(FEATURE[0] * shape[1])
        ux, uy = field(shape)(float(col), float(row))
        guess = ["--guess", f"{ux:.3f}", f"{uy:.3f}"]
        cases = {"tuned": ([] if args.auto else guess, True),
                 "defaults": ([], False)}
        if not args.both:
            cases = {"tuned": cases["tuned"]}
        ratios = {}
        for case, (given, one_thread) in cases.items():
            print(f"\n{case}: " + ("the displacement given, one thread" if given else
                                   "the fringe order by gridstrain")
                  + ("" if one_thread else "; threads as a user gets them"))
            ratios[case] = _case(args, shape, tmp, case, given, one_thread,
                                 (row, col, row + uy, col + ux))
        if args.stages:
            for case, (given, one_thread) in cases.items():
                _stages(tmp, case, given, one_thread)
        if len(ratios) > 1 and all(r is not None for r in ratios.values()):
            print("\nCPU time ratio openlsa / gridstrain: "
                  + ", ".join(f"{c} {r:.2f}" for c, r in ratios.items()))


def _case(args, shape, tmp, case, given, one_thread, point):
    """Time one case's candidates; the CPU time ratio openlsa / gridstrain, or None."""
    olsa_python = args.openlsa_python or sys.executable
    have_openlsa = subprocess.run([olsa_python, "-c", "import openlsa"],
                                  capture_output=True).returncode == 0
    env = dict(os.environ, **ONE_THREAD) if one_thread else dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")])
    # the checkout's modules compiled once, as pip compiles an installed package's (and
    # OpenLSA's): with PYTHONDONTWRITEBYTECODE set, every run would compile them again
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "src")], env=env,
                   check=True, stdout=subprocess.DEVNULL)
    ref, cur = str(tmp / "ref.tif"), str(tmp / "def.tif")
    out = tmp / f"{case}.h5"
    cands = {}
    if one_thread:
        cands["python -c 'import numpy'"] = [sys.executable, "-c", "import numpy"]
        cands["gridstrain --help"] = [sys.executable, "-m", "gridstrain.cli", "--help"]
    cands["gridstrain measure"] = [sys.executable, "-m", "gridstrain.cli", "measure", ref,
                                   cur, "-o", str(out), "--quiet", "--overwrite", *given]
    if args.baseline:
        cands["gridstrain measure (baseline)"] = [
            sys.executable, "-c",
            f"import sys; sys.path.insert(0, {args.baseline!r}); "
            "from gridstrain.cli import main; sys.exit(main())",
            "measure", ref, cur, "-o", str(tmp / "base.h5"), "--quiet", "--overwrite",
            *given]
    if have_openlsa:
        cands["openlsa"] = [olsa_python, "-O", "-c", OPENLSA_SCRIPT, ref, cur,
                            str(tmp / "olsa.npy"), *(str(v) for v in point)]
    cpu = {n: [] for n in cands}
    wall = {n: [] for n in cands}
    user = {n: [] for n in cands}
    for _ in range(args.repeat):
        for name, cmd in cands.items():
            c, w, u = run_child(cmd, env)
            cpu[name].append(c)
            wall[name].append(w)
            user[name].append(u)
    best = {n: min(v) for n, v in cpu.items()}
    # the system time (page faults) of one program varies by a fifth and more from
    # run to run on a virtual machine: the user time is printed beside the total
    print(f"{'candidate':<28} {'CPU s':>8} {'user s':>8} {'wall s':>8}")
    for name in cands:
        print(f"{name:<28} {best[name]:>8.2f} {min(user[name]):>8.2f} "
              f"{min(wall[name]):>8.2f}")
    if one_thread:
        print(f"start-up: gridstrain --help takes {best['gridstrain --help']:.2f} s CPU, "
              f"{best['gridstrain --help'] - best[next(iter(cands))]:+.2f} s beyond "
              "importing numpy")

    import h5py

    with h5py.File(out, "r") as f:
        u_ours, valid = _read_ours(f)
    print(f"gridstrain: u RMS error {rms_error(u_ours, shape, valid):.2e} px")
    ratio = None
    if have_openlsa:
        u_olsa = np.load(tmp / "olsa.npy")
        print(f"openlsa:    u RMS error {rms_error(u_olsa, shape, valid):.2e} px (over "
              "gridstrain's valid pixels)")
        ratio = best["openlsa"] / best["gridstrain measure"]
        users = min(user["openlsa"]) / min(user["gridstrain measure"])
        print(f"CPU time ratio openlsa / gridstrain: {ratio:.2f} (user time alone: "
              f"{users:.2f})")
    else:
        print("openlsa: not installed (pip install openlsa; GPL, benchmark only)")
    print(json.dumps({n: round(v, 3) for n, v in best.items()}))
    print(f"load average after the case: {os.getloadavg()[0]:.1f}")
    return ratio


def _stages(tmp, case, given, one_thread) -> None:
    """Print the CPU time of each part of one run of a case, timed inside the process."""
    env = dict(os.environ, **ONE_THREAD) if one_thread else dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")])
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")
    out = tmp / "stages.json"
    subprocess.run([sys.executable, "-c", STAGES_SCRIPT, str(out), "measure",
                    str(tmp / "ref.tif"), str(tmp / "def.tif"), "-o", str(tmp / "stages.h5"),
                    "--quiet", "--overwrite", *given], env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    cpu = json.loads(out.read_text())
    total = cpu.pop("total")
    print(f"\n{case}, one run timed by parts (CPU s, all threads):")
    for name, t in cpu.items():
        print(f"  {name:<28} {t:6.2f}")
    print(f"  {'the rest':<28} {total - sum(cpu.values()):6.2f}")
    print(f"  {'total':<28} {total:6.2f}")


def _read_ours(f):
    """Displacement (2, H, W) and validity of the first loaded state in the output file."""
    found = {}

    def visit(name, obj):
        base = name.rsplit("/", 1)[-1]
        if hasattr(obj, "shape") and base in ("ux", "uy", "valid") and base not in found:
            found[base] = obj[...]

    f.visititems(visit)
    u = np.stack([np.squeeze(found["ux"]), np.squeeze(found["uy"])])
    if u.ndim == 4:  # (2, states, H, W)
        u = u[:, 0]
    valid = np.squeeze(found["valid"]).astype(bool) if "valid" in found else np.all(
        np.isfinite(u), axis=0)
    if valid.ndim == 3:
        valid = valid[0]
    return u, valid


if __name__ == "__main__":
    main()
