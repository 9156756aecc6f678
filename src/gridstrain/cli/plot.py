"""``gridstrain plot``: figures of a result file, for papers and reports."""

from __future__ import annotations

import os
from pathlib import Path

from ._post import (
    add_colour_options,
    add_gauge_options,
    add_loads_options,
    cmap_option,
    limits_option,
    open_result,
    reads_result,
)

_FORMATS = ("png", "pdf", "svg")


def register(sub) -> None:
    p = sub.add_parser(
        "plot", help="figures of a result file: maps of every state, strain history",
        description="Draw the maps of a result file's states on colour limits shared by "
        "the states (robust percentiles by default) "
        "(strains in microstrain, the valid region shown over the reference image, the "
        "axes and a scale bar in the file's physical unit when it has a pixel size; up "
        "to 12 states: "
        "the first, evenly spaced ones and the last; no figure taller than 4000 px) and "
        "the strain history of every state at a point or averaged over a region, against "
        "time or load when known, with error bars of one std. --region and --point are "
        "in the file's physical unit when it has a pixel size (px with --px), as in "
        "gauge, modulus and history.")
    p.add_argument("result", metavar="RESULT.h5", help="a file written by gridstrain measure")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="output directory (default: RESULT_figures next to the result)")
    p.add_argument("--maps", default="ux,uy,exx,eyy,exy,rotation", metavar="NAMES",
                   help="comma-separated quantities (ux, uy, exx, eyy, exy, rotation, "
                   "exx_std..., and the derived e1, e2, principal_angle, equivalent, "
                   "max_shear, e1_std..., the finite strains gl_xx, gl_yy, gl_xy "
                   "(Green-Lagrange), log_xx, log_yy, log_xy (logarithmic), gl_xx_std..., "
                   "rotation_std; default ux,uy,exx,eyy,exy,rotation)")
    add_colour_options(p)
    p.add_argument("--strain-units", choices=("microstrain", "%", "1"),
                   default="microstrain",
                   help="strains in microstrain (default), percent or dimensionless")
    add_loads_options(p, default=" (default: those stored in the result, if any)")
    add_gauge_options(p, what="the strain history", polygon=False,
                      px_help="coordinates, the maps' axes and displacements in px even "
                      "when the file has a pixel size")
    p.add_argument("--dpi", type=int, default=150, help="resolution (default 150; 300 for "
                   "print)")
    p.add_argument("--format", choices=_FORMATS, default="png",
                   help="file format (default png)")
    p.add_argument("--overwrite", action="store_true", help="replace existing figures")
    p.set_defaults(func=run)


@reads_result
def run(args) -> int:
    from ..io import OutputDirectory
    from ..post import QUANTITIES, capped_dpi, plot_history, plot_states

    if not 20 <= args.dpi <= 1200:
        raise ValueError(f"--dpi must be between 20 and 1200, got {args.dpi}")
    names = [n.strip() for n in args.maps.split(",") if n.strip()]
    bad = [n for n in names if n not in QUANTITIES]
    if bad or not names:
        raise ValueError(f"--maps must list quantities among {', '.join(QUANTITIES)}, got "
                         f"{args.maps!r}")
    if args.point and args.region:
        raise ValueError("give --point or --region, not both")
    limits, cmap = limits_option(args.limits), cmap_option(args.cmap)
    result, src, ps, unit, ld, lu, t = open_result(args)
    out = Path(os.path.expanduser(args.output)) if args.output else \
        src.with_name(src.stem + "_figures")
    micro = args.strain_units
    figures = {f"{n}.{args.format}": (lambda n=n: plot_states(
        result, n, limits=limits, cmap=cmap, microstrain=micro, pixel_size=ps,
        unit=unit, px=ps is None))
        for n in names}
    # drawn first: a place outside the field, or with no valid pixel, is refused
    # before the maps are drawn
    history = plot_history(result, point=args.point, region=args.region,
                           microstrain=micro, load=ld, load_unit=lu, time=t, pixel_size=ps,
                           unit=unit, px=ps is None)
    figures[f"history.{args.format}"] = lambda: history
    # only figures gridstrain wrote there are replaced (the folder's marker lists them)
    directory = OutputDirectory(out, list(figures), overwrite=args.overwrite,
                                parents=True, what="output directory")
    # build every figure before writing any: a bad option leaves no partial set
    built = {name: make() for name, make in figures.items()}
    directory.prepare()
    for name, fig in built.items():
        # no figure taller than 4000 px: a tall one is saved at a lower resolution
        dpi = capped_dpi(fig, args.dpi)
        directory.write(name, lambda fh, fig=fig, dpi=dpi: fig.savefig(
            fh, format=args.format, dpi=dpi))
        print(out / name)
    return 0
