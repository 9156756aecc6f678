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
        "state), evenly spaced.")
    add_result_options(p)
    add_gauge_options(p)
    p.add_argument("--window", type=int, default=5, help="states in the window (odd, "
                   "default 5)")
    p.add_argument("--order", type=int, default=2, help="degree of the polynomial (default 2)")
    add_output_options(p, "every column")
    p.set_defaults(func=run)


@reads_result
def run(args) -> int:
    from ..post import history

    result, src, ps, unit, ld, lu, t = open_result(args)
    out = output_path(args, src, "history CSV")
    reading = gauge_of(args, result, ps, unit, ld, lu, t)
    h = history(reading, window=args.window, order=args.order, pixel_size=ps, unit=unit)
    print(f"{reading.where}; Savitzky-Golay window {h.window} states, order {h.order}")
    print(f"{'state':>12} {'time [s]':>10} {'exx [µε]':>9} {'d exx/dt [1/s]':>15} "
          f"{'std':>9} {f'vx [{h.unit}/s]':>12} {f'ax [{h.unit}/s2]':>13}")
    for i, name in enumerate(h.states):
        print(f"{name:>12} {h.time[i]:>10.6g} {h.exx[i] * 1e6:>9.1f} "
              f"{fmt(h.exx_rate[i]):>15} {fmt(h.exx_rate_std[i]):>9} "
              f"{fmt(h.vx[i]):>12} {fmt(h.ax[i]):>13}")
    if out is not None:
        print(h.to_csv(out, overwrite=args.overwrite))
    return 0
