"""``gridstrain identify``: Young's modulus and Poisson's ratio of a heterogeneous test by
the virtual fields method."""

from __future__ import annotations

import os
from pathlib import Path

from ._common import check_output_file, print_json
from ._post import add_result_options, open_result, reads_result

SUMMARY = ("Young's modulus and Poisson's ratio of a heterogeneous test by the virtual "
           "fields method, with their intervals")


def register(sub) -> None:
    p = sub.add_parser(
        "identify", help=SUMMARY,
        description="The principle of virtual work over the measured region with the "
        "noise-optimal special virtual fields (Avril and Pierron): E and nu of a "
        "linear-elastic isotropic material in plane stress, each with a 95 percent "
        "interval from the strain maps' std (and from the scatter over states when "
        "larger). A state's load is the +x (or +y) component of the resultant force "
        "acting on the specimen through the loaded edge (a tensile test loaded on the "
        "right is positive); the opposite edge is gripped, the two others free. With "
        "loads in N and lengths in mm, moduli are in MPa. A test whose fields cannot "
        "separate E from nu (a uniform shear, an equibiaxial field) is refused.")
    add_result_options(p)
    p.add_argument("--thickness", type=float, required=True, metavar="T",
                   help="the specimen's thickness, in the file's length unit")
    p.add_argument("--loaded-edge", required=True,
                   choices=("left", "right", "top", "bottom"),
                   help="the edge of the region that carries the load (top is row 0)")
    p.add_argument("--load-direction", required=True, choices=("x", "y"),
                   help="the load's component: x along the columns, y down the rows")
    p.add_argument("--region", type=float, nargs=4, metavar=("X0", "Y0", "X1", "Y1"),
                   help="only x0 <= x < x1, y0 <= y < y1 (the file's length unit, px with "
                   "--px; default: the whole valid region); its edges are the loaded, "
                   "gripped and free edges")
    p.add_argument("--px", action="store_true",
                   help="--region in px (the thickness stays in the file's length unit)")
    p.add_argument("--elements", type=int, nargs=2, metavar=("NY", "NX"),
                   help="elements of the virtual fields' mesh along y and x (default: "
                   "about square, 8 along the longer side)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--stress-out", metavar="FILE.npz",
                   help="write the identified stress of every state (sxx, syy, sxy, "
                   "state by row and column, NaN outside the pixels used) as NumPy .npz")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --stress-out file")
    p.set_defaults(func=run)


def _write_stress(path: Path, fit, result, overwrite: bool) -> None:
    import numpy as np

    from ..io import write_atomic

    n = result.n_states
    out = np.empty((n, 3, *result.shape))
    for i in range(n):
        strain = np.stack([np.asarray(result.get_map(k)[i], dtype=np.float64)
                           for k in ("exx", "eyy", "exy")])
        out[i] = fit.stress(strain)
    arrays = {"sxx": out[:, 0], "syy": out[:, 1], "sxy": out[:, 2],
              "states": np.array(fit.states), "unit": np.array(fit.stress_unit),
              "pixel_size": np.array(fit.pixel_size), "length_unit": np.array(fit.unit)}
    write_atomic(path, lambda fh: np.savez_compressed(fh, **arrays), overwrite=overwrite)


@reads_result
def run(args) -> int:
    from ..identify import identify

    result, src, ps, unit, ld, lu, _ = open_result(args, px_drops_scale=False)
    if ps is None:
        raise ValueError(f"{src} has no pixel size: moduli need lengths (measure it with "
                         f"--pixel-size SIZE --unit mm)")
    out = Path(os.path.expanduser(args.stress_out)) if args.stress_out else None
    if out is not None:
        check_output_file(out, "stress file", args.overwrite, {src.resolve()})
    fit = identify(result, thickness=args.thickness, loaded_edge=args.loaded_edge,
                   load_direction=args.load_direction, pixel_size=ps, unit=unit, load=ld,
                   load_unit=lu, region=args.region, px=args.px,
                   elements=args.elements)
    if out is not None:
        _write_stress(out, fit, result, args.overwrite)
    if args.json:
        d = fit.to_dict()
        if out is not None:
            d["stress_out"] = str(out)
        print_json(d)
        return 0
    print(f"E  = {fit.E:.5g} {fit.stress_unit}, 95 % interval [{fit.E_interval[0]:.5g}, "
          f"{fit.E_interval[1]:.5g}]")
    print(f"nu = {fit.nu:.4f}, 95 % interval [{fit.nu_interval[0]:.4f}, "
          f"{fit.nu_interval[1]:.4f}]")
    print(f"{len(fit.states)} states, {fit.n_pixels} px, {fit.elements[0]} x "
          f"{fit.elements[1]} elements; intervals from the {fit.interval_basis}")
    if out is not None:
        print(out)
    return 0
