"""CSV export: one row per valid pixel, the unit of each column in its header.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .._validation import check_pixel_size, check_type
from ..io import write_csv
from ._result import MAP_FIELDS, SeriesResult

#: Significant digits of the CSV export: 7 resolves 1e-7 of a value, far below
#: the noise floor of any map (1e-5 strain, 1e-3 px), and keeps the file small.
CSV_DIGITS = 7


def save_csv(result: SeriesResult, path, *, pixel_size: float | None = None,
             unit: str | None = None, overwrite: bool = False,
             digits: int | None = CSV_DIGITS) -> Path:
    """Write one row per valid pixel, with the unit of each column in the header.

    Columns ``state``, ``x [px]``, ``y [px]`` (column and row,
    :mod:`gridstrain.conventions`), with a pixel size ``x [unit]``, ``y [unit]``;
    ``ux [px]``, ``uy [px]`` (and in ``unit``), ``exx [1]``, ``eyy [1]``,
    ``exy [1]`` (dimensionless, tensor shear), ``rotation [rad]``, and the
    uncertainty maps ``ux_std [px]``... when the result has them. ``state``
    holds the state's name. Written atomically.

    Parameters
    ----------
    digits : int or None
        Significant digits of floats (default 7); ``None`` writes each float64 as
        its shortest exact decimal.
    """
    check_type(result, "result", SeriesResult)
    ps, unit = check_pixel_size(pixel_size, unit)
    st, yy, xx = np.nonzero(result.valid)
    cols = {"state": np.array(result.names[1:], dtype=str)[st], "x [px]": xx, "y [px]": yy}
    if ps is not None:
        cols[f"x [{unit}]"], cols[f"y [{unit}]"] = xx * ps, yy * ps
    for name, u in MAP_FIELDS.items():
        cols[f"{name} [{u}]"] = result.get_map(name)[st, yy, xx]
        if ps is not None and u == "px":
            cols[f"{name} [{unit}]"] = result.get_map(name)[st, yy, xx] * ps
    rot = np.stack([m.rotation for m in result.measurements])
    cols["rotation [rad]"] = rot[st, yy, xx]
    for name, arr in (result.uncertainty or {}).items():
        u = MAP_FIELDS.get(name.removesuffix("_std"), "1")
        cols[f"{name} [{u}]"] = np.asarray(arr)[st, yy, xx]
    if ps is not None and re.search(r"[,\"'\r\n\[\]]", unit):
        raise ValueError(f"unit must not contain commas, quotes or brackets for the CSV "
                         f"header, got {unit!r}")
    return write_csv(path, cols, overwrite=overwrite, digits=digits)
