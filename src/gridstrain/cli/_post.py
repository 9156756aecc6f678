"""Options shared by the commands that read a result file's states (gauge, modulus,
history, animate): the file, its pixel size, the loads and the gauge's region."""

from __future__ import annotations

import functools
import os
import sys
from pathlib import Path

from ..series import OPTIONS
from ._common import OVERWRITE_HELP, add_option, check_output_file, xy_pairs

# measure's options by name: the loads file's reading options are theirs
_MEASURE_OPTIONS = {o.name: o for o in OPTIONS}


def add_result_options(p, *, loads: bool = True) -> None:
    p.add_argument("result", metavar="RESULT.h5", help="a file written by gridstrain measure")
    if loads:
        add_loads_options(p, default=" (default: those stored in the result, if any)")


def add_loads_options(p, *, default: str = "") -> None:
    """``--loads`` and how to read it: the testing machine's export as it comes."""
    g = p.add_argument_group("loads (a testing machine's export, read as it comes)")
    g.add_argument("--loads", metavar="FILE.csv",
                   help="load (and time) of each state: a testing machine's export "
                   "(',', ';', tab or spaces between columns, decimal comma, preamble "
                   "lines, units in the header: 'Force (kN)', 'Zeit [ms]'); a log with a "
                   "time column is joined to the states' times by linear interpolation; "
                   "else one row per state or a 'state' column naming them" + default)
    # how to read it: measure's options of the same names (gridstrain.series.OPTIONS)
    for name in ("load_column", "time_column", "loads_offset"):
        add_option(g, _MEASURE_OPTIONS[name])


#: How every command names a place (gridstrain.post._places holds the rule).
PLACES = ("Coordinates in the file's physical unit when it has a pixel size, else px; "
          "--px forces px; a place outside the measured field or with no valid pixel is "
          "refused, naming the field's extent.")


def add_gauge_options(p, *, what: str = "the gauge", polygon: bool = True,
                      px_help: str = "coordinates in px even when the file has a pixel "
                      "size") -> None:
    g = p.add_argument_group(what, PLACES)
    g.add_argument("--region", type=float, nargs=4, metavar=("X0", "Y0", "X1", "Y1"),
                   help="mean over the valid pixels whose centre lies in x0 <= x < x1, "
                   "y0 <= y < y1 (default: the whole field)")
    g.add_argument("--point", type=float, nargs=2, metavar=("X", "Y"),
                   help="the pixel nearest to this point")
    if polygon:
        g.add_argument("--polygon", nargs="+", metavar="X,Y",
                       help="mean over a polygon, its vertices as x,y (at least 3)")
    g.add_argument("--px", action="store_true", help=px_help)


def add_colour_options(p) -> None:
    """``--limits`` and ``--cmap``: the colour limits and colormap of the maps, one
    default (robust) for plot, animate and report."""
    p.add_argument("--limits", nargs="+", default=["robust"], metavar="MODE",
                   help="colour limits over all states: 'robust' (default: the "
                   "0.5-99.5th percentiles of the valid values), 'common' (their full "
                   "range) or 'explicit LO HI' (in the unit drawn: microstrain for "
                   "strains by default)")
    p.add_argument("--cmap", metavar="NAME",
                   help="a matplotlib colormap (default: RdBu_r centred on zero for a "
                   "field of both signs, else viridis)")


def limits_option(values):
    """``--limits``'s words as ``limits=``: a name, or the pair after 'explicit'."""
    words = list(values or ["robust"])
    if words[0] == "explicit":
        if len(words) != 3:
            raise ValueError(f"--limits explicit needs two numbers LO HI, got "
                             f"{' '.join(words[1:]) or 'none'}")
        try:
            lo, hi = float(words[1]), float(words[2])
        except ValueError:
            raise ValueError(f"--limits explicit needs two numbers LO HI, got "
                             f"{words[1]} {words[2]}") from None
        from ..post import check_limits

        return check_limits((lo, hi), name="--limits explicit LO HI")
    if len(words) != 1 or words[0] not in ("robust", "common"):
        raise ValueError(f"--limits must be robust, common or explicit LO HI, got "
                         f"{' '.join(words)}")
    return words[0]


