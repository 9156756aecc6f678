"""``gridstrain demo``: a tensile test, simulated end to end, then measured.

An aluminium coupon (E = 70 GPa, nu = 0.33, cross-section 20 mm² by default) carrying a
grid of pitch 5 px is pulled along x at a constant rate while a 12-bit camera that stores
its data x16 in 16-bit TIFFs (the paper's Fig. 1) takes one image every 2 s: the
unloaded reference and ``--steps`` load steps, one record of numbered frames, with
Poisson-Gaussian sensor noise (K = 0.28, L = 5 in 12-bit levels; paper §3.2, given to
the measurement as the camera's noise model, as a datasheet would give it), a random
rigid shift of each image (vibrations) and a grip slip that grows with the load. The
testing machine writes its own log next to the images, as machines do: a preamble, a
semicolon between columns, a decimal comma, the force in kN and a time column sampled
at 10 Hz, its clock started 0.2 s before the camera's trigger. The record and the log
are then measured as ``gridstrain measure`` would (the log joined to the images by
time), a virtual gauge is read over the whole valid region, Young's modulus and
Poisson's ratio are fitted with their 95 % intervals, the report is written, and
everything is compared with the truth the images were drawn from.
"""

from __future__ import annotations

import json
import math
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import tifffile

from .._progress import bar
from .._validation import check_int
from ..io import LoadsFile, OutputDirectory, open_series, read_mask, write_hdf5, write_tiff_series
from ..models import synthetic
from ..phase import Lattice
from ..post import elastic_constants, gauge, write_report
from ..results import load, save_result
from ..series import measure_series
from ._summary import jsonable, report_lines, summary
from .measure import config_text

# The simulated camera and specimen (paper §3.2 and README of the paper notes).
_AMPLITUDE = 2400.0  # mean grey level of the grid, 12-bit levels: peaks at 3480 + black
_CONTRAST = 0.9
_BLACK_LEVEL = 100.0  # the camera's offset, 12-bit levels (the background shows it)
_K, _L = 0.28, 5.0  # Poisson-Gaussian noise, Var = K l + L in 12-bit levels
_BITS, _STORE_SCALE = 12, 16
# The camera's noise model in the stored levels (x16), as its datasheet or 'gridstrain
# noise' gives it: Var_s = 16^2 (K l + L) with l = l_s / 16. One image per state has
# no temporal variance, and a small image too few pixels to estimate it alone.
_NOISE_MODEL = (_STORE_SCALE * _K, _STORE_SCALE**2 * _L)
_PIXEL_SIZE, _UNIT = 0.04, "mm"  # 40 um per pixel on the specimen
_FRAME_DIGITS = 6
# A grid bonded by hand is never square to the sensor: turned by 0.8 degree, the
# harmonics that an integer pitch folds onto the carriers land beside them, where the
# reference image shows how strong they are (docs: metrology, harmonic aliasing)
_GRID_ANGLE = 0.8
_E_MPA, _NU = 70e3, 0.33  # aluminium
_FRAME_RATE = 0.5  # Hz: an image every 2 s
_LOG_RATE = 10.0  # Hz: the machine's log
_LOG_LEAD = 0.2  # s: the log's clock at the camera's trigger (--loads-offset)
_LOAD_NOISE_KN = 2e-4  # the load cell's noise, kN (0.01 % of 2 kN)
# The coupon spans the rows from this fraction of the height to one less it: its two
# edges in view, the grips out of it.
_EDGE = 0.08


