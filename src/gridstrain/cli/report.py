"""``gridstrain report``: a result file as one self-contained HTML page."""

from __future__ import annotations

import os
from pathlib import Path

from ._common import OVERWRITE_HELP, check_output_file
from ._post import (
    add_colour_options,
    add_loads_options,
    cmap_option,
    limits_option,
    open_result,
    reads_result,
)


def register(sub) -> None:
    p = sub.add_parser(
        "report", help="a self-contained HTML report of a result file",
        description="Write one HTML file (figures embedded, nothing fetched from the "
        "network): when the states have loads (the result's or --loads) or a --region or "
        "--area is named, a gauge's strains "
        "in every state and their history; with loads the load-strain plot, or with "
        "--area the stress-strain plot with Young's modulus and Poisson's ratio and "
        "their 95 percent intervals; the maps "
        "of every state on colour limits they share; one table with a row per state "
        "and one with a row per image series; the uncertainty maps, the lattice, the "
        "warnings and the run's provenance.")
    p.add_argument("result", metavar="RESULT.h5", help="a file written by gridstrain measure")
    p.add_argument("-o", "--output", metavar="REPORT.html",
                   help="output file (default: RESULT.html next to the result)")
    add_loads_options(p, default=" (default: those stored in the result, if any)")
    g = p.add_argument_group("the test (a gauge; E and nu need loads; coordinates in "
                             "the file's physical unit when it has a pixel size, else "
                             "px; --px forces px)")
    g.add_argument("--region", type=float, nargs=4, metavar=("X0", "Y0", "X1", "Y1"),
                   action="append",
                   help="a gauge: mean over the rectangle x0 <= x < x1, y0 <= y < y1 "
                   "(default: the whole valid region); repeated, several gauges G1, "
                   "G2... side by side in the table, each with its plots and E, nu")
    g.add_argument("--px", action="store_true",
                   help="--region in px even when the file has a pixel size")
    g.add_argument("--area", type=float, metavar="A",
                   help="the specimen's cross-section, in --area-unit: E and nu with their "
                   "intervals and the stress-strain plot (without it: the load-strain "
                   "plot)")
    g.add_argument("--area-unit", default="mm2", metavar="UNIT",
                   help="unit of --area: mm2 (default), cm2, m2, in2")
    g.add_argument("--axis", choices=("x", "y"), default="x",
                   help="loading direction (default x: exx is the axial strain)")
    add_colour_options(p)
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.set_defaults(func=run)


@reads_result
def run(args) -> int:
    from ..post import write_report

    limits, cmap = limits_option(args.limits), cmap_option(args.cmap)
    if args.area is not None and not args.area > 0:
        raise ValueError(f"--area must be a positive cross-section, got {args.area:g}")
    src = Path(os.path.expanduser(args.result))
    out = Path(os.path.expanduser(args.output)) if args.output else src.with_suffix(".html")
    check_output_file(out, "report file", args.overwrite, {src.resolve()})
    loads = {}
    if any(getattr(args, f) is not None for f in ("loads", "load_column", "time_column",
                                                   "loads_offset")):
        # read as gauge and modulus read it (a flag without --loads refused there)
        _, _, _, _, ld, lu, t = open_result(args)
        loads = {"load": ld, "load_unit": lu, "time": t}
    region = args.region if args.region is None or len(args.region) > 1 else args.region[0]
    print(write_report(src, out, overwrite=args.overwrite, region=region, px=args.px,
                       area=args.area, area_unit=args.area_unit, axis=args.axis,
                       limits=limits, cmap=cmap, **loads))
    return 0
