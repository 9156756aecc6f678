"""``gridstrain history``: a gauge's strain rate, velocity and acceleration over time."""

from __future__ import annotations

from ._common import fmt
from ._post import (
    add_gauge_options,
    add_output_options,
    add_result_options,
    gauge_of,
    open_result,
    output_path,
    reads_result,
)

SUMMARY = "strain rate, velocity and acceleration of a gauge over time, smoothed, with std"


def register(sub) -> None:
    p = sub.add_parser(
        "history", help=SUMMARY,
        description="Smooth a gauge's readings over the states' times with a Savitzky-Golay "
        "filter (a polynomial of degree --order fitted to --window consecutive states) and "
        "differentiate it: strain rates, and the velocity and acceleration of the gauge's "
        "mean displacement, each with its std. The times come from the result (the frame "
        "rate or the camera's time stamps) or from --loads (its time column, one row per "
        "state), evenly spaced. Places, velocities and accelerations are in the file's "
        "unit when it has a pixel size, px with --px. --finite also smooths and "
        "differentiates the Green-Lagrange and logarithmic strains of the mean "
        "displacement gradient (gl_xx... log_xy, with their rates and std).")
    add_result_options(p)
    add_gauge_options(p)
    p.add_argument("--window", type=int, default=5, help="states in the window (odd, "
                   "default 5)")
    p.add_argument("--order", type=int, default=2, help="degree of the polynomial (default 2)")
    p.add_argument("--finite", action="store_true",
                   help="also the Green-Lagrange and logarithmic strains and their rates "
                   "(table: gl_xx and log_xx; CSV: every component; needs a result "
                   "measured with the Lagrangian correction, the default)")
    p.add_argument("--strain-units", choices=("microstrain", "%", "1"), default="microstrain",
                   help="strains of the printed table in microstrain (default), percent "
                   "or dimensionless; the CSV stays dimensionless")
    add_output_options(p, "every column")
    p.set_defaults(func=run)


@reads_result
def run(args) -> int:
    from ..post import history, strain_scale

    result, src, ps, unit, ld, lu, t = open_result(args)
    out = output_path(args, src, "history CSV")
    reading = gauge_of(args, result, ps, unit, ld, lu, t, finite=args.finite)
    h = history(reading, window=args.window, order=args.order, pixel_size=ps, unit=unit,
                px=ps is None, finite=args.finite)
    factor, label = strain_scale(args.strain_units)
    # a tenth of a microstrain in every unit, as gauge's table
    digits = {1e6: 1, 100.0: 5, 1.0: 7}[factor]
    strains = ("exx", "gl_xx", "log_xx") if h.finite else ("exx",)
    print(f"{reading.where}; Savitzky-Golay window {h.window} states, order {h.order}")
    head = [f"{'state':>12}", f"{'time [s]':>10}"]
    for name in strains:
        head += [f"{f'{name} [{label}]':>13}", f"{f'd {name}/dt [1/s]':>17}", f"{'std':>9}"]
    head += [f"{f'vx [{h.unit}/s]':>12}", f"{f'ax [{h.unit}/s2]':>13}"]
    print(" ".join(head))
    for i, name in enumerate(h.states):
        row = [f"{name:>12}", f"{h.time[i]:>10.6g}"]
        for s in strains:
            row += [f"{getattr(h, s)[i] * factor:>13.{digits}f}",
                    f"{fmt(getattr(h, f'{s}_rate')[i]):>17}",
                    f"{fmt(getattr(h, f'{s}_rate_std')[i]):>9}"]
        row += [f"{fmt(h.vx[i]):>12}", f"{fmt(h.ax[i]):>13}"]
        print(" ".join(row))
    if out is not None:
        print(h.to_csv(out, overwrite=args.overwrite))
    return 0
