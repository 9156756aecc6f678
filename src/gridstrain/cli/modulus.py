"""``gridstrain modulus``: Young's modulus and Poisson's ratio from a gauge and the loads."""

from __future__ import annotations

from ._common import OVERWRITE_HELP, check_output_file, png_option, print_json
from ._post import add_gauge_options, add_result_options, gauge_of, open_result, reads_result

SUMMARY = ("Young's modulus and Poisson's ratio with their intervals, from a gauge and the "
           "loads")


def register(sub) -> None:
    p = sub.add_parser(
        "modulus", help=SUMMARY,
        description="Fit the gauge's strains of every state against the stress (load / "
        "area), weighted by their std: E from the axial strain, nu from the transverse "
        "one, each with a 95 percent interval (from the stated std, or from the residual "
        "scatter when it is larger).")
    add_result_options(p)
    add_gauge_options(p)
    p.add_argument("--area", type=float, required=True, metavar="A",
                   help="the specimen's cross-section, in --area-unit")
    p.add_argument("--area-unit", default="mm2", metavar="UNIT",
                   help="unit of --area: mm2 (default), cm2, m2 (with loads in N, kN or "
                   "MN the stress is in MPa), in2 (with lbf: psi)")
    p.add_argument("--axis", choices=("x", "y"), default="x",
                   help="loading direction (default x: exx is the axial strain)")
    p.add_argument("--strain-range", type=float, nargs=2, metavar=("LO", "HI"),
                   help="fit only the states whose axial strain (dimensionless) lies in "
                   "[LO, HI]")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--plot", metavar="FILE.png", help="write the stress-strain plot")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.set_defaults(func=run)


@reads_result
def run(args) -> int:
    from ..post import elastic_constants

    plot = png_option(args.plot)
    result, src, ps, unit, ld, lu, t = open_result(args)
    if plot is not None:
        check_output_file(plot, "plot file", args.overwrite, {src.resolve()})
    reading = gauge_of(args, result, ps, unit, ld, lu, t)
    c = elastic_constants(reading, area=args.area, area_unit=args.area_unit,
                          axis=args.axis, strain_range=args.strain_range)
    if plot is not None:
        from ..post import plot_stress_strain, save_figure

        save_figure(plot_stress_strain(c), plot, overwrite=args.overwrite)
    if args.json:
        d = c.to_dict()
        d["gauge"] = reading.where
        if plot is not None:
            d["plot"] = str(plot)
        print_json(d)
        return 0
    print(reading.where)
    print(f"E  = {c.E_text()}")
    if c.unit_doubt() is not None:
        print(f"note: {c.unit_doubt()}")
    print(f"nu = {c.nu:.4f}, 95 % interval [{c.nu_ci[0]:.4f}, {c.nu_ci[1]:.4f}]")
    print(f"{len(c.states)} states fitted; intervals from the {c.interval_basis} (reduced "
          f"chi2 {c.reduced_chi2[0]:.2f} axial, {c.reduced_chi2[1]:.2f} transverse)")
    if plot is not None:
        print(plot)
    return 0
