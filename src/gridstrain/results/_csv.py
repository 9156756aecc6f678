"""CSV export: one row per valid pixel, the unit of each column in its header.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validation import check_pixel_size, check_type
from ..io import write_csv
from ._result import MAP_FIELDS, SeriesResult, map_unit

#: Significant digits of the CSV export: 7 resolves 1e-7 of a value, far below
#: the noise floor of any map (1e-5 strain, 1e-3 px), and keeps the file small.
CSV_DIGITS = 7


def save_csv(result: SeriesResult, path, *, pixel_size: float | None = None,
             unit: str | None = None, overwrite: bool = False,
             digits: int | None = CSV_DIGITS) -> Path:
    """Write one row per valid pixel, with the unit of each column in the header.

    Columns ``state`` (the state's name), with loads ``load [UNIT]``, with times
    ``time [s]``, then ``x [px]``, ``y [px]`` (column and row,
    :mod:`gridstrain.conventions`), with a pixel size ``x [unit]``, ``y [unit]``;
    ``ux [px]``, ``uy [px]`` (and in ``unit``), ``exx [-]``, ``eyy [-]``,
    ``exy [-]`` (dimensionless, tensor shear), ``rotation [rad]``, the derived
    strains ``e1 [-]``, ``e2 [-]``, ``principal_angle [rad]``, ``equivalent [-]``,
    ``max_shear [-]`` (:meth:`SeriesResult.principal_strains`), the finite strains
    ``gl_xx [-]``... ``log_xy [-]`` (:meth:`SeriesResult.finite_strains`, Lagrangian
    results only), and the uncertainty maps ``ux_std [px]``..., ``e1_std [-]``...,
    ``gl_xx_std [-]``..., ``rotation_std [rad]`` when the result has them. Written
    atomically by :func:`gridstrain.io.write_csv` (RFC 4180 quoting: names and
    units from other people's files are kept whatever they hold).

    Parameters
    ----------
    digits : int or None
        Significant digits of floats (default 7); ``None`` writes each float64 as
        its shortest exact decimal.
    """
    check_type(result, "result", SeriesResult)
    ps, unit = check_pixel_size(pixel_size, unit)

    def head(name, u):
        # "-" for dimensionless, as the gauge's, the history's and ParaView's columns
        return f"{name} [{'-' if u == '1' else u}]"

    st, yy, xx = np.nonzero(result.valid)
    cols = {"state": np.array(result.names[1:], dtype=str)[st]}
    if result.load is not None:
        cols[head("load", result.load_unit or "1")] = np.asarray(result.load)[st]
    if result.time is not None:
        cols["time [s]"] = np.asarray(result.time)[st]
    cols.update({"x [px]": xx, "y [px]": yy})
    if ps is not None:
        cols[f"x [{unit}]"], cols[f"y [{unit}]"] = xx * ps, yy * ps
    for name, u in MAP_FIELDS.items():
        cols[head(name, u)] = result.get_map(name)[st, yy, xx]
        if ps is not None and u == "px":
            cols[f"{name} [{unit}]"] = result.get_map(name)[st, yy, xx] * ps
    rot = np.stack([m.rotation for m in result.measurements])
    cols["rotation [rad]"] = rot[st, yy, xx]
    derived = result.derived_maps()
    for name, arr in derived.items():
        if not name.endswith("_std"):
            cols[head(name, map_unit(name))] = arr[st, yy, xx]
    for name, arr in (result.uncertainty or {}).items():
        u = MAP_FIELDS.get(name.removesuffix("_std"), "1")
        cols[head(name, u)] = np.asarray(arr)[st, yy, xx]
    for name, arr in derived.items():
        if name.endswith("_std"):
            cols[head(name, map_unit(name))] = arr[st, yy, xx]
    return write_csv(path, cols, overwrite=overwrite, digits=digits)
