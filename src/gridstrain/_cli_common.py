"""Options and helpers shared by the sub-commands (command-line layer only)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from .lattice import Lattice, detect_lattice


def add_lattice_options(p) -> None:
    """``--pitch/--angle`` or ``--k1/--k2``; automatic detection otherwise."""
    g = p.add_argument_group("lattice (default: detected on the reference)")
    g.add_argument("--pitch", type=float, help="grid pitch, px")
    g.add_argument("--angle", type=float, default=None,
                   help="direction of k1, degrees from x towards y (default 0 with --pitch)")
    g.add_argument("--k1", type=float, nargs=2, metavar=("KX", "KY"),
                   help="first wave vector, cycles/px")
    g.add_argument("--k2", type=float, nargs=2, metavar=("KX", "KY"),
                   help="second wave vector, cycles/px")


def lattice_from_args(args, image, *, mask=None) -> Lattice:
    """The lattice the options ask for, or the one detected on ``image``."""
    k1, k2 = getattr(args, "k1", None), getattr(args, "k2", None)
    if (k1 is None) != (k2 is None):
        raise ValueError("--k1 and --k2 must be given together")
    if k1 is not None:
        if args.pitch is not None:
            raise ValueError("give either --pitch/--angle or --k1/--k2, not both")
        return Lattice(tuple(k1), tuple(k2))
    if args.pitch is not None:
        return Lattice.from_pitch(args.pitch, angle=args.angle or 0.0)
    if args.angle is not None:
        raise ValueError("--angle needs --pitch")
    return detect_lattice(image, mask=mask)


def check_output(path, *, overwrite: bool, suffixes=None) -> Path:
    """Refuse an output whose directory is missing, or that exists (no --overwrite)."""
    out = Path(path)
    if suffixes and out.suffix.lower() not in suffixes:
        raise ValueError(f"output {out} must end in one of {', '.join(suffixes)}")
    if not out.parent.exists():
        raise FileNotFoundError(f"output directory {out.parent} does not exist")
    if out.exists() and not overwrite:
        raise FileExistsError(f"output {out} exists; pass --overwrite to replace it")
    return out


def fmt(x: float) -> str:
    """A number for a table: 3 significant digits, NaN as '-'."""
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.3g}"


def print_json(obj) -> None:
    """Write ``obj`` as JSON on stdout."""
    json.dump(obj, sys.stdout, indent=2, default=float)
    sys.stdout.write("\n")
