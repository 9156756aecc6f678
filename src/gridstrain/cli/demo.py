"""``gridstrain demo``: a realistic test, simulated end to end, then measured.

An aluminium plate with a hole (:mod:`gridstrain.models.kirsch`, E = 70 GPa, nu = 0.33)
carrying a grid of pitch 5 px is imaged by a 12-bit camera that stores its data
x16 in 16-bit TIFFs (the paper's Fig. 1), with Poisson-Gaussian sensor noise
(K = 0.28, L = 5 in 12-bit levels; paper §3.2) and vibrations (i.i.d. Gaussian
rigid shifts of every frame, the paper's case 3 by default). ``T`` frames of the
unloaded reference and ``T`` of the loaded state are written as TIFF series, with
the specimen mask, then measured exactly as ``gridstrain measure`` would, and the
maps are compared with the analytic truth.
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
from ..io import OutputDirectory, open_series, read_mask, write_hdf5, write_tiff_series
from ..models import kirsch, synthetic
from ..phase import Lattice
from ..post import figure_names, save_figures, write_report
from ..results import MAP_FIELDS, save_result
from ..series import measure_series
from ._summary import jsonable, report_lines, summary
from .measure import config_text

# The simulated camera and specimen (paper §3.2 and README of the paper notes).
_AMPLITUDE = 2400.0  # mean grey level of the grid, 12-bit levels: peaks at 3480 + black
_CONTRAST = 0.9
_BLACK_LEVEL = 100.0  # the camera's offset, 12-bit levels (the hole shows it)
_K, _L = 0.28, 5.0  # Poisson-Gaussian noise, Var = K l + L in 12-bit levels
_BITS, _STORE_SCALE = 12, 16
_PIXEL_SIZE, _UNIT = 0.04, "mm"  # 40 um per pixel on the specimen
_FRAME_DIGITS = 6
# A grid bonded by hand is never square to the sensor: turned by 0.8 degree, the
# harmonics that an integer pitch folds onto the carriers land beside them, where the
# reference image shows how strong they are (docs: metrology, harmonic aliasing)
_GRID_ANGLE = 0.8


def register(sub) -> None:
    p = sub.add_parser(
        "demo", help="simulate a plate with a hole in tension and measure it",
        description="Simulate a tensile test on an aluminium plate with a hole (analytic "
        "Kirsch field) imaged by a noisy, vibrating 12-bit camera; write the image series "
        "and the mask as TIFFs, measure them like 'gridstrain measure', and compare the "
        "maps with the truth.")
    p.add_argument("--out", default="gridstrain-demo", metavar="DIR",
                   help="output directory (default: ./gridstrain-demo)")
    p.add_argument("--size", type=int, default=384, metavar="PX",
                   help="image side, px (default 384)")
    p.add_argument("--pitch", type=float, default=5.0, metavar="PX",
                   help="grid pitch, px (default 5)")
    p.add_argument("--frames", type=int, default=10, metavar="T",
                   help="frames per state (default 10)")
    p.add_argument("--radius", type=float, default=60.0, metavar="PX",
                   help="hole radius, px (default 60)")
    p.add_argument("--stress", type=float, default=100.0, metavar="MPA",
                   help="remote tensile stress along x, MPa (default 100)")
    p.add_argument("--vibration", type=float, default=0.01, metavar="PX",
                   help="std of the per-frame rigid shifts along x and y, px (default "
                   "0.01, the paper's case 3)")
    p.add_argument("--translation", type=float, nargs=2, default=(3.2, -1.4),
                   metavar=("UX", "UY"),
                   help="rigid translation of the loaded specimen, px (default 3.2 -1.4)")
    p.add_argument("--method", type=str.upper, choices=("A", "B", "C"), default="A",
                   help="averaging method (default A)")
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
    check_int(args.frames, "--frames", minimum=1)
    if not 0 < args.radius <= args.size / 4:
        raise ValueError(f"--radius must be in (0, size/4 = {args.size / 4:g}] px, got "
                         f"{args.radius:g}")
    if not math.isfinite(args.stress) or abs(args.stress) > 250:
        raise ValueError(f"--stress must be within +-250 MPa (aluminium stays elastic at "
                         f"3 x 250 MPa only for the strongest alloys), got {args.stress:g}")
    if not (math.isfinite(args.vibration) and 0 <= args.vibration <= 0.5):
        raise ValueError(f"--vibration must be in [0, 0.5] px, got {args.vibration:g}")
    if not all(math.isfinite(v) and abs(v) <= 20 for v in args.translation):
        raise ValueError(f"--translation must be within +-20 px, got {args.translation}")


def _frame_name(k: int) -> str:
    return f"frame{k:0{_FRAME_DIGITS}d}.tif"


def _prepare(out: Path, frames: int, overwrite: bool) -> OutputDirectory:
    """Check ``out``: only the files of an earlier demo are replaced, with ``overwrite``.

    The frame folders must hold the demo's frames only (anything else there would
    join the series measured); the figures folder keeps its own list.
    """
    names = [f"{sub}/{_frame_name(k)}" for sub in ("ref", "load") for k in range(frames)]
    names += ["mask.tif", "maps.h5", "truth.h5", "report.html"]
    directory = OutputDirectory(out, names, overwrite=overwrite, exclusive=("ref", "load"),
                                what="demo directory")
    if (out / "figures").exists():
        OutputDirectory(out / "figures", figure_names(1), overwrite=overwrite,
                        what="figures directory")
    return directory


def run(args) -> int:
    _check(args)
    t0 = time.perf_counter()
    out = Path(args.out).expanduser()
    directory = _prepare(out, args.frames, args.overwrite)
    progress = bar(quiet=args.quiet)
    centre = ((args.size - 1) / 2, (args.size - 1) / 2)
    elastic = {"radius": float(args.radius), "remote_stress": float(args.stress),
               "centre": centre}
    shifts = _simulate(args, out, directory, elastic, progress)
    t1 = time.perf_counter()
    result, maps, figs, report = _measure(out, args.method, directory, progress)
    t2 = time.perf_counter()
    truth = _write_truth(args, out, directory, elastic, shifts)
    errors, shift_err = _errors(result, truth, shifts)
    demo = shlex.quote(str(out))
    command = (f"gridstrain measure {demo}/ref {demo}/load -o maps.h5 --mask {demo}/mask.tif "
               f"--pixel-size {_PIXEL_SIZE:g} --unit {_UNIT} --figures figs")
    seconds = {"simulate": t1 - t0, "measure_and_write": t2 - t1,
               "total": time.perf_counter() - t0}
    if args.json:
        s = summary(result, outputs={"hdf5": str(maps), "figures": [str(f) for f in figs],
                                     "report": str(report)},
                    seconds=seconds["total"], pixel_size=_PIXEL_SIZE, unit=_UNIT)
        s["demo"] = {"directory": str(out), "rms_error": errors,
                     "shift_rms_error_px": {"reference": shift_err[0],
                                            "loaded": shift_err[1]},
                     "seconds": seconds, "measure_command": command,
                     "truth": str(out / "truth.h5")}
        json.dump(jsonable(s), sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
        return 0
    if args.quiet:
        return 0
    print("\n".join([
        *_report(args, out, result, errors, shift_err),
        f"wrote {maps}, the report {report} (open it in a browser) and {len(figs)} "
        f"figures in {out / 'figures'}; {seconds['total']:.1f} s in all",
        "",
        "measure the same series yourself:",
        f"  {command}",
    ]))
    return 0


def _simulate(args, out: Path, directory: OutputDirectory, elastic: dict, progress) -> dict:
    """Write the reference and loaded frame series and the mask; return the true
    rigid shift of every frame, ``{"reference": (T, 2), "loaded": (T, 2)}``, px."""
    rng = np.random.default_rng(args.seed)
    n, T, a = args.size, args.frames, float(args.radius)
    centre = elastic["centre"]
    lat = Lattice.from_pitch(args.pitch, angle=_GRID_ANGLE)
    tx, ty = (float(v) for v in args.translation)

    def specimen(X, Y):
        # reflectance of the specimen: the grid, or the dark hole (camera black level)
        return ((X - centre[0]) ** 2 + (Y - centre[1]) ** 2 >= a * a).astype(float)

    def loaded(X, Y):
        ux, uy = kirsch.displacement(X, Y, inside="extend", **elastic)
        return ux + tx, uy + ty

    shifts = {}

    def frames(state: str, field, k0: int):
        true = []
        for t in range(T):
            alpha = rng.normal(0.0, args.vibration, 2)  # frame = s(x + alpha), eq. (2)
            true.append(alpha)

            def disp(X, Y, alpha=alpha):
                ux, uy = field(X, Y) if field is not None else (0 * X, 0 * Y)
                return ux - alpha[0], uy - alpha[1]

            img = synthetic.grid_image((n, n), lat, amplitude=_AMPLITUDE,
                                       contrast=_CONTRAST, displacement=disp,
                                       reflectance=specimen) + _BLACK_LEVEL
            noisy = synthetic.add_noise(img, K=_K, L=_L, rng=rng, bits=_BITS, clip=True)
            progress((k0 + t + 1) / (2 * T) * 0.4, f"simulating the {state} frames")
            yield (noisy * _STORE_SCALE).astype(np.uint16)
        shifts[state] = np.array(true)

    progress(0.0, "simulating the reference frames")
    directory.prepare()
    directory.record(*write_tiff_series(out / "ref", frames("reference", None, 0),
                                        digits=_FRAME_DIGITS))
    directory.record(*write_tiff_series(out / "load", frames("loaded", loaded, T),
                                        digits=_FRAME_DIGITS))
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
    # the specimen in the reference image, one pixel clear of the hole's edge
    mask = (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 > (a + 1) ** 2
    directory.write("mask.tif", lambda fh: tifffile.imwrite(
        fh, (mask * 255).astype(np.uint8), photometric="minisblack"))
    return shifts


def _measure(out: Path, method: str, directory: OutputDirectory, progress):
    """Measure the written series as ``gridstrain measure`` would; write the result,
    the figures and the report. Returns ``(result, maps file, figures, report)``."""
    ref = open_series(out / "ref", name="reference")
    load = open_series(out / "load", name="load")
    m = read_mask(out / "mask.tif", ref.shape)

    def measuring(f, msg):
        progress(0.4 + 0.5 * f, msg)

    result = measure_series(ref, [load], method=method, mask=m, progress=measuring)
    # the measurement's configuration, so that 'gridstrain measure --config maps.h5'
    # replays it like any result of 'gridstrain measure'
    config = config_text({"reference": str((out / "ref").resolve()),
                          "states": [str((out / "load").resolve())],
                          "mask": str((out / "mask.tif").resolve()),
                          "method": method, "pixel-size": _PIXEL_SIZE, "unit": _UNIT})
    maps = save_result(result, out / "maps.h5", pixel_size=_PIXEL_SIZE, unit=_UNIT,
                       attrs={"mask_file": str(out / "mask.tif"), "demo": "gridstrain demo",
                              "config": config})
    directory.record(maps)
    figs = save_figures(result, out / "figures", pixel_size=_PIXEL_SIZE, unit=_UNIT,
                        overwrite=True,
                        progress=lambda f, msg: progress(0.9 + 0.1 * f, msg))
    report = write_report(maps, out / "report.html")
    directory.record(report)
    return result, maps, figs, report


def _write_truth(args, out: Path, directory: OutputDirectory, elastic: dict,
                 shifts: dict) -> dict:
    """The analytic maps at the reference pixels (Lagrangian, conventions), written
    with the true frame shifts to ``truth.h5``; returns the maps by name."""
    n = args.size
    tx, ty = (float(v) for v in args.translation)
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
    ux, uy = kirsch.displacement(xx, yy, **elastic)
    truth = {"ux": ux + tx, "uy": uy + ty}
    truth.update(zip(("exx", "eyy", "exy"), kirsch.strain(xx, yy, **elastic), strict=True))
    write_hdf5(out / "truth.h5", {**{k: v[None] for k, v in truth.items()},
                                  "shifts_reference": shifts["reference"],
                                  "shifts_loaded": shifts["loaded"]},
               {"model": "Kirsch plate with a hole, plane stress",
                "radius_px": elastic["radius"], "centre_px": list(elastic["centre"]),
                "remote_stress_MPa": float(args.stress),
                "youngs_modulus_MPa": kirsch.ALUMINIUM_YOUNGS_MODULUS,
                "poisson_ratio": kirsch.ALUMINIUM_POISSON_RATIO,
                "translation_px": [tx, ty], "vibration_std_px": args.vibration,
                "shifts": "frame t is s(x + alpha_t, y + beta_t)"},
               units={"ux": "px", "uy": "px", "exx": "1", "eyy": "1", "exy": "1",
                      "shifts_reference": "px", "shifts_loaded": "px"})
    directory.record(out / "truth.h5")
    return truth


def _errors(result, truth: dict, shifts: dict) -> tuple[dict, list[float]]:
    """RMS error of every map over the valid pixels (and of the displacements about
    their mean), and of the measured frame shifts of each series, px."""
    v = result.valid[0]
    errors = {}
    for name in MAP_FIELDS:
        d = result.get_map(name)[0][v] - truth[name][v]
        errors[name] = math.sqrt(float(np.mean(d**2)))
        if name in ("ux", "uy"):
            errors[f"{name}_about_mean"] = float(np.std(d))
    shift_err = []
    for vib, key in zip(result.vibration, ("reference", "loaded"), strict=True):
        true = shifts[key] - shifts[key].mean(axis=0)
        shift_err.append(math.sqrt(float(np.mean((vib.shifts - true) ** 2))))
    return errors, shift_err


def _report(args, out: Path, result, errors: dict, shift_err: list) -> list[str]:
    """What was simulated, the measurement's report, and its errors against the truth."""
    nf = result.noise
    n, T, a = args.size, args.frames, float(args.radius)
    return [
        f"gridstrain demo: aluminium plate (E = 70 GPa, nu = 0.33) with a hole of radius "
        f"{a:g} px in tension, {args.stress:g} MPa along x",
        f"camera: {n} x {n} px, grid pitch {args.pitch:g} px, 12-bit noise K = {_K:g}, "
        f"L = {_L:g} stored x16, vibrations {args.vibration:g} px std, {T} frames per state",
        f"wrote {T} + {T} frames to {out / 'ref'} and {out / 'load'}, the mask "
        f"{out / 'mask.tif'}, the truth {out / 'truth.h5'}",
        "",
        *report_lines(result, pixel_size=_PIXEL_SIZE, unit=_UNIT),
        "",
        "RMS error against the analytic field (valid pixels, the hole masked):",
        f"  u_x {errors['ux']:.2e} px, u_y {errors['uy']:.2e} px (about their mean: "
        f"{errors['ux_about_mean']:.2e}, {errors['uy_about_mean']:.2e} px)",
        f"  e_xx {errors['exx']:.2e}, e_yy {errors['eyy']:.2e}, e_xy {errors['exy']:.2e} "
        f"(predicted noise floor {nf.theory_strain[0][0]:.2e}, {nf.theory_strain[0][1]:.2e}, "
        f"{nf.theory_strain[0][2]:.2e})",
        f"  per-frame shifts: RMS error {shift_err[0]:.1e} px (reference), "
        f"{shift_err[1]:.1e} px (loaded)",
    ]