def cmap_option(value):
    from ..post import check_cmap

    return check_cmap(value, name="--cmap")


def polygon_option(values):
    if values is None:
        return None
    out = xy_pairs(values, "--polygon")
    if len(out) < 3:
        raise ValueError(f"--polygon needs at least 3 vertices, got {len(out)}")
    return out


def add_output_options(p, what: str) -> None:
    p.add_argument("-o", "--output", metavar="FILE.csv", help=f"write {what} as CSV")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


def output_path(args, src: Path, what: str) -> Path | None:
    """``-o``'s path, refused before any work if it would clobber a file or the input."""
    if not args.output:
        return None
    out = Path(os.path.expanduser(args.output))
    check_output_file(out, what, args.overwrite, {src.resolve()})
    return out


def reads_result(run):
    """A command's ``run`` that reads a result file: inside it, the reads of the maps
    left in the file keep one open handle (:func:`gridstrain.results.kept_open`),
    closed when it returns, rather than opening the file for each state."""
    @functools.wraps(run)
    def wrapped(args) -> int:
        from ..results import kept_open

        with kept_open():
            return run(args)
    return wrapped


def load_with_attrs(src: Path):
    """The result (its maps left in the file) and the root attributes of the file at
    ``src``, both read from one file: one replaced between the two reads is refused."""
    from ..results import load, read_attrs

    before = _identity(src)
    result = load(src, in_memory=False)
    attrs = read_attrs(src)
    if _identity(src) != before:
        raise ValueError(f"{src}: the result file was replaced while it was opened; run "
                         "again on the file as it is now")
    return result, attrs


def _identity(src: Path):
    try:
        st = os.stat(src)
    except OSError:
        return None  # missing: load says so, naming the file
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def open_result(args, *, px_drops_scale: bool = True):
    """``(result, path, pixel_size, unit, load, load_unit, time)`` of the command's file.

    ``--px`` names places in px; with ``px_drops_scale`` it also drops the file's pixel
    size (every length in px), else the command keeps it for its other lengths (a
    modulus's thickness) and hands ``--px`` to the places alone."""
    from ..io import LoadsFile
    from ..results import state_loads

    src = Path(os.path.expanduser(args.result))
    result, attrs = load_with_attrs(src)
    ps, unit = attrs.get("pixel_size"), attrs.get("unit")
    if ps is None or unit is None or (px_drops_scale and getattr(args, "px", False)):
        ps = unit = None
    if getattr(args, "loads", None):
        own = state_loads(result)[2]
        table = LoadsFile(os.path.expanduser(args.loads), load_column=args.load_column,
                          time_column=args.time_column, offset=args.loads_offset or 0.0
                          ).read(result.names[1:], reference=result.names[0], times=own)
        for note in table.notes:  # rows skipped as frames the record lacks
            print(f"gridstrain {getattr(args, 'command', '')}: warning: {note}",
                  file=sys.stderr)
        ld, lu, t = table.load, table.unit, table.time
        if t is None:
            t = own
    else:
        for flag in ("load_column", "time_column", "loads_offset"):
            if getattr(args, flag, None) is not None:
                raise ValueError(f"--{flag.replace('_', '-')} needs --loads")
        ld, lu, t = state_loads(result)
    return result, src, ps, unit, ld, lu, t


def gauge_of(args, result, ps, unit, ld, lu, t, **extra):
    from ..post import gauge

    return gauge(result, region=args.region, point=args.point,
                 polygon=polygon_option(args.polygon), pixel_size=ps, unit=unit,
                 px=ps is None, load=ld, load_unit=lu, time=t, **extra)
