"""MATLAB export: the maps as ``(H, W, n_states)`` arrays in a version-5 ``.mat`` file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validation import as_path, check_pixel_size, check_type
from ..io import write_atomic
from ._result import MAP_FIELDS, SeriesResult, map_unit


def export_mat(result: SeriesResult, path, *, pixel_size: float | None = None,
               unit: str | None = None, overwrite: bool = False) -> Path:
    """Write the maps to a MATLAB ``.mat`` file (version 5, compressed), atomically.

    Maps are ``(H, W, n_states)`` (``ux(:, :, k)`` is state ``k``, row ``y`` and
    column ``x`` as in the image), NaN where not ``valid`` (a logical array).
    Also ``x``, ``y`` (px), ``x_phys``, ``y_phys`` with a pixel size, ``states``
    (cell array of names), ``units`` (a struct), ``k1``, ``k2`` (cycles/px),
    ``sigma`` (px), ``method``; the derived strains ``e1``, ``e2``,
    ``principal_angle`` (rad), ``equivalent``, ``max_shear``
    (:meth:`SeriesResult.principal_strains`), the finite strains ``gl_xx``...
    ``log_xy`` (:meth:`SeriesResult.finite_strains`, Lagrangian results only) and
    their ``*_std`` and ``rotation_std`` with uncertainty maps; with loads ``load``
    (``n_states`` x 1, its unit in ``units.load``) and with times ``time`` (s).
    """
    from scipy.io import savemat

    check_type(result, "result", SeriesResult)
    ps, unit = check_pixel_size(pixel_size, unit)
    H, W = result.shape

    def hwn(a):
        return np.ascontiguousarray(np.moveaxis(np.asarray(a), 0, -1))

    data = {name: hwn(result.get_map(name)) for name in MAP_FIELDS}
    data["rotation"] = hwn(np.stack([m.rotation for m in result.measurements]))
    data["valid"] = hwn(result.valid)
    units = dict(MAP_FIELDS, rotation="rad", x="px", y="px")
    for name, arr in (result.uncertainty or {}).items():
        data[name] = hwn(arr)
        units[name] = MAP_FIELDS.get(name.removesuffix("_std"), "1")
    derived = result.derived_maps()
    for name, arr in derived.items():
        data[name] = hwn(arr)
        units[name] = map_unit(name)
    if result.load is not None:
        data["load"] = np.asarray(result.load, dtype=np.float64)
        units["load"] = result.load_unit or "1"
    if result.time is not None:
        data["time"] = np.asarray(result.time, dtype=np.float64)
        units["time"] = "s"
    data["x"], data["y"] = np.arange(W, dtype=float), np.arange(H, dtype=float)
    if ps is not None:
        data["x_phys"], data["y_phys"] = data["x"] * ps, data["y"] * ps
        data["ux_phys"], data["uy_phys"] = data["ux"] * ps, data["uy"] * ps
        units.update(x_phys=unit, y_phys=unit, ux_phys=unit, uy_phys=unit)
    data["states"] = np.array(result.names[1:], dtype=object)
    data["units"] = units
    data["k1"], data["k2"] = np.array(result.lattice.k1), np.array(result.lattice.k2)
    data["sigma"], data["method"] = result.sigma, result.method
    data["mask"] = result.mask
    dest = as_path(path, "path")
    # built in memory, then written: a full disk is one line naming the file
    return write_atomic(dest, lambda fh: savemat(fh, data, do_compression=True,
                                                 oned_as="column"), overwrite=overwrite)
