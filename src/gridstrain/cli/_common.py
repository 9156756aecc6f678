"""Options and helpers shared by the sub-commands (command-line layer only)."""

from __future__ import annotations

import contextlib
import json
import logging
import math
import sys
from pathlib import Path

from .._validation import check_positive
from ..io._files import _check_destination
from ..lattice import Lattice


def add_lattice_options(group) -> None:
    """``--pitch/--angle`` or ``--k1/--k2`` (automatic detection when absent)."""
    group.add_argument("--pitch", type=float, metavar="PX",
                       help="grid pitch, px (default: detected on the reference)")
    group.add_argument("--angle", type=float, metavar="DEG",
                       help="grid angle, degrees (with --pitch; default 0)")
    group.add_argument("--k1", type=float, nargs=2, metavar=("KX", "KY"),
                       help="first wave vector, cycles/px (with --k2, instead of --pitch)")
    group.add_argument("--k2", type=float, nargs=2, metavar=("KX", "KY"),
                       help="second wave vector, cycles/px")


def positive_option(opts: dict, name: str) -> None:
    """Refuse ``--name`` unless it is absent or a finite positive number."""
    if opts.get(name) is not None:
        check_positive(opts[name], f"--{name}")


def lattice_option(opts: dict) -> Lattice | None:
    """The lattice the options give, or None to detect it."""
    has_pitch = opts.get("pitch") is not None
    k1, k2 = opts.get("k1"), opts.get("k2")
    if has_pitch and (k1 is not None or k2 is not None):
        raise ValueError("give the grid either by --pitch (and --angle) or by --k1 and "
                         "--k2, not both")
    if (k1 is None) != (k2 is None):
        raise ValueError("--k1 and --k2 go together: give both wave vectors")
    if opts.get("angle") is not None and not has_pitch:
        raise ValueError("--angle needs --pitch")
    if has_pitch:
        positive_option(opts, "pitch")
        if opts["pitch"] <= 2:
            raise ValueError(f"--pitch must be above 2 px (the Nyquist limit), got "
                             f"{opts['pitch']:g}")
        return Lattice.from_pitch(opts["pitch"], angle=float(opts.get("angle") or 0.0))
    if k1 is not None:
        try:
            return Lattice(tuple(k1), tuple(k2))
        except ValueError as exc:
            raise ValueError(f"--k1/--k2: {exc}") from None
    return None


def check_output_file(path: Path, what: str, overwrite: bool, inputs=frozenset()) -> None:
    """Refuse, before any work, an output that would fail or clobber at the end."""
    if path.resolve() in inputs:
        raise ValueError(f"{what} {path} is one of the input files; inputs are never "
                         "modified")
    _check_destination(path, overwrite, what=what, how="--overwrite")


@contextlib.contextmanager
def quiet_dask_logs():
    """Dask's own log records off while a command runs (restored after).

    A lost scheduler makes ``distributed`` log dozens of lines of tracebacks; the
    command says what happened in one line instead. Imports ``distributed``
    first, whose configuration sets the levels of its loggers on import.
    """
    with contextlib.suppress(ImportError):  # the command says which extra is missing
        import distributed  # noqa: F401
    names = [n for n in list(logging.root.manager.loggerDict)
             if n.split(".")[0] in ("distributed", "tornado")]
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", *names)]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def xy_pairs(values, option: str) -> list[list[float]]:
    """``["x,y", ...]`` from the command line as ``[[x, y], ...]``; ``option`` names it."""
    out = []
    for v in values:
        try:
            x, y = (float(c) for c in v.split(","))
        except ValueError:
            raise ValueError(f"{option} vertices must be x,y pairs such as 10,20, got "
                             f"{v!r}") from None
        out.append([x, y])
    return out


def fmt(x: float) -> str:
    """A number for a table: 3 significant digits, NaN as '-'."""
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.3g}"


def print_json(obj) -> None:
    """Write ``obj`` as JSON on stdout."""
    json.dump(obj, sys.stdout, indent=2, default=float)
    sys.stdout.write("\n")
