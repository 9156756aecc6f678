"""Result files: a self-describing HDF5 (NetCDF-4) file, reloaded exactly, and exports.

The file
    :func:`save_result` writes one HDF5 file in the NetCDF-4 data model (CF-1.10
    conventions), written with ``h5py`` dimension scales, so that
    ``xarray.open_dataset(path)`` (engine ``h5netcdf``) opens it directly:

    - dimensions ``state`` (the loaded states, labelled after their folder or file,
      ``"state i"`` for arrays), ``y`` and ``x`` (rows and columns, px,
      :mod:`gridstrain.conventions`), ``series`` (the reference then the states),
      ``frame``, ``u_component`` (``ux, uy``),
      ``strain_component`` (``exx, eyy, exy``), ``wave_vector`` (``k1, k2``) and
      ``axis`` (``x, y``);
    - coordinates ``x``, ``y`` in px and, with a pixel size, ``x_phys``,
      ``y_phys`` in its unit; with loads or times, ``load`` (its unit) and ``time``
      (s) along ``state``;
    - maps ``(state, y, x)``: ``ux``, ``uy`` (px), ``exx``, ``eyy``, ``exy``
      (``"1"``: strain is dimensionless), ``rotation`` (rad), ``valid`` (bool),
      the per-pixel uncertainty maps ``*_std`` and, with a pixel size,
      ``ux_phys``, ``uy_phys``; ``reference_image`` and ``mask`` ``(y, x)``. By
      default the float maps are float32, each rounded to a tenth of its own std at
      each pixel (the std maps to 5 mantissa bits) and compressed, the rounding in
      each variable's ``rounding*`` attributes; ``lossless=True`` stores them as
      measured (:func:`save_result`);
    - the vibrations (``vibration_shifts (series, frame, axis)``, NaN after the
      last frame of a shorter series, and their standard deviations, contrast
      factors and phase offsets), the noise floor (``noise_*``), the lattice
      (``lattice_k (wave_vector, axis)``) as variables, and the parameters, the
      lattice's pitches and angles, the warnings and the configuration that
      replays the run (``config``, TOML text) as root attributes;
    - the metrological figures per state: ``resolution_u`` (px),
      ``resolution_strain`` (1), ``efficiency_u`` and ``efficiency_strain``
      (px^2), ``systematic_smoothing_strain`` (1), and as root attributes
      ``noise_model_source`` (where the image noise came from),
      ``spatial_resolution_px``, ``step_width_px``, ``systematic_aliasing_u_px``
      and ``systematic_aliasing_strain_per_strain``.

    Every variable has ``units`` and ``long_name``. The group ``gridstrain``
    holds the rest of the :class:`~gridstrain.results.SeriesResult`, field by
    field (every dataclass, dict, tuple and array as HDF5 groups, attributes and
    datasets; no pickle, no JSON), so that :func:`load` returns a result equal
    to the one saved. A field added to a result class is saved and reloaded
    without changes here, as long as it holds arrays, numbers, strings, ``None``,
    tuples, lists, dicts with string keys or dataclasses of these. A list of
    states or series (the measurements, the vibrations, the screening, the metrology
    of each state...) is written by columns, one group for the whole list whatever
    the number of states: each field one attribute or one dataset of a value per
    state (format 3; files of format 2, written value by value, are read too).

Exports
    :func:`export_mat` (MATLAB, ``scipy.io.savemat``), :func:`export_vtk` (VTK
    XML image data ``.vti``, for ParaView), :func:`save_csv` (one row per
    valid pixel, units in the header, RFC 4180 quoting) and :func:`export_netcdf`
    (a clean NetCDF-4 copy, without the ``gridstrain`` group), each in its own module
    and named in one table, :data:`EXPORTS`, that :func:`export`, ``measure
    --export`` and ``gridstrain export`` read. Every export carries the load and time
    of each state when known and the derived strains (``e1``, ``e2``,
    ``principal_angle``, ``equivalent``, ``max_shear``, :data:`DERIVED_FIELDS`).

Modules
    ``_result`` the result type; ``_file`` saving, loading and the file written as
    the states are measured; ``_layout`` the file's variables; ``_codec`` the generic,
    safe codec of the result's fields; ``_formats`` the export registry; ``_mat``,
    ``_vtk``, ``_csv``, ``_netcdf`` one module per export format.
"""

from __future__ import annotations

from ._csv import CSV_DIGITS as CSV_DIGITS
from ._csv import save_csv
from ._file import FORMAT_VERSION, load, read_attrs, save_result, to_xarray
from ._file import ResultFile as ResultFile
from ._file import StoredMaps as StoredMaps

# shared with gridstrain's other folders, not part of the public API
from ._file import StreamedResult as StreamedResult
from ._file import kept_open as kept_open
from ._formats import EXPORTS as EXPORTS
from ._formats import ExportFormat as ExportFormat
from ._formats import export as export
from ._formats import export_path as export_path
from ._layout import LONG_NAMES as LONG_NAMES
from ._loads import state_loads
from ._mat import export_mat
from ._netcdf import export_netcdf
from ._paraview import export_pvd
from ._result import DERIVED_FIELDS as DERIVED_FIELDS
from ._result import FINITE_FIELDS as FINITE_FIELDS
from ._result import MAP_FIELDS as MAP_FIELDS
from ._result import SeriesResult as SeriesResult
from ._result import map_unit as map_unit
from ._vtk import export_vtk

# the file's functions; the result type and the rest of the face (the streamed file,
# the export registry) are importable from here and documented where they belong
__all__ = [
    "FORMAT_VERSION",
    "export_mat",
    "export_netcdf",
    "export_pvd",
    "export_vtk",
    "load",
    "read_attrs",
    "save_csv",
    "save_result",
    "state_loads",
    "to_xarray",
]
