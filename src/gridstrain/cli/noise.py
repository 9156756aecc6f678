"""``gridstrain noise IMAGES``: camera noise (K, L), vibrations and the predicted noise floor.

A static stack gives the noise from the frames' temporal scatter (vibrations
regressed out); a single image (or a stack too short) from the image itself
(:func:`gridstrain.uncertainty.estimate_noise_image`).
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from .._progress import bar, findings_of
from .._validation import check_int
from ..io import open_series, provenance, write_atomic, write_hdf5
from ..phase import detect_lattice, wft
from ..series import outlier_verdict
from ..stacks.screening import screen_frames
from ..stacks.vibration import vibration_report
from ..uncertainty import NOISE_RESULT_KIND, estimate_noise, estimate_noise_image, noise_floor
from ._common import (
    OVERWRITE_HELP,
    add_lattice_options,
    check_output_file,
    fmt,
    lattice_option,
    print_json,
)
from ._summary import findings_json


def register(sub) -> None:
    p = sub.add_parser(
        "noise", help="estimate the camera noise (and vibrations) from a static stack or "
        "a single image",
        description="Estimate the sensor noise Var = K l + L from a static grid stack "
        "affected by vibrations (and the per-frame vibration series), or from a single "
        "grid image, and the predicted noise floor of displacement and strain. The .h5 "
        "output can be given to 'gridstrain measure --noise'.")
    p.add_argument("stack", help="static series or one image: multi-page TIFF, directory, "
                   "glob or file")
    p.add_argument("--from", dest="source", choices=("auto", "stack", "image"),
                   default="auto",
                   help="stack: temporal scatter of a static stack (6 frames at least); "
                   "image: the first frame alone (grid removed by its harmonics); auto "
                   "(default): stack when it has enough frames")
    p.add_argument("-o", "--output", help="write the report to OUT.h5 or OUT.json")
    p.add_argument("--T", type=int, default=None, dest="frames",
                   help="frames per state for the predicted noise floor (default: the stack's)")
    p.add_argument("--sigma", type=float, help="window standard deviation, px (default: pitch)")
    p.add_argument("--bit-depth", type=int, choices=(8, 12, 16),
                   help="override the detected bit depth")
    p.add_argument("--degree", type=int, default=None, choices=(0, 1, 2, 3, 4),
                   help="fit a polynomial of this degree in the frames' shifts instead of "
                   "the default vibration model (the shifts and the carriers' harmonics "
                   "of order 1 to 3, which holds at any vibration amplitude); 0 = static "
                   "set-up")
    add_lattice_options(p.add_argument_group("lattice"))
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    out = _output(args)
    lattice_given = lattice_option(vars(args))
    if args.frames is not None:
        check_int(args.frames, "--T", minimum=1)
    series = open_series(args.stack, name="stack", bit_depth=args.bit_depth)
    progress = bar(quiet=args.quiet or args.json)
    mean = series.mean(progress=lambda f, m: progress(0.3 * f, "mean image"))
    lattice = lattice_given or detect_lattice(mean)
    read_notes = tuple(series.notes)  # how the frames were read (colour, lossy codecs)
    series, notes = _screened(series, lattice)
    if notes:
        mean = series.mean()
    notes = [*read_notes, *notes]
    model, vib, degree = _estimate(series, lattice, args.source, args.degree, progress)
    progress(0.9, "noise floor")
    T = args.frames or series.n_frames
    maps = wft(mean, lattice, sigma=args.sigma)
    floor = noise_floor(maps, mean, K=model.K, L=model.L, frames=T)
    progress(1.0, "done")
    summary = _summary(args.stack, series, lattice, model, vib, degree, floor)
    summary["warnings"] = notes
    summary["findings"] = findings_json(notes)
    for note in notes:  # on stderr, whatever the output: a warning, not a result
        print(f"gridstrain noise: warning: {note}", file=sys.stderr)
    if out is not None:
        _write(out, summary, model, vib, args.overwrite)
    if args.json:
        print_json(summary)
        return 0
    _print_report(series, lattice, model, vib, degree, floor, T)
    if out is not None:
        print(f"report written to {out}")
    return 0


def _output(args) -> Path | None:
    """The ``-o`` file, refused now if its type or destination would fail at the end."""
    if not args.output:
        return None
    out = Path(args.output)
    if out.suffix.lower() not in (".h5", ".hdf5", ".json"):
        raise ValueError(f"output {out} must end in .h5, .hdf5 or .json")
    check_output_file(out, "output file", args.overwrite, frozenset({Path(args.stack)
                                                                      .resolve()}))
    return out


def _screened(series, lattice):
    """The stack without its frames of no grid, low contrast, a slip or another
    scene (:func:`gridstrain.stacks.screening.screen_frames`), and the warnings naming them
    (:func:`gridstrain.series.outlier_verdict`, half or more refused). A frame that
    moved or changed would pass its change for noise: K and L would be too large.
    Clipped pixels are left to the estimate, which leaves them out."""
    if series.n_frames < 3:
        return series, []
    sc = screen_frames(series.frames(), lattice, saturation_level=series.saturation_level,
                       scale=series.scale, max_saturation=1.0)
    keep, notes = outlier_verdict(series, sc, "exclude")
    return ((series if len(keep) == series.n_frames else series.subset(keep)),
            findings_of(notes, "screening.flagged", series.name))


def _estimate(series, lattice, source: str, degree: int | None, progress):
    """``(noise model, vibration report or None, vibration model degree or None)``:
    from the stack's temporal scatter when it has enough frames (or ``source`` says
    so), else from its first image alone."""
    use_stack = source == "stack" or (source == "auto" and series.n_frames >= 6)
    if use_stack and degree != 0 and series.n_frames < 6:
        # the mean, the two shifts and 3 degrees of freedom at least
        raise ValueError(f"stack: at least 6 frames are needed to separate the noise "
                         f"from the vibrations, got {series.n_frames} (use --from image)")
    vib = None
    if use_stack:
        model = estimate_noise(series.frames(), lattice, saturation=series.saturation_level,
                               scale=series.scale, degree=degree,
                               progress=lambda f, m: progress(0.3 + 0.5 * f, "noise model"))
        vib = vibration_report(series.frames(), lattice)
    else:
        first = next(iter(series.frames()))
        model = estimate_noise_image(first, lattice, saturation=series.saturation_level,
                                     scale=series.scale)
        degree = None
    return dataclasses.replace(model, bit_depth=series.bit_depth), vib, degree


def _summary(stack, series, lattice, model, vib, degree, floor) -> dict:
    """The JSON summary (and the HDF5 attributes) of the noise, vibrations and floor."""
    return {
        "stack": str(stack), "n_frames": series.n_frames, "shape": list(series.shape),
        "bit_depth": series.bit_depth, "scale": series.scale,
        "lattice": {"k1": list(lattice.k1), "k2": list(lattice.k2),
                    "pitches_px": list(lattice.pitches), "angles_deg": list(lattice.angles)},
        "result_kind": NOISE_RESULT_KIND,
        "noise": {"K": model.K, "L": model.L, "K_ci": model.K_ci, "L_ci": model.L_ci,
                  "method": model.method, "vibration_model_degree": degree,
                  "vibration_terms": (None if model.motion_terms is None
                                      else list(model.motion_terms)),
                  "K_sensor": model.K_sensor, "L_sensor": model.L_sensor,
                  "reduced_chi2": model.reduced_chi2, "units": "stored grey levels"},
        "noise_model": model.as_dict(),
        "vibration": None if vib is None else {
            "std_px": vib.std.tolist(), "covariance_px2": vib.covariance.tolist(),
            "contrast_factor": vib.contrast_factor.tolist(),
            "method_a_phase_offset_std_rad": vib.phase_offset_std.tolist()},
        "noise_floor": {"frames_per_state": floor.frames[1], "sigma_px": floor.sigma,
                        "spatial_resolution_px": floor.spatial_resolution,
                        "window_fwhm_px": floor.window_fwhm,
                        "u_std_px": floor.theory_u[0].tolist(),
                        "strain_std": floor.theory_strain[0].tolist(),
                        "phase_std_rad": floor.theory_phase[0].tolist(),
                        "dphi_std_rad_per_px": floor.theory_dphi[0].tolist()},
    }


def _write(out: Path, summary: dict, model, vib, overwrite: bool) -> None:
    """The summary as JSON, or as the attributes of an HDF5 file with the shifts and
    the noise levels and variances (readable by ``gridstrain measure --noise``)."""
    summary = dict(summary, **provenance())
    if out.suffix.lower() == ".json":
        write_atomic(out, json.dumps(summary, indent=2, default=float).encode("utf-8"),
                     overwrite=overwrite)
        return
    write_hdf5(out, {"vibration/shifts": np.zeros((0, 2)) if vib is None else vib.shifts,
                     "noise/levels": _arr(model.levels),
                     "noise/variances": _arr(model.variances),
                     "noise/variance_errors": _arr(model.variance_errors)},
               summary, units={"vibration/shifts": "px", "noise/levels": "grey level",
                             "noise/variances": "grey level^2",
                             "noise/variance_errors": "grey level^2"},
               overwrite=overwrite)


def _print_report(series, lattice, model, vib, degree, floor, T: int) -> None:
    """The noise model, vibrations and predicted noise floor, for a person."""
    print(f"stack: {series.n_frames} frames of {series.shape[0]}x{series.shape[1]}, "
          f"bit depth {series.bit_depth}" + (f" stored x{series.scale:g}" if series.scale != 1
                                             else ""))
    print(f"lattice: pitches {fmt(lattice.pitches[0])}/{fmt(lattice.pitches[1])} px, "
          f"angles {fmt(lattice.angles[0])}/{fmt(lattice.angles[1])} deg")
    ci = (lambda c: "" if c is None else f"  (95 % CI {fmt(c[0])} to {fmt(c[1])})")  # noqa: E731
    how = ("from the first image alone, grid removed by its harmonics" if vib is None else
           f"vibrations regressed out, polynomial of degree {degree}" if degree is not None
           else _motion_words(model.motion_terms or ()))
    print(f"noise Var = K l + L ({how}):")
    print(f"                      K = {fmt(model.K)}{ci(model.K_ci)}")
    print(f"                      L = {fmt(model.L)}{ci(model.L_ci)}   (stored grey levels)")
    if series.scale != 1:
        print(f"  sensor units:       K = {fmt(model.K_sensor)}, L = {fmt(model.L_sensor)}")
    if vib is not None:
        print(f"vibrations: std = ({fmt(vib.std[0])}, {fmt(vib.std[1])}) px; contrast factor "
              f"({fmt(vib.contrast_factor[0])}, {fmt(vib.contrast_factor[1])}); method-A "
              f"phase offset std ({fmt(vib.phase_offset_std[0])}, "
              f"{fmt(vib.phase_offset_std[1])}) rad")
    print(f"predicted noise floor, T = {T} frames per state, sigma = {fmt(floor.sigma)} px "
          f"(spatial resolution {fmt(floor.spatial_resolution)} px, the period damped by "
          f"10 %; window FWHM {fmt(floor.window_fwhm)} px):")
    u, e = floor.theory_u[0], floor.theory_strain[0]
    print(f"  u_x {fmt(u[0])} px   u_y {fmt(u[1])} px")
    print(f"  e_xx {fmt(e[0])}   e_yy {fmt(e[1])}   e_xy {fmt(e[2])}")


def _motion_words(terms) -> str:
    """How the vibrations were regressed out, from the terms the fit kept."""
    n_harm = sum(1 for t in terms if t not in ("x", "y"))
    if not terms:
        return "stack looks still, plain temporal variance"
    if not n_harm:
        return "shifts regressed out"
    return f"shifts and {n_harm} terms of the carriers' harmonics regressed out"


def _arr(a):
    return np.zeros(0) if a is None else np.asarray(a)
