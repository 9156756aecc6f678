"""``gridstrain export``: a result file written again as MATLAB, CSV, ParaView or
NetCDF files."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from ._common import check_output_file
from ._post import add_result_options, open_result, reads_result

SUMMARY = "write a result file as MATLAB, CSV, ParaView (VTK) or NetCDF files"

# the formats of gridstrain.results.EXPORTS, written here so that --help imports nothing
_FORMATS = ("mat", "vtk", "csv", "netcdf")


def register(sub) -> None:
    p = sub.add_parser(
        "export", help=SUMMARY,
        description="Write the maps of a result file (measured earlier) as PREFIX.mat "
        "(MATLAB: maps H x W x states), PREFIX.csv (one row per valid pixel, units in "
        "the header), PREFIX.pvd with PREFIX_vti/ (a ParaView time series) and/or "
        "PREFIX.nc (a clean NetCDF-4 copy for xarray). Each holds the load and time of "
        "every state when known, the strains, their std and the derived strains (e1, "
        "e2, principal_angle, equivalent, max_shear); lengths in the file's unit when "
        "it has a pixel size.")
    add_result_options(p)
    p.add_argument("--to", required=True, metavar="FORMATS",
                   help=f"comma-separated formats among {', '.join(_FORMATS)} "
                   "(e.g. mat,csv)")
    p.add_argument("-o", "--output", metavar="PREFIX",
                   help="path and name of the files, their suffix added (a .mat, .csv, "
                   ".pvd or .nc given is dropped; default: the result's, next to it)")
    p.add_argument("--px", action="store_true",
                   help="lengths in px even when the file has a pixel size")
    p.add_argument("--overwrite", action="store_true",
                   help="replace files an earlier export wrote")
    p.set_defaults(func=run)


def _formats(text: str) -> list[str]:
    items = [v.strip().lower() for v in text.split(",")]
    if not items or any(v not in _FORMATS for v in items):
        raise ValueError(f"--to must list formats among {', '.join(_FORMATS)} (e.g. "
                         f"mat,csv), got {text!r}")
    return list(dict.fromkeys(items))


@reads_result
def run(args) -> int:
    from ..results import EXPORTS, export, export_path

    formats = _formats(args.to)
    result, src, ps, unit, ld, lu, t = open_result(args)
    if getattr(args, "loads", None):
        result = dataclasses.replace(result, load=ld, load_unit=lu, time=t)
    stem = Path(os.path.expanduser(args.output)) if args.output else src.with_suffix("")
    if args.output and stem.suffix.lower() in {e.suffix for e in EXPORTS.values()}:
        # "-o maps.mat" names the files maps.*, not maps.mat.mat
        stem = stem.with_suffix("")
    if not stem.name or stem.name in (".", ".."):
        raise ValueError(f"-o must name the files (a path and a name without suffix), got "
                         f"{args.output!r}")
    # every destination refused before any is written: the input, or a file there
    for f in formats:
        path = export_path(stem, f)
        if path.resolve() == src.resolve():
            raise ValueError(f"the {f} export {path} is the result file itself; give -o "
                             "another PREFIX")
        check_output_file(path, f"{f} export", args.overwrite, {src.resolve()})
    written = export(result, stem, formats, pixel_size=ps, unit=unit,
                     overwrite=args.overwrite)
    for path in written.values():
        print(path)
    return 0
