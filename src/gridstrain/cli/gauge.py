"""``gridstrain gauge``: virtual strain gauges and extensometers over the states."""

from __future__ import annotations

from ._post import (
    add_gauge_options,
    add_output_options,
    add_result_options,
    gauge_of,
    open_result,
    output_path,
    reads_result,
)

SUMMARY = "virtual strain gauge and extensometer: mean strain of every state with its std"


def register(sub) -> None:
    p = sub.add_parser(
        "gauge", help=SUMMARY,
        description="Read a virtual strain gauge (the mean of exx, eyy, exy over the valid "
        "pixels of a region, a point or a polygon) and optionally an extensometer (the "
        "engineering strain between two points) on every state, each with its standard "
        "deviation from the noise, propagated through the window's correlation. Prints a "
        "table (strains in --strain-units, microstrain by default); -o writes a CSV "
        "(strains dimensionless). --derived adds the principal strains e1, e2, their "
        "angle, the equivalent (von Mises) strain and the maximum shear of the mean "
        "tensor, with their std; --finite the Green-Lagrange (gl_xx, gl_yy, gl_xy) and "
        "logarithmic (log_xx...) strains of the mean displacement gradient, with their "
        "std.")
    add_result_options(p)
    add_gauge_options(p)
    p.add_argument("--extensometer", type=float, nargs=4, metavar=("X0", "Y0", "X1", "Y1"),
                   help="also the engineering strain between the points (x0, y0), (x1, y1)")
    p.add_argument("--strain-units", choices=("microstrain", "%", "1"),
                   default="microstrain",
                   help="strains of the printed table in microstrain (default), percent or "
                   "dimensionless; the CSV stays dimensionless")
    p.add_argument("--derived", action="store_true",
                   help="also e1, e2, principal_angle, equivalent, max_shear and their std "
                   "(table and CSV)")
    p.add_argument("--finite", action="store_true",
                   help="also the Green-Lagrange and logarithmic strains gl_xx, gl_yy, "
                   "gl_xy, log_xx, log_yy, log_xy and their std (table and CSV; needs a "
                   "result measured with the Lagrangian correction, the default)")
    add_output_options(p, "the table")
    p.set_defaults(func=run)


@reads_result
def run(args) -> int:
    result, src, ps, unit, ld, lu, t = open_result(args)
    out = output_path(args, src, "gauge CSV")
    reading = gauge_of(args, result, ps, unit, ld, lu, t, extensometer=args.extensometer,
                       finite=args.finite)
    print(reading.table(strain_units=args.strain_units, derived=args.derived,
                        finite=args.finite))
    if out is not None:
        print(reading.to_csv(out, derived=args.derived, finite=args.finite,
                             overwrite=args.overwrite))
    return 0