def register(sub) -> None:
    p = sub.add_parser(
        "demo", help="simulate a tensile test with a testing machine's log and measure it",
        description="Simulate a tensile test on an aluminium coupon imaged by a noisy "
        "12-bit camera, one image per load step, with the testing machine's own log "
        "(preamble, semicolons, decimal comma, kN, 10 Hz); write the images, the log and "
        "the mask; measure them like 'gridstrain measure', read a gauge, fit E and nu "
        "with their intervals, write the report, and compare with the truth.")
    p.add_argument("--out", default="gridstrain-demo", metavar="DIR",
                   help="output directory (default: ./gridstrain-demo)")
    p.add_argument("--size", type=int, default=192, metavar="PX",
                   help="image side, px (default 192)")
    p.add_argument("--pitch", type=float, default=5.0, metavar="PX",
                   help="grid pitch, px (default 5)")
    p.add_argument("--steps", type=int, default=6, metavar="N",
                   help="load steps after the reference, one image each (default 6; 3 to "
                   "12)")
    p.add_argument("--stress", type=float, default=150.0, metavar="MPA",
                   help="the stress at the last step, MPa (default 150)")
    p.add_argument("--area", type=float, default=20.0, metavar="MM2",
                   help="the coupon's cross-section, mm2 (default 20: 10 mm x 2 mm)")
    p.add_argument("--vibration", type=float, default=0.01, metavar="PX",
                   help="std of each image's rigid shift along x and y, px (default 0.01, "
                   "the paper's case 3)")
    p.add_argument("--translation", type=float, nargs=2, default=(0.4, -0.1),
                   metavar=("UX", "UY"),
                   help="the grips' slip at the last step, growing with the load, px "
                   "(default 0.4 -0.1)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the files of an earlier demo in DIR (only those: DIR "
                   "lists them in its .gridstrain file)")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no report")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def _check(args) -> None:
    if args.size < 96:
        raise ValueError(f"--size must be at least 96 px, got {args.size}")
    if not 2.5 <= args.pitch <= args.size / 16:
        raise ValueError(f"--pitch must be in [2.5, size/16 = {args.size / 16:g}] px, got "
                         f"{args.pitch:g}")
    check_int(args.steps, "--steps", minimum=3)
    if args.steps > 12:
        raise ValueError(f"--steps must be 3 to 12 (a short demo), got {args.steps}")
    if not (math.isfinite(args.stress) and 0 < args.stress <= 250):
        raise ValueError(f"--stress must be in (0, 250] MPa (aluminium stays elastic up to "
                         f"250 MPa only for the strongest alloys), got {args.stress:g}")
    if not (math.isfinite(args.area) and args.area > 0):
        raise ValueError(f"--area must be a positive cross-section in mm2, got {args.area:g}")
    if not (math.isfinite(args.vibration) and 0 <= args.vibration <= 0.5):
        raise ValueError(f"--vibration must be in [0, 0.5] px, got {args.vibration:g}")
    if not all(math.isfinite(v) and abs(v) <= 1 for v in args.translation):
        raise ValueError(f"--translation must be within +-1 px (a slip of more than a few "
                         f"tenths of a period between images leaves the fringe order "
                         f"unknown), got {args.translation}")


def _frame_name(k: int) -> str:
    return f"frame{k:0{_FRAME_DIGITS}d}.tif"


def _prepare(out: Path, steps: int, overwrite: bool) -> OutputDirectory:
    """Check ``out``: only the files of an earlier demo are replaced, with ``overwrite``.

    The record's folder must hold the demo's frames only (anything else there would
    join the record measured).
    """
    names = [f"record/{_frame_name(k)}" for k in range(steps + 1)]
    names += ["mask.tif", "loads.csv", "maps.h5", "truth.h5", "report.html"]
    return OutputDirectory(out, names, overwrite=overwrite, exclusive=("record",),
                           parents=True, what="demo directory")


def _truth(args) -> dict:
    """The test as simulated: the states' times (s) and their true loads (kN), stresses
    (MPa) and strains; the grips' slip (px)."""
    t = np.arange(1, args.steps + 1) / _FRAME_RATE
    t_end = args.steps / _FRAME_RATE
    stress = args.stress * t / t_end  # a constant rate from the trigger on
    return {"time": t, "t_end": t_end, "stress": stress,
            "load": stress * args.area / 1e3, "exx": stress / _E_MPA,
            "eyy": -_NU * stress / _E_MPA,
            "slip": np.outer(t / t_end, np.asarray(args.translation, dtype=float))}


