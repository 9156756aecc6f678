"""``gridstrain animate``: a map of every state as a GIF or MP4 animation."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from ._common import OVERWRITE_HELP, check_output_file
from ._post import (
    add_colour_options,
    add_result_options,
    cmap_option,
    limits_option,
    open_result,
    reads_result,
)

SUMMARY = "an animation (GIF, MP4) of a map over the states on fixed colour limits"


def register(sub) -> None:
    p = sub.add_parser(
        "animate", help=SUMMARY,
        description="Draw one quantity of every state as the frames of a GIF (Pillow) or "
        "an MP4 (PyAV: pip install 'gridstrain[video]'), on colour limits fixed over all "
        "the states, with each state's name, time and load in its frame.")
    add_result_options(p)
    p.add_argument("quantity", help="ux, uy, exx, eyy, exy, rotation, exx_std..., the "
                   "derived e1, e2, principal_angle, equivalent, max_shear, or the finite "
                   "strains gl_xx, gl_yy, gl_xy (Green-Lagrange), log_xx, log_yy, log_xy "
                   "(logarithmic), gl_xx_std...")
    p.add_argument("-o", "--output", required=True, metavar="FILE.mp4|FILE.gif",
                   help="the animation; its extension chooses the format")
    p.add_argument("--fps", type=float, default=5.0, help="states per second (default 5)")
    add_colour_options(p)
    p.add_argument("--dpi", type=float, default=100, help="frame resolution (default 100: "
                   "640 px wide)")
    p.add_argument("--strain-units", choices=("microstrain", "%", "1"),
                   default="microstrain",
                   help="strains in microstrain (default), percent or dimensionless")
    p.add_argument("--px", action="store_true",
                   help="displacements and the axes in px even when the file has a "
                   "pixel size")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.set_defaults(func=run)


@reads_result
def run(args) -> int:
    from ..post import ANIMATION_FORMATS, animate

    out = Path(os.path.expanduser(args.output))
    if out.suffix.lower() not in ANIMATION_FORMATS:
        raise ValueError(f"-o must end in {' or '.join(ANIMATION_FORMATS)}, got "
                         f"{args.output!r}")
    limits, cmap = limits_option(args.limits), cmap_option(args.cmap)
    result, src, ps, unit, ld, lu, t = open_result(args)
    check_output_file(out, "animation", args.overwrite, {src.resolve()})
    try:
        path = animate(result, args.quantity, out, fps=args.fps, limits=limits, cmap=cmap,
                       pixel_size=ps, unit=unit, px=ps is None, load=ld, load_unit=lu, time=t,
                       dpi=args.dpi, strain_units=args.strain_units,
                       overwrite=args.overwrite)
    except ImportError as exc:  # the optional video writer: one line naming the extra
        print(f"gridstrain animate: error: {exc}", file=sys.stderr)
        return 2
    print(path)
    return 0
