"""NetCDF export: a clean NetCDF-4 copy of a result, for xarray, netCDF tools and
MATLAB's ``ncread``.
"""

from __future__ import annotations

from pathlib import Path

from .._validation import as_path, check_pixel_size, check_type
from ..io import hdf5_file
from ._layout import _var, _write_dimensions, _write_maps, _write_tables
from ._result import SeriesResult, map_unit

_DERIVED_NAMES = {"e1": "major principal strain", "e2": "minor principal strain",
                  "principal_angle": "direction of e1 from +x towards +y (rows down)",
                  "equivalent": "von Mises equivalent strain (incompressible)",
                  "max_shear": "maximum in-plane tensor shear (e1 - e2) / 2",
                  "gl_xx": "Green-Lagrange strain E_xx", "gl_yy": "Green-Lagrange strain E_yy",
                  "gl_xy": "Green-Lagrange strain E_xy (tensor shear)",
                  "log_xx": "logarithmic (Hencky) strain, xx",
                  "log_yy": "logarithmic (Hencky) strain, yy",
                  "log_xy": "logarithmic (Hencky) strain, xy (tensor shear)",
                  "rotation": "rotation"}


def export_netcdf(result: SeriesResult, path, *, pixel_size: float | None = None,
                  unit: str | None = None, overwrite: bool = False) -> Path:
    """Write the result's variables to a NetCDF-4 file, atomically.

    The variables, dimensions, coordinates (``load`` and ``time`` along ``state``
    when known) and attributes of :func:`save_result`'s layout (described in
    :mod:`gridstrain.results`), plus the derived strains ``e1``, ``e2``,
    ``principal_angle`` (rad), ``equivalent``, ``max_shear`` ``(state, y, x)``
    (:meth:`SeriesResult.principal_strains`), the finite strains ``gl_xx``...
    ``log_xy`` (:meth:`SeriesResult.finite_strains`, Lagrangian results only) and their
    ``*_std`` and ``rotation_std`` with uncertainty maps; without the ``gridstrain``
    group that lets :func:`load` rebuild the result object: ``xarray.open_dataset(path)``
    (engine ``h5netcdf``) sees nothing it
    cannot read.
    """
    check_type(result, "result", SeriesResult)
    ps, unit = check_pixel_size(pixel_size, unit)
    H, W = result.shape
    dest = as_path(path, "path")
    with hdf5_file(dest, overwrite=overwrite) as h5:
        _write_dimensions(h5, result, H, W)
        # the values as the result holds them: an export rounds nothing again
        _write_maps(h5, result, ps, unit, H, W, lossless=True)
        extra = {"coordinates": "x_phys y_phys"} if ps is not None else {}
        for name, arr in result.derived_maps().items():
            base = name.removesuffix("_std")
            text = _DERIVED_NAMES[base] if name == base else \
                f"first-order standard deviation of {base} (1 sigma; the displacement " \
                "gradient's noises uncorrelated)"
            _var(h5, name, arr, ("state", "y", "x"), map_unit(name), text, **extra)
        _write_tables(h5, result, ps, unit, {}, len(result.names), lossless=True)
    return dest