def run(args) -> int:
    _check(args)
    t0 = time.perf_counter()
    out = Path(args.out).expanduser()
    directory = _prepare(out, args.steps, args.overwrite)
    progress = bar(quiet=args.quiet)
    truth = _truth(args)
    _simulate(args, out, directory, truth, progress)
    t1 = time.perf_counter()
    result, maps = _measure(args, out, directory, progress)
    # the gauge of the maps as stored, which the report and the user's own commands
    # read: the same figures everywhere
    reading = gauge(load(maps), pixel_size=_PIXEL_SIZE, unit=_UNIT)
    constants = elastic_constants(reading, area=args.area)
    progress(0.8, "writing the report")
    report = write_report(maps, out / "report.html", area=args.area)
    directory.record(report)
    progress(1.0, "done")
    t2 = time.perf_counter()
    _write_truth(args, out, directory, truth)
    errors = _errors(result, truth)
    demo = shlex.quote(str(out))
    commands = [
        f"gridstrain measure {demo}/record --reference-frames 1 --frame-rate "
        f"{_FRAME_RATE:g} --loads {demo}/loads.csv --loads-offset {_LOG_LEAD:g} --mask "
        f"{demo}/mask.tif --noise-model {_NOISE_MODEL[0]:g} {_NOISE_MODEL[1]:g} "
        f"--pixel-size {_PIXEL_SIZE:g} --unit {_UNIT} -o maps.h5",
        f"gridstrain modulus maps.h5 --area {args.area:g}",
        f"gridstrain report maps.h5 --area {args.area:g} -o report.html"]
    seconds = {"simulate": t1 - t0, "measure_and_report": t2 - t1,
               "total": time.perf_counter() - t0}
    if args.json:
        s = summary(result, outputs={"hdf5": str(maps), "report": str(report)},
                    seconds=seconds["total"], pixel_size=_PIXEL_SIZE, unit=_UNIT)
        s["demo"] = {"directory": str(out), "loads_file": str(out / "loads.csv"),
                     "rms_error": errors, "seconds": seconds,
                     "elastic_constants": {**constants.to_dict(), "E_true": _E_MPA,
                                           "nu_true": _NU},
                     "gauge": reading.where, "commands": commands,
                     "measure_command": commands[0], "truth": str(out / "truth.h5")}
        json.dump(jsonable(s), sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
        return 0
    if args.quiet:
        return 0
    print("\n".join([
        *_report(args, out, result, errors),
        "",
        reading.table(),
        "",
        f"E  = {constants.E_text()} (true: {_E_MPA / 1e3:g} GPa)",
        f"nu = {constants.nu:.4f}, 95 % interval [{constants.nu_ci[0]:.4f}, "
        f"{constants.nu_ci[1]:.4f}] (true: {_NU:g})",
        f"     {len(constants.states)} states fitted, stress = load / {args.area:g} mm2; "
        f"intervals from the {constants.interval_basis}",
        "",
        f"wrote {maps} and the report {report} (open it in a browser); "
        f"{seconds['total']:.1f} s in all",
        "",
        "do the same yourself:",
        *(f"  {c}" for c in commands),
    ]))
    return 0


def _simulate(args, out: Path, directory: OutputDirectory, truth: dict, progress) -> None:
    """Write the record (the reference, then one image per step), the mask and the
    testing machine's log."""
    rng = np.random.default_rng(args.seed)
    n = args.size
    c = (n - 1) / 2
    lat = Lattice.from_pitch(args.pitch, angle=_GRID_ANGLE)
    top, bottom = _EDGE * n, (1 - _EDGE) * n

    def specimen(X, Y):
        # the coupon's grid between its two edges; the dark background beyond them
        return ((top <= Y) & (bottom > Y)).astype(float)

    strains = [(0.0, 0.0), *zip(truth["exx"], truth["eyy"], strict=True)]
    slips = [(0.0, 0.0), *map(tuple, truth["slip"])]

    def frames():
        for k, ((exx, eyy), (sx, sy)) in enumerate(zip(strains, slips, strict=True)):
            alpha = rng.normal(0.0, args.vibration, 2)  # image = s(x + alpha), eq. (2)

            def disp(X, Y, exx=exx, eyy=eyy, sx=sx, sy=sy, alpha=alpha):
                # homogeneous strain about the image's centre (Lagrangian), the slip
                return exx * (X - c) + sx - alpha[0], eyy * (Y - c) + sy - alpha[1]

            img = synthetic.grid_image((n, n), lat, amplitude=_AMPLITUDE,
                                       contrast=_CONTRAST, displacement=disp,
                                       reflectance=specimen) + _BLACK_LEVEL
            noisy = synthetic.add_noise(img, K=_K, L=_L, rng=rng, bits=_BITS, clip=True)
            progress((k + 1) / (args.steps + 1) * 0.2, "simulating the images")
            yield (noisy * _STORE_SCALE).astype(np.uint16)

    progress(0.0, "simulating the images")
    directory.prepare()
    directory.record(*write_tiff_series(out / "record", frames(), digits=_FRAME_DIGITS))
    yy = np.mgrid[0:n, 0:n][0].astype(np.float64)
    # the coupon in the reference image, one pixel clear of its edges
    mask = (yy >= top + 1) & (yy < bottom - 1)
    directory.write("mask.tif", lambda fh: tifffile.imwrite(
        fh, (mask * 255).astype(np.uint8), photometric="minisblack"))
    directory.write("loads.csv", _machine_log(args, truth, rng).encode("utf-8"))


def _machine_log(args, truth: dict, rng) -> str:
    """The testing machine's export: a preamble, ';' between columns, a decimal comma,
    the force in kN and the crosshead in mm, a row every 0.1 s on the machine's clock,
    which starts :data:`_LOG_LEAD` s before the camera's trigger."""
    t = np.arange(0.0, truth["t_end"] + _LOG_LEAD + 1.0, 1.0 / _LOG_RATE)
    camera_t = t - _LOG_LEAD
    load = np.clip(camera_t / truth["t_end"], 0.0, None) * truth["load"][-1]
    load = load + rng.normal(0.0, _LOAD_NOISE_KN, t.size)
    crosshead = 0.5 * load / truth["load"][-1]  # mm: the grips' travel, for the show
    rows = [f"{a:.2f};{f:.4f};{x:.4f}".replace(".", ",")
            for a, f, x in zip(t, load, crosshead, strict=True)]
    return "\n".join([
        "Zugversuch DIN EN ISO 6892-1",
        "Probe: Aluminium-Flachprobe gridstrain demo",
        f"Querschnitt: {args.area:g} mm2",
        "",
        "Zeit [s];Kraft [kN];Traversenweg [mm]",
        *rows]) + "\n"


def _measure(args, out: Path, directory: OutputDirectory, progress):
    """Measure the record as ``gridstrain measure`` would, its log joined by time;
    write the result. Returns ``(result, maps file)``."""
    record = open_series(out / "record", name="record")
    m = read_mask(out / "mask.tif", record.shape)
    loads = LoadsFile(out / "loads.csv", offset=_LOG_LEAD)

    def measuring(f, msg):
        progress(0.2 + 0.55 * f, msg)

    result = measure_series(None, [record], reference_frames=1, frame_rate=_FRAME_RATE,
                            loads=loads, mask=m, noise_model=_NOISE_MODEL,
                            progress=measuring)
    # the measurement's configuration, so that 'gridstrain measure --config maps.h5'
    # replays it like any result of 'gridstrain measure'
    config = config_text({"reference": str((out / "record").resolve()),
                          "reference-frames": 1, "frame-rate": _FRAME_RATE,
                          "loads": str((out / "loads.csv").resolve()),
                          "loads-offset": _LOG_LEAD,
                          "mask": str((out / "mask.tif").resolve()),
                          "noise-model": list(_NOISE_MODEL),
                          "pixel-size": _PIXEL_SIZE, "unit": _UNIT})
    maps = save_result(result, out / "maps.h5", pixel_size=_PIXEL_SIZE, unit=_UNIT,
                       attrs={"mask_file": str(out / "mask.tif"), "demo": "gridstrain demo",
                              "config": config})
    directory.record(maps)
    return result, maps


def _write_truth(args, out: Path, directory: OutputDirectory, truth: dict) -> None:
    """The test as simulated, written to ``truth.h5``: each state's time, load, stress
    and homogeneous strains, the grips' slip, E and nu."""
    write_hdf5(out / "truth.h5", {k: truth[k] for k in ("time", "load", "stress", "exx",
                                                        "eyy", "slip")},
               {"model": "aluminium coupon in uniaxial tension, homogeneous strain",
                "youngs_modulus_MPa": _E_MPA, "poisson_ratio": _NU,
                "area_mm2": float(args.area), "vibration_std_px": args.vibration,
                "loads_offset_s": _LOG_LEAD, "frame_rate_hz": _FRAME_RATE},
               units={"time": "s", "load": "kN", "stress": "MPa", "exx": "1", "eyy": "1",
                      "slip": "px"})
    directory.record(out / "truth.h5")


def _errors(result, truth: dict) -> dict:
    """The largest over the states of each strain map's RMS error over its valid
    pixels (dimensionless), and of the displacements' about their mean (px: the
    slip and the vibrations are rigid)."""
    H, W = result.shape
    c = (W - 1) / 2
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    errors = dict.fromkeys(("exx", "eyy", "exy", "ux_about_mean", "uy_about_mean"), 0.0)
    for i in range(result.n_states):
        v = np.asarray(result.valid[i])
        true = {"exx": truth["exx"][i], "eyy": truth["eyy"][i], "exy": 0.0,
                "ux_about_mean": truth["exx"][i] * (xx - c),
                "uy_about_mean": truth["eyy"][i] * (yy - c)}
        for name, t in true.items():
            m = np.asarray(result.get_map(name.removesuffix("_about_mean"))[i])
            d = (m - t)[v] if np.ndim(t) else m[v] - t
            if name.endswith("_about_mean"):
                d = d - d.mean()
            errors[name] = max(errors[name], math.sqrt(float(np.mean(d**2))))
    return errors


def _report(args, out: Path, result, errors: dict) -> list[str]:
    """What was simulated, the measurement's report, and its errors against the truth."""
    nf = result.noise
    n = args.size
    floor = np.max(np.asarray(nf.theory_strain, dtype=float), axis=0)
    return [
        f"gridstrain demo: aluminium coupon (E = {_E_MPA / 1e3:g} GPa, nu = {_NU:g}, "
        f"{args.area:g} mm2) pulled along x to {args.stress:g} MPa, an image every "
        f"{1 / _FRAME_RATE:g} s",
        f"camera: {n} x {n} px, grid pitch {args.pitch:g} px, 12-bit noise K = {_K:g}, "
        f"L = {_L:g} stored x16, vibrations {args.vibration:g} px std",
        f"wrote the reference and {args.steps} load steps to {out / 'record'}, the "
        f"testing machine's log {out / 'loads.csv'} (';', decimal comma, kN, "
        f"{_LOG_RATE:g} Hz, started {_LOG_LEAD:g} s before the camera), the mask "
        f"{out / 'mask.tif'}, the truth {out / 'truth.h5'}",
        "",
        *report_lines(result, pixel_size=_PIXEL_SIZE, unit=_UNIT),
        "",
        "RMS error against the truth (valid pixels, worst state):",
        f"  e_xx {errors['exx']:.2e}, e_yy {errors['eyy']:.2e}, e_xy {errors['exy']:.2e} "
        f"(predicted noise floor {floor[0]:.2e}, {floor[1]:.2e}, {floor[2]:.2e})",
        f"  u_x {errors['ux_about_mean']:.2e} px, u_y {errors['uy_about_mean']:.2e} px "
        "about their mean (the slip and the vibrations are rigid)",
    ]
