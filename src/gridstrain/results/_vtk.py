"""ParaView export: the states as a ``.pvd`` time series of ``.vti`` images.
"""

from __future__ import annotations

from pathlib import Path

from ._result import SeriesResult


def export_vtk(result: SeriesResult, path, *, pixel_size: float | None = None,
               unit: str | None = None, overwrite: bool = False) -> Path:
    """Write the states as a ParaView time series (``.pvd`` and a folder of ``.vti``).

    See :func:`gridstrain.results.export_pvd`: one ``.vti`` per state as a time step
    (time, else load, else index), the displacement as one vector in ``unit``,
    the image upright in ParaView, units in the field names.
    """
    from ._paraview import export_pvd

    return export_pvd(result, path, pixel_size=pixel_size, unit=unit, overwrite=overwrite)
