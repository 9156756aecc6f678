"""``gridstrain stress-gauge``: the stress gauge of an image-based inertial impact test."""

from __future__ import annotations

import os
from pathlib import Path

from ._common import check_output_file, png_option, print_json
from ._post import add_result_options, reads_result

SUMMARY = ("Young's modulus at high strain rate from an impact record: stress from the "
           "accelerations")


def register(sub) -> None:
    p = sub.add_parser(
        "stress-gauge", help=SUMMARY,
        description="For an impact record measured with --each-frame --frame-rate HZ and a "
        "pixel size: the mean axial stress over every cross-section at a distance d from "
        "the free edge, rho d a, with a the mean axial acceleration (a Savitzky-Golay "
        "second derivative over time) of the specimen between the free edge and the "
        "section; the mean axial strain of the section; E from the slope of the "
        "stress-strain points over states and sections (one intercept per state, which "
        "takes the stress of the strip without data along the free edge), with a 95 "
        "percent interval; the strain rates. Assumes a uniaxial stress along the axis "
        "normal to the free edge (plane stress), small strains, a linear elastic "
        "material for E. Density in kg/m3, lengths in the result's unit, stress in MPa.")
    add_result_options(p, loads=False)
    p.add_argument("--density", type=float, required=True, metavar="RHO",
                   help="the specimen's density, kg/m3")
    p.add_argument("--free-edge", required=True, choices=("left", "right", "top", "bottom"),
                   help="the specimen's free edge, opposite the impact (left/right: the "
                   "axis is x, the stress sxx; top/bottom: y, syy)")
    p.add_argument("--edge-at", type=float, metavar="POS",
                   help="position of the free edge along the axis, in the result's unit "
                   "(px with --px; default: the border of the result's specimen mask on "
                   "that side)")
    p.add_argument("--px", action="store_true",
                   help="--edge-at in px (the stress keeps the file's length unit)")
    p.add_argument("--smoothing", type=int, nargs=2, default=(9, 4),
                   metavar=("WINDOW", "ORDER"),
                   help="the Savitzky-Golay filter over time: states in the window (odd) "
                   "and degree of the polynomial (default 9 4: exact for a quartic)")
    p.add_argument("--strain-floor", type=float, default=0.1, metavar="F",
                   help="fit E on the points whose |strain| is at least F times the "
                   "largest (default 0.1)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--curves", metavar="FILE.csv",
                   help="write the stress-strain curves: one row per state and section")
    p.add_argument("--plot", metavar="FILE.png", help="write the stress-strain plot")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.set_defaults(func=run)


def _output(value, what, args, src):
    if not value:
        return None
    path = Path(os.path.expanduser(value))
    check_output_file(path, what, args.overwrite, {src.resolve()})
    return path


@reads_result
def run(args) -> int:
    from ..identify import stress_gauge_of
    from ..results import load, read_attrs

    src = Path(os.path.expanduser(args.result))
    curves = _output(args.curves, "curves file", args, src)
    plot = _output(str(png_option(args.plot)) if args.plot else None, "plot file", args, src)
    attrs = read_attrs(src)
    ps, unit = attrs.get("pixel_size"), attrs.get("unit")
    if ps is None or unit is None:
        raise ValueError(f"{src} has no pixel size: measure the record with --pixel-size "
                         "SIZE --unit mm, so that the stress has a length scale")
    result = load(src, in_memory=False)
    if result.time is None:
        raise ValueError(f"{src} has no times: measure the record with --each-frame "
                         "--frame-rate HZ")
    from ..post import frame_of

    # --edge-at in the unit places are named in (gridstrain.post's rule); it may lie
    # outside the field (a free end beyond the image), so it is scaled, not checked
    frame = frame_of(result.shape, pixel_size=ps, unit=unit, px=args.px)
    edge = None if args.edge_at is None else args.edge_at / frame.scale
    window, order = args.smoothing
    try:
        g = stress_gauge_of(result, density=args.density, free_edge=args.free_edge,
                            pixel_size=ps, unit=unit, edge=edge, window=window,
                            order=order, strain_floor=args.strain_floor)
    except ValueError as exc:
        # the filter's window and order are --smoothing's two numbers here
        if str(exc).startswith(("window ", "order ")):
            raise ValueError(f"--smoothing WINDOW ORDER: {exc}") from None
        raise
    if curves is not None:
        from ..io import write_csv

        write_csv(curves, g.curves(), overwrite=args.overwrite, digits=10)
    if plot is not None:
        from ..post import save_figure

        save_figure(g.plot(), plot, overwrite=args.overwrite)
    if args.json:
        d = g.to_dict()
        for key, path in (("curves", curves), ("plot", plot)):
            if path is not None:
                d[key] = str(path)
        print_json(d)
        return 0
    lo, hi = g.E_interval
    r0, r1 = g.strain_rate_range
    print(f"{g.distance.size} sections from {g.distance[0]:.4g} to {g.distance[-1]:.4g} "
          f"{g.unit} of the {g.free_edge} free edge, {g.time.size} states; Savitzky-Golay "
          f"window {g.window} states, order {g.order}")
    print(f"E = {g.E:.5g} MPa, 95 % interval [{lo:.5g}, {hi:.5g}] (from the "
          f"{g.interval_basis}; {int(g.fitted.sum())} points)")
    print(f"strain rate {r0:.3g} to {r1:.3g} 1/s over the points fitted; peak stress "
          f"{abs(g.stress).max():.4g} MPa")
    print(f"strip without data along the free edge: {g.strip_width:.3g} {g.unit}, its "
          f"extrapolated stress up to {abs(g.strip_stress).max():.3g} MPa (in the curves, "
          "not in E)")
    for path in (curves, plot):
        if path is not None:
            print(path)
    return 0
