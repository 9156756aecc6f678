"""``gridstrain report``: a result file as one self-contained HTML page."""

from __future__ import annotations

import os
from pathlib import Path

from ._common import OVERWRITE_HELP, check_output_file
from ._post import reads_result


def register(sub) -> None:
    p = sub.add_parser(
        "report", help="a self-contained HTML report of a result file",
        description="Write one HTML file (figures embedded, nothing fetched from the "
        "network) with the run's parameters and provenance, the lattice, the vibrations, "
        "the noise floor, the maps of every state on common colour limits, the "
        "uncertainty maps and the warnings.")
    p.add_argument("result", metavar="RESULT.h5", help="a file written by gridstrain measure")
    p.add_argument("-o", "--output", metavar="REPORT.html",
                   help="output file (default: RESULT.html next to the result)")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.set_defaults(func=run)


@reads_result
def run(args) -> int:
    from ..post import write_report

    src = Path(os.path.expanduser(args.result))
    out = Path(os.path.expanduser(args.output)) if args.output else src.with_suffix(".html")
    check_output_file(out, "report file", args.overwrite, {src.resolve()})
    print(write_report(src, out, overwrite=args.overwrite))
    return 0
