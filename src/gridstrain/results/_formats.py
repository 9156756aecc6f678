"""The export formats of a result, by name.

A format is one module holding its writer, ``(result, path, *, pixel_size, unit,
overwrite) -> Path``, and one entry of :data:`EXPORTS`; :func:`export` and the command
line's ``--export`` read the names and suffixes from there.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .._validation import as_path
from ._csv import save_csv
from ._mat import export_mat
from ._netcdf import export_netcdf
from ._result import SeriesResult
from ._vtk import export_vtk

__all__ = ["EXPORTS", "ExportFormat", "export", "export_path"]


@dataclass(frozen=True)
class ExportFormat:
    """One export format: its name, the suffix of the file it writes and its writer."""

    name: str
    suffix: str
    write: Callable[..., Path]


#: The export formats, by name, in the order the command line lists them.
EXPORTS = {f.name: f for f in (
    ExportFormat("mat", ".mat", export_mat),
    ExportFormat("vtk", ".pvd", export_vtk),
    ExportFormat("csv", ".csv", save_csv),
    ExportFormat("netcdf", ".nc", export_netcdf),
)}


def export_path(stem, name: str) -> Path:
    """The file the format ``name`` writes for ``stem``: ``stem`` and its suffix."""
    stem = as_path(stem, "stem")
    return stem.with_name(stem.name + EXPORTS[name].suffix)


def export(result: SeriesResult, stem, formats, *, pixel_size: float | None = None,
           unit: str | None = None, overwrite: bool = False) -> dict:
    """Write ``stem.mat``, ``stem.pvd`` (with ``stem_vti/``), ``stem.csv`` and/or
    ``stem.nc``; returns ``{format: path}``.

    Each carries the load and time of every state when the result has them, and the
    derived strains (:meth:`SeriesResult.principal_strains`).
    """
    for f in formats:
        if f not in EXPORTS:
            raise ValueError(f"export format must be one of {', '.join(EXPORTS)}, got "
                             f"{f!r}")
    stem = as_path(stem, "stem")
    return {f: EXPORTS[f].write(result, export_path(stem, f), pixel_size=pixel_size,
                                unit=unit, overwrite=overwrite) for f in formats}
