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
      ``ux_phys``, ``uy_phys``; ``reference_image`` and ``mask`` ``(y, x)``;
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
    holds the rest of the :class:`~gridstrain.pipeline.SeriesResult`, field by
    field (every dataclass, dict, tuple and array as HDF5 groups, attributes and
    datasets; no pickle, no JSON), so that :func:`load` returns a result equal
    to the one saved. A field added to a result class is saved and reloaded
    without changes here, as long as it holds arrays, numbers, strings, ``None``,
    tuples, lists, dicts with string keys or dataclasses of these.

Exports
    :func:`export_mat` (MATLAB, ``scipy.io.savemat``), :func:`export_vtk` (VTK
    XML image data ``.vti``, for ParaView) and :func:`save_csv` (one row per
    valid pixel, units in the header).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import re
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from . import __version__
from ._memory import available_memory, format_size
from ._validation import as_path, check_float_dtype, check_mapping, check_type
from .io import hdf5_file, hdf5_stream, provenance, write_atomic, write_csv
from .pipeline import MAP_FIELDS, SeriesResult, _check_pixel_size

__all__ = [
    "FORMAT_VERSION",
    "export_mat",
    "export_vtk",
    "load",
    "read_attrs",
    "save_csv",
    "save_result",
    "to_xarray",
]

#: Version of the file layout; :func:`load` refuses other versions by name.
FORMAT_VERSION = 2
_GROUP = "gridstrain"
_TYPE, _CLASS, _KEYS, _TUPLES, _LISTS = "_type", "_class", "_keys", "_tuple_attrs", "_list_attrs"
_RESERVED = {_TYPE, _CLASS, _KEYS, _TUPLES, _LISTS}

#: Long names of the maps, for the file and the figures.
LONG_NAMES = {
    "ux": "displacement along x (Lagrangian)",
    "uy": "displacement along y (Lagrangian)",
    "exx": "normal strain along x",
    "eyy": "normal strain along y",
    "exy": "shear strain (tensor component)",
    "rotation": "infinitesimal rotation omega = (duy/dx - dux/dy)/2",
    "valid": "pixel measured (window inside the image, the mask and the grid)",
}
_UNC_KEYS = ("ux_std", "uy_std", "exx_std", "eyy_std", "exy_std")
# Fields of the result classes stored as the file's CF variables, not in its group.
_ROOT_FIELDS = {"SeriesResult": ("u", "strain", "valid", "mask", "reference_image",
                                 "uncertainty"),
                "Measurement": ("u", "strain", "rotation", "valid")}
# Lossless filters of the images, masks and tables: gzip is read everywhere. Level 1:
# the 1040 x 1376 reference image in 40 ms and 2.25 MB, against 54 ms and 2.19 MB at
# level 4 (gridstrain.io.write_hdf5's level, for data written once and kept)
_FILTERS = {"compression": "gzip", "compression_opts": 1, "shuffle": True,
            "fletcher32": True}
# The per-state float maps: checksummed, stored as they are (see _create_maps).
_CHECKSUM = {"fletcher32": True}


# --------------------------------------------------------------------------- generic codec


def _check_key(key, where: str) -> str:
    if not isinstance(key, str) or not key or "/" in key or key in (".", "..") \
            or key in _RESERVED:
        raise TypeError(f"{where}: key {key!r} cannot name an HDF5 member (a non-empty "
                        "string without '/', not one of " + ", ".join(sorted(_RESERVED))
                        + ")")
    return key


def _scalar_kind(v) -> str | None:
    if isinstance(v, bool | np.bool_):
        return "b"
    if isinstance(v, numbers.Integral):
        return "i"
    if isinstance(v, numbers.Real):
        return "f"
    if isinstance(v, str):
        return "s"
    return None


def _utf8(text: str) -> str:
    """``text`` storable as UTF-8: a file name's byte that is not UTF-8 (which Python
    decodes as a lone surrogate) is written ``\\xff``, instead of failing the save."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def _array(values: list, kinds: set) -> np.ndarray:
    if kinds == {"s"}:
        return np.array([_utf8(v) for v in values], dtype=h5py.string_dtype())
    if kinds == {"b"}:
        return np.array(values, dtype=bool)
    if kinds == {"i"} and all(-(2**63) <= int(v) < 2**63 for v in values):
        return np.array(values, dtype=np.int64)
    return np.array(values, dtype=np.float64)


def _dataset(group: h5py.Group, key: str, arr: np.ndarray) -> h5py.Dataset:
    if arr.dtype.kind not in "biufc":
        raise TypeError(f"{group.name}/{key}: arrays must be numeric or boolean, got "
                        f"dtype {arr.dtype}")
    opts = dict(_FILTERS, chunks=True) if arr.ndim > 0 and arr.size > 1 else {}
    return group.create_dataset(key, data=arr, **opts)


def _encode(group: h5py.Group, items, memo: dict, skip: Mapping = _ROOT_FIELDS) -> None:
    """Write ``(key, value)`` pairs into ``group`` (see the module docstring);
    ``skip`` names, per class name, the fields not written."""
    tuples, lists = [], []
    for key, value in items:
        _check_key(key, group.name)
        kind = _scalar_kind(value)
        if kind is not None or isinstance(value, os.PathLike):
            if isinstance(value, os.PathLike):
                value = os.fspath(value)
            elif kind == "i" and not -(2**63) <= int(value) < 2**63:
                raise TypeError(f"{group.name}/{key}: integer {value} too large to store")
            group.attrs[key] = {"b": np.bool_, "i": np.int64, "f": np.float64,
                                "s": _utf8}[_scalar_kind(value)](value)
        elif isinstance(value, np.ndarray):
            if id(value) in memo:
                group[key] = h5py.SoftLink(memo[id(value)])
            else:
                memo[id(value)] = _dataset(group, key, value).name
        elif isinstance(value, list | tuple):
            kinds = {_scalar_kind(v) for v in value}
            if value and None not in kinds and (len(kinds) == 1 or kinds <= {"i", "f"}):
                group.attrs[key] = _array(list(value), kinds)
                (tuples if isinstance(value, tuple) else lists).append(key)
            else:
                g = group.create_group(key, track_order=True)
                g.attrs[_TYPE] = "tuple" if isinstance(value, tuple) else "list"
                _encode(g, ((str(i), v) for i, v in enumerate(value)), memo, skip)
        elif value is None:
            group.create_group(key).attrs[_TYPE] = "none"
        elif isinstance(value, Mapping):
            g = group.create_group(key, track_order=True)
            g.attrs[_TYPE] = "dict"
            keys = [_check_key(k, f"{group.name}/{key}") for k in value]
            g.attrs[_KEYS] = np.array(keys, dtype=h5py.string_dtype())
            _encode(g, value.items(), memo, skip)
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            if id(value) in memo:
                group[key] = h5py.SoftLink(memo[id(value)])
                continue
            cls = type(value)
            name = _class_name(cls, f"{group.name}/{key}")
            g = group.create_group(key, track_order=True)
            memo[id(value)] = g.name
            g.attrs[_TYPE] = "dataclass"
            g.attrs[_CLASS] = name
            left = skip.get(cls.__name__, ())
            _encode(g, ((f.name, getattr(value, f.name)) for f in dataclasses.fields(value)
                        if f.init and f.name not in left), memo, skip)
        elif isinstance(value, np.generic):
            group.attrs[key] = value
        else:
            raise TypeError(f"{group.name}/{key}: cannot store a {type(value).__name__} "
                            "(arrays, numbers, strings, None, tuples, lists, dicts and "
                            "dataclasses are stored)")
    if tuples:
        group.attrs[_TUPLES] = np.array(tuples, dtype=h5py.string_dtype())
    if lists:
        group.attrs[_LISTS] = np.array(lists, dtype=h5py.string_dtype())


def _plain(v):
    if isinstance(v, bytes):
        return v.decode("utf-8")
    if isinstance(v, np.ndarray):
        return [_plain(x) for x in v.tolist()] if v.dtype.kind == "O" else v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


def _names(group, attr) -> list[str]:
    return [_plain(x) for x in group.attrs[attr]] if attr in group.attrs else []


# --------------------------------------------------------------------------- reading safely


class _Bad(ValueError):
    """A result file that does not hold what its layout says, at one field."""


def _where(obj, field: str | None = None) -> str:
    """``FILE: /group/field``, the place a message names."""
    name = obj.name if field is None else f"{obj.name.rstrip('/')}/{field}"
    return f"{obj.file.filename}: {name}"


def _attr(obj, key: str):
    """An attribute of ``obj`` as a plain value: a bool, number or string, or a list of
    them; anything else (references, compound or opaque types) is refused."""
    try:
        raw = obj.attrs[key]
    except (OSError, TypeError, ValueError):  # a type h5py cannot read
        raise _Bad(f"{_where(obj, key)}: attribute of an unreadable type") from None
    if isinstance(raw, np.ndarray) and raw.ndim > 1:
        raise _Bad(f"{_where(obj, key)}: attribute must be a value or a list of values, "
                   f"got an array of shape {raw.shape}")
    kind = getattr(raw, "dtype", np.dtype(object)).kind
    if isinstance(raw, np.ndarray | np.generic) and kind not in "biuf" and not (
            kind == "O" and all(isinstance(x, str | bytes) for x in np.ravel(raw))):
        raise _Bad(f"{_where(obj, key)}: attribute of dtype {raw.dtype}, not a number, "
                   "boolean or string")
    try:
        return _plain(raw)
    except UnicodeDecodeError:
        raise _Bad(f"{_where(obj, key)}: attribute is not UTF-8 text") from None


def _member(group: h5py.Group, key: str):
    """``group[key]``, never through an external link (another file), a link that
    leads nowhere, or a dataset whose data lie outside the file."""
    link = group.get(key, getlink=True)
    if isinstance(link, h5py.ExternalLink):
        raise _Bad(f"{_where(group, key)}: a link to another file ({link.filename}); a "
                   "result file is read alone")
    try:
        obj = group[key]
    except (KeyError, OSError):
        raise _Bad(f"{_where(group, key)}: a link to nothing") from None
    if isinstance(obj, h5py.Dataset) and (obj.external or obj.is_virtual):
        raise _Bad(f"{_where(group, key)}: a dataset stored outside the file; a result "
                   "file is read alone")
    if not isinstance(obj, h5py.Dataset | h5py.Group):
        raise _Bad(f"{_where(group, key)}: not a dataset or a group")
    return obj


def _check_memory(path, needed: int, what: str) -> None:
    """Refuse, before reading, data that cannot fit in the memory left."""
    avail, source = available_memory()
    if needed > avail:
        raise _Bad(f"{path}: {what} need {format_size(needed)} of memory, more than the "
                   f"{format_size(avail)} available ({source})")


def _read_dataset(ds: h5py.Dataset, *, kinds: str = "biufc") -> np.ndarray:
    """A dataset's values, once its dtype is known to be a plain number or boolean."""
    if ds.dtype.kind not in kinds or ds.dtype.fields is not None or ds.dtype.subdtype:
        raise _Bad(f"{_where(ds)}: dtype {ds.dtype}, expected "
                   + ("booleans" if kinds == "b" else "numbers"))
    try:
        return np.asarray(ds[()])
    except OSError as exc:  # a checksum or a filter that fails: a damaged file
        raise _Bad(f"{_where(ds)}: cannot be read ({exc})") from None


def _registry() -> dict[str, type]:
    """The classes a result file may hold, by the name it stores. Nothing else is
    built from a file, and no name read from one is ever imported."""
    from ._wft import PhaseMaps
    from .kinematics import FringeOrder, Measurement
    from .lattice import Lattice
    from .screening import FrameScreen, Trend
    from .uncertainty import NoiseFloor
    from .vibration import VibrationReport

    return {
        "gridstrain.pipeline.SeriesResult": SeriesResult,
        "gridstrain.kinematics.Measurement": Measurement,
        "gridstrain.kinematics.FringeOrder": FringeOrder,
        "gridstrain.lattice.Lattice": Lattice,
        "gridstrain.screening.FrameScreen": FrameScreen,
        "gridstrain.screening.Trend": Trend,
        "gridstrain.uncertainty.NoiseFloor": NoiseFloor,
        "gridstrain.vibration.VibrationReport": VibrationReport,
        "gridstrain._wft.PhaseMaps": PhaseMaps,
    }


def _qualname(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _subclasses(classes):
    for cls in classes:
        yield cls
        yield from _subclasses(cls.__subclasses__())


def _class_named(name: str):
    """The registered class stored as ``name``, or a subclass of one that the running
    program has defined already (a result class extended by its user); None if none.
    Looked up among classes that exist, never imported."""
    registry = _registry()
    if name in registry:
        return registry[name]
    for cls in _subclasses(registry.values()):
        if _qualname(cls) == name and dataclasses.is_dataclass(cls):
            return cls
    return None


def _class_name(cls: type, where: str) -> str:
    """The name under which a dataclass is stored; refused unless :func:`load` can
    build it again."""
    for name, registered in _registry().items():
        if registered is cls:
            return name
    if _class_named(_qualname(cls)) is cls:
        return _qualname(cls)
    raise TypeError(f"{where}: cannot store a {_qualname(cls)}: a result file holds only "
                    "gridstrain's result classes and their subclasses")


def _fits(value, hint) -> bool:
    """Whether ``value`` has the type annotated ``hint`` (the annotations of the result
    classes: numbers, strings, arrays, tuples, dicts, optionals, dataclasses); an
    annotation not understood here accepts anything."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, a) for a in args)
    if hint is type(None):
        return value is None
    if hint is typing.Any:
        return True
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if hint is np.ndarray:
        return isinstance(value, np.ndarray)
    if origin is tuple or hint is tuple:
        if not isinstance(value, tuple):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(_fits(v, args[0]) for v in value)
        return not args or (len(args) == len(value)
                            and all(_fits(v, a) for v, a in zip(value, args, strict=True)))
    if origin is dict or hint is dict:
        return isinstance(value, dict)
    if origin is list or hint is list:
        return isinstance(value, list)
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return isinstance(value, hint)
    return True


def _check_fields(cls, group, values: dict) -> None:
    """The fields stored in ``group``: none unknown, each of its annotated type."""
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(values) - fields)
    if unknown:
        raise _Bad(f"{_where(group)} holds fields {', '.join(unknown)} that this "
                   f"gridstrain's {cls.__name__} does not have (written by a newer "
                   "version?)")
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # annotations this module cannot resolve: no check
        hints = {}
    for key, value in values.items():
        if key in hints and not _fits(value, hints[key]):
            raise _Bad(f"{_where(group, key)}: expected {_hint_text(hints[key])}, got "
                       f"{_received(value)}")


def _hint_text(hint) -> str:
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")


def _received(value) -> str:
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    text = repr(value)
    return f"{type(value).__name__} {text[:60] + '...' if len(text) > 60 else text}"


_KINDS = ("none", "tuple", "list", "dict", "dataclass")
_READING = object()  # the mark of a group being decoded, to refuse links in a cycle


def _decode(group: h5py.Group, memo: dict, fill):
    """The object written by :func:`_encode` into ``group``, each value checked: a
    class only from the registry (:func:`_registry`), each field of its annotated
    type, datasets of numbers, no link out of the file, no cycle."""
    if not isinstance(group, h5py.Group):
        raise _Bad(f"{_where(group)}: a dataset where a group is expected")
    kind = _attr(group, _TYPE) if _TYPE in group.attrs else "dict"
    if kind not in _KINDS:
        raise _Bad(f"{_where(group, _TYPE)}: {kind!r} is not one of {', '.join(_KINDS)}")
    if kind == "none":
        return None
    tuples = set(_names(group, _TUPLES))
    values = {}
    for key in group.attrs:
        if key in _RESERVED:
            continue
        v = _attr(group, key)
        values[key] = tuple(v) if key in tuples and isinstance(v, list) else v
    for key in group:
        if key in values:
            raise _Bad(f"{_where(group, key)}: stored twice (an attribute and a member)")
        link = group.get(key, getlink=True)
        obj = _member(group, key)
        target = link.path if isinstance(link, h5py.SoftLink) else obj.name
        if memo.get(target) is _READING:
            raise _Bad(f"{_where(group, key)}: a link to a group that holds it (a cycle)")
        if target not in memo:
            memo[target] = _READING
            if isinstance(obj, h5py.Dataset):
                memo[target] = _read_dataset(obj)
            else:
                memo[target] = _decode(obj, memo, fill)
        values[key] = memo[target]
    if kind in ("tuple", "list"):
        try:
            seq = [values[str(i)] for i in range(len(values))]
        except KeyError:
            raise _Bad(f"{_where(group)}: a {kind} whose members are not named 0, 1, "
                       "...") from None
        return tuple(seq) if kind == "tuple" else seq
    if kind == "dict":
        keys = _names(group, _KEYS)
        if sorted(keys) != sorted(values):
            raise _Bad(f"{_where(group, _KEYS)}: lists {sorted(keys)}, the group holds "
                       f"{sorted(values)}")
        return {k: values[k] for k in keys}
    if _CLASS not in group.attrs:
        raise _Bad(f"{_where(group, _CLASS)}: missing")
    qualname = _attr(group, _CLASS)
    cls = _class_named(qualname) if isinstance(qualname, str) else None
    if cls is None:
        raise _Bad(f"{_where(group, _CLASS)}: {qualname!r} is not a class a result file "
                   "may hold (" + ", ".join(_registry()) + ")")
    _check_fields(cls, group, values)
    values = fill(cls, group, values)
    missing = [f.name for f in dataclasses.fields(cls) if f.init and f.name not in values
               and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:
        raise _Bad(f"{_where(group, missing[0])}: missing (a {cls.__name__} needs it)")
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise _Bad(f"{_where(group)}: not a valid {cls.__name__} ({exc})") from None


# --------------------------------------------------------------------------- save


def _var(h5, name, data, dims, units, long_name, **attrs) -> h5py.Dataset:
    arr = np.asarray(data)
    ds = _dataset(h5, name, arr) if arr.dtype.kind != "O" else \
        h5.create_dataset(name, data=arr.astype(h5py.string_dtype()))
    return _describe(ds, dims, units, long_name, **attrs)


def _describe(ds, dims, units, long_name, **attrs) -> h5py.Dataset:
    """Attach the dimensions ``dims`` (variables of the file) and the CF attributes."""
    h5 = ds.file
    for i, d in enumerate(dims):
        ds.dims[i].attach_scale(h5[d])
    if units is not None:
        ds.attrs["units"] = units
    ds.attrs["long_name"] = long_name
    for k, v in attrs.items():
        ds.attrs[k] = v
    return ds


def _dim(h5, name, values, units, long_name) -> None:
    arr = np.asarray(values)
    if arr.dtype.kind in "US":
        ds = h5.create_dataset(name, data=arr.astype(h5py.string_dtype()))
    else:
        ds = h5.create_dataset(name, data=arr)
    ds.make_scale(name)
    if units is not None:
        ds.attrs["units"] = units
    ds.attrs["long_name"] = long_name


def _root_attr(value):
    """A root attribute value: native scalars, strings and arrays, never JSON."""
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    kind = _scalar_kind(value)
    if kind is not None:
        return {"b": np.bool_, "i": np.int64, "f": np.float64, "s": _utf8}[kind](value)
    if isinstance(value, list | tuple) and value:
        kinds = {_scalar_kind(v) for v in value}
        if None not in kinds and (len(kinds) == 1 or kinds <= {"i", "f"}):
            return _array(list(value), kinds)
    if isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
        return value
    return None


def save_result(result: SeriesResult, path, *, pixel_size: float | None = None,
                unit: str | None = None, overwrite: bool = False,
                attrs: Mapping | None = None, phase_maps: bool = False) -> Path:
    """Write a :class:`~gridstrain.pipeline.SeriesResult` to one HDF5 file, atomically.

    Parameters
    ----------
    result : SeriesResult
    path : str or os.PathLike
        Destination (``.h5`` or ``.nc``).
    pixel_size : float, optional
        Size of a pixel on the specimen, in ``unit``: adds ``x_phys``, ``y_phys``,
        ``ux_phys`` and ``uy_phys``.
    unit : str, optional
        Length unit of ``pixel_size`` (``"mm"``...); required with it.
    overwrite : bool
        Replace an existing file.
    attrs : dict, optional
        Extra root attributes (``config``, the mask file...): strings, numbers,
        lists of them; a dict or any other value is stored in the group
        ``gridstrain/attrs`` instead.
    phase_maps : bool
        Also store the phase maps of every series (``Measurement.reference`` and
        ``.deformed``: ``Psi`` and its derivatives, eight maps per series, which
        triples the file). Without them :func:`load` gives those two fields as
        ``None``; every other field comes back equal.

    Returns
    -------
    pathlib.Path

    Notes
    -----
    The layout is described in :mod:`gridstrain.results`; ``xarray.open_dataset``
    opens it, :func:`load` reads it back.
    """
    check_type(result, "result", SeriesResult)
    ps, unit = _check_pixel_size(pixel_size, unit)
    attrs = check_mapping(attrs, "attrs", allow_none=True)
    H, W = result.shape
    n_series = len(result.names)
    with hdf5_file(path, overwrite=overwrite) as h5:
        _write_dimensions(h5, result, H, W)
        _write_maps(h5, result, ps, unit, H, W)
        _write_tables(h5, result, ps, unit, attrs, n_series)
        _write_group(h5, result, attrs, phase_maps=phase_maps)
    return as_path(path, "path")


def _write_group(h5, result, attrs: Mapping, *, phase_maps: bool) -> None:
    """The ``gridstrain`` group: the whole result, less the maps of the root."""
    g = h5.create_group(_GROUP, track_order=True)
    g.attrs["format_version"] = np.int64(FORMAT_VERSION)
    memo: dict = {}
    skip = dict(_ROOT_FIELDS)
    if not phase_maps:
        skip["Measurement"] = (*skip["Measurement"], "reference", "deformed")
    g.attrs["phase_maps"] = bool(phase_maps)
    _encode(g, [("result", result)], memo, skip)
    extra = [(k, v) for k, v in attrs.items() if _root_attr(v) is None]
    if extra:
        _encode(g, [("attrs", dict(extra))], memo)


def _write_tables(h5, result, ps, unit, attrs: Mapping, n_series: int) -> None:
    """The variables of the series and states (vibrations, noise floor, metrology) and
    the root attributes (see the module's layout)."""
    lat = result.lattice
    _write_vibrations(h5, result, n_series)
    _write_noise(h5, result, lat)
    _write_metrology(h5, result)
    root = _root_attributes(result, ps, unit, lat)
    for key, value in attrs.items():
        root[_check_key(key, "attrs")] = value
    for key, value in root.items():
        stored = _root_attr(value)
        if stored is not None:
            h5.attrs[key] = stored


def _write_dimensions(h5, result, H: int, W: int) -> None:
    """The coordinate variables every other variable is laid out on."""
    T = max(result.n_frames)
    _dim(h5, "state", np.array(result.names[1:]), None, "loaded state")
    _dim(h5, "y", np.arange(H, dtype=np.float64), "px", "row (y, downwards)")
    _dim(h5, "x", np.arange(W, dtype=np.float64), "px", "column (x, to the right)")
    _dim(h5, "series", np.array(result.names), None, "image series (reference first)")
    _dim(h5, "frame", np.arange(T, dtype=np.int64), "1", "frame index in its series")
    _dim(h5, "u_component", np.array(["ux", "uy"]), None, "displacement component")
    _dim(h5, "strain_component", np.array(["exx", "eyy", "exy"]), None,
         "strain component")
    _dim(h5, "wave_vector", np.array(["k1", "k2"]), None, "wave vector of the grid")
    _dim(h5, "axis", np.array(["x", "y"]), None, "image axis")
    _write_state_coordinates(h5, result)


def _write_state_coordinates(h5, result) -> None:
    """The load and time of each state, as coordinates along ``state`` (named in the
    root ``coordinates`` attribute, which xarray reads)."""
    names = []
    if result.load is not None:
        _var(h5, "load", result.load, ("state",), result.load_unit or "1",
             "load applied to the specimen in each state")
        names.append("load")
    if result.time is not None:
        _var(h5, "time", result.time, ("state",), "s", "time of each state")
        names.append("time")
    if names:
        h5.attrs["coordinates"] = " ".join(names)


_MAPS = ("state", "y", "x")


def _map_specs(unc_names) -> list[tuple[str, str | None, str, dict]]:
    """``(name, units, long name, extra attributes)`` of every per-state map."""
    out = [(name, u, LONG_NAMES[name], {}) for name, u in MAP_FIELDS.items()]
    out.append(("rotation", "rad", LONG_NAMES["rotation"], {}))
    out.append(("valid", None, LONG_NAMES["valid"], {}))
    for name in unc_names:
        base = name.removesuffix("_std")
        out.append((name, MAP_FIELDS.get(base, "1"),
                    f"predicted standard deviation of {base} (1 sigma)",
                    {"uncertainty_of": base}))
    return out


def _state_arrays(res, unc: dict | None) -> dict[str, np.ndarray]:
    """The maps of one state, by variable name."""
    out = {name: res.u[j] for j, name in enumerate(("ux", "uy"))}
    out.update({name: res.strain[j] for j, name in enumerate(("exx", "eyy", "exy"))})
    out["rotation"], out["valid"] = res.rotation, res.valid
    out.update(unc or {})
    return out


def _describe_maps(h5, ps, unit, H: int, W: int, unc_names) -> None:
    """Attach the dimensions and the CF attributes to the per-state maps (created
    already), and write the coordinates in physical units."""
    coords = ""
    if ps is not None:
        _var(h5, "x_phys", np.arange(W) * ps, ("x",), unit, "x on the specimen")
        _var(h5, "y_phys", np.arange(H) * ps, ("y",), unit, "y on the specimen")
        coords = "x_phys y_phys"
    extra = {"coordinates": coords} if coords else {}
    specs = _map_specs(unc_names)
    if ps is not None:
        specs += [(f"{n}_phys", unit, LONG_NAMES[n], {}) for n in ("ux", "uy")]
    for name, units, long_name, more in specs:
        _describe(h5[name], _MAPS, units, long_name, **more, **extra)


def _write_maps(h5, result, ps, unit, H: int, W: int) -> None:
    """Maps of every state (px values, and physical ones with a pixel size), their
    predicted standard deviations, the mean reference frame and the mask."""
    unc = result.uncertainty or {}
    for k, m in enumerate(result.measurements):
        arrays = _state_arrays(m, {n: a[k] for n, a in unc.items()})
        if k == 0:
            _create_maps(h5, arrays, result.n_states, ps)
        _put_state(h5, k, arrays, ps)
    _describe_maps(h5, ps, unit, H, W, list(unc))
    _write_images(h5, result, ps)


def _write_images(h5, result, ps) -> None:
    """The mean reference frame and the mask."""
    extra = {"coordinates": "x_phys y_phys"} if ps is not None else {}
    _var(h5, "reference_image", result.reference_image, ("y", "x"), "1",
         "mean reference frame, raw grey levels", **extra)
    _var(h5, "mask", result.mask, ("y", "x"), None,
         "specimen mask used (given mask less regions without a grid)", **extra)


def _create_maps(h5, arrays: dict, n: int, ps, dtype=None) -> None:
    """Empty (n, H, W) variables for the maps of ``arrays`` (one state's), chunked by
    state and compressed; NaN (False for ``valid``) until a state is written."""
    for name, arr in arrays.items():
        if name in h5:
            continue
        dt = np.dtype(bool) if arr.dtype == bool else np.dtype(dtype or arr.dtype)
        fill = False if dt.kind == "b" else np.nan
        # the measured maps' lower bytes are noise: deflating them took 0.2 s a map
        # of 1040 x 1376 for 12 % of its size; the validity maps shrink 100-fold
        filters = _FILTERS if dt.kind == "b" else _CHECKSUM
        h5.create_dataset(name, shape=(n, *arr.shape), dtype=dt, chunks=(1, *arr.shape),
                          fillvalue=fill, **filters)
        if ps is not None and name in ("ux", "uy"):
            h5.create_dataset(f"{name}_phys", shape=(n, *arr.shape), dtype=dt,
                              chunks=(1, *arr.shape), fillvalue=np.nan, **_CHECKSUM)


def _put_state(h5, k: int, arrays: dict, ps) -> None:
    """Write state ``k``'s maps into the variables of :func:`_create_maps`."""
    for name, arr in arrays.items():
        h5[name][k] = arr
        if ps is not None and name in ("ux", "uy"):
            h5[f"{name}_phys"][k] = np.asarray(arr) * ps


def _write_vibrations(h5, result, n_series: int) -> None:
    """The frame shifts of every series and their statistics."""
    T = max(result.n_frames)
    # vibrations, padded with NaN after the last frame of a shorter series
    shifts = np.full((n_series, T, 2), np.nan)
    for i, v in enumerate(result.vibration):
        shifts[i, :v.n_frames] = v.shifts
    _var(h5, "vibration_shifts", shifts, ("series", "frame", "axis"), "px",
         "rigid translation (alpha_t, beta_t) of each frame, series mean removed; frame "
         "t is s(x + alpha_t, y + beta_t) (paper eq. 2)")
    _var(h5, "n_frames", np.array(result.n_frames, dtype=np.int64), ("series",), "1",
         "frames in the series")
    _var(h5, "vibration_std", np.array([v.std for v in result.vibration]),
         ("series", "axis"), "px", "standard deviation of the frame shifts")
    _var(h5, "vibration_contrast_factor",
         np.array([v.contrast_factor for v in result.vibration]), ("series", "wave_vector"),
         "1", "modulus kept by averaging (paper Prop. 2.2)")
    _var(h5, "vibration_phase_offset_std",
         np.array([v.phase_offset_std for v in result.vibration]),
         ("series", "wave_vector"), "rad", "std of the vibration phase offset (eq. 31)")


def _write_noise(h5, result, lat) -> None:
    """The noise floor of every state, the sensor noise and modulus of every series,
    and the wave vectors."""
    nf = result.noise
    for name, dims, u, text in (
            ("theory_u", ("state", "u_component"), "px", "noise floor, theory"),
            ("theory_strain", ("state", "strain_component"), "1", "noise floor, theory"),
            ("split_u", ("state", "u_component"), "px",
             "noise floor, reference halves scaled"),
            ("split_strain", ("state", "strain_component"), "1",
             "noise floor, reference halves scaled"),
            ("vibration_u", ("state", "u_component"), "px",
             "std of the rigid vibration offset of the displacement")):
        _var(h5, f"noise_{name}", getattr(nf, name), dims, u, f"{text} (1 std at a pixel)")
    _var(h5, "noise_sensor_variance", np.array(nf.sensor_variance, dtype=float),
         ("series",), "1", "per-frame image noise variance, raw grey levels^2")
    _var(h5, "noise_modulus", nf.modulus, ("series", "wave_vector"), "1",
         "median modulus |Psi| of the phase maps, raw grey levels")
    _var(h5, "lattice_k", np.array([lat.k1, lat.k2]), ("wave_vector", "axis"),
         "cycles/px", "wave vectors of the grid")


def _root_attributes(result, ps, unit, lat) -> dict:
    """The file's root attributes (CF and gridstrain's), before the caller's ``attrs``."""
    nf = result.noise
    root = {
        "Conventions": "CF-1.10",
        "title": "gridstrain displacement and strain maps",
        "source": f"gridstrain {__version__}",
        **provenance(),
        "format_version": FORMAT_VERSION,
        "conventions": "gridstrain.conventions: [row, col] = [y, x], Lagrangian "
                       "displacement, small-strain tensor (exy = tensor shear), "
                       "strain dimensionless",
        "k1": list(lat.k1), "k2": list(lat.k2), "pitches": list(lat.pitches),
        "angles": list(lat.angles), "lattice_detected": bool(result.lattice_detected),
        "sigma": result.sigma, "method": result.method, "lagrangian": result.lagrangian,
        "margin": result.margin, "spatial_resolution_px": nf.spatial_resolution,
        "window_fwhm_px": nf.window_fwhm,
        "noise_model_source": (nf.model or {}).get("source", "stack"),
        "n_frames_reference": result.n_frames[0],
        "reference_files": list(result.sources[0]),
        "warnings": list(result.warnings),
        # how each state's whole number of periods was fixed (FringeOrder)
        "fringe_order_source": [r.source for r in result.fringe_orders],
        "fringe_order_confirmed": [bool(r.confirmed) for r in result.fringe_orders],
    }
    if ps is not None:
        root.update(pixel_size=ps, unit=unit)
    return root


def _write_metrology(h5, result) -> None:
    """Resolution, efficiency and systematic errors per state, as CF variables with
    units (the full records, definitions included, are in the ``gridstrain`` group)."""
    met, sy = result.metrology, result.systematic
    if met is not None:
        for kind, comps, unit in (("u", ("ux", "uy"), "px"),
                                  ("strain", ("exx", "eyy", "exy"), "1")):
            for what, u, text in (
                    ("resolution", unit, "resolution: median predicted std at a pixel"),
                    ("efficiency", "px^2", "metrological efficiency indicator: resolution "
                     "x d (u) or x d^2 (strain), d the 10 % attenuation period")):
                vals = np.array([[np.nan if st[c][what] is None else st[c][what]
                                  for c in comps] for st in met["states"]], dtype=float)
                _var(h5, f"{what}_{kind}", vals, ("state", f"{kind}_component"), u, text)
        h5.attrs["spatial_resolution_px"] = float(met["spatial_resolution_px"])
        h5.attrs["window_fwhm_px"] = float(met["window_fwhm_px"])
        h5.attrs["step_width_px"] = float(met["step_width_px"])
    if sy is not None:
        smooth = np.array([[np.nan if v is None else v for v in s["max"]]
                           for s in sy["smoothing"]], dtype=float)
        _var(h5, "systematic_smoothing_strain", smooth, ("state", "strain_component"), "1",
             "window smoothing of strain gradients, bound on the peak error: 3 x the "
             "largest sigma^2/2 lap(e)")
        h5.attrs["systematic_aliasing_u_px"] = float(sy["aliasing"]["u_px"])
        h5.attrs["systematic_aliasing_strain_per_strain"] = float(
            sy["aliasing"]["strain_per_strain"])


# --------------------------------------------------------------------------- streaming


@dataclass(frozen=True)
class ResultFile:
    """Where and how :func:`gridstrain.pipeline.measure_series` writes its result
    while it measures (``output=``): each state's maps go to the file as soon as they
    are measured and leave memory, so that memory does not grow with the number of
    states. The file is the one :func:`save_result` writes (put at ``path``
    atomically when the measurement ends; nothing there if it fails).

    Attributes
    ----------
    path : str or os.PathLike
        Destination (``.h5`` or ``.nc``).
    pixel_size, unit, overwrite, attrs
        As for :func:`save_result`.
    dtype : {None, "float32", "float64"}
        Precision of the stored maps; None keeps that of the measurement
        (:mod:`gridstrain.conventions`). float32 halves the file and keeps a
        displacement below 1024 px to 3.1e-5 px (half the spacing of float32 numbers
        below 1024, 2^-14) and a strain below 1 to 3e-8; the measurement itself is
        computed as without it.
    """

    path: object
    pixel_size: float | None = None
    unit: str | None = None
    overwrite: bool = False
    attrs: Mapping | None = None
    dtype: object = None

    def __post_init__(self):
        as_path(self.path, "path")
        ps, unit = _check_pixel_size(self.pixel_size, self.unit)
        object.__setattr__(self, "pixel_size", ps)
        object.__setattr__(self, "unit", unit)
        object.__setattr__(self, "attrs", dict(check_mapping(self.attrs, "attrs",
                                                             allow_none=True)))
        object.__setattr__(self, "dtype", check_float_dtype(self.dtype, "dtype"))


class StoredMaps(np.lib.mixins.NDArrayOperatorsMixin):
    """Maps of a result file, read from it when indexed: a read-only array of shape
    ``(n_states, [components,] H, W)`` (or of one state) whose ``[i]`` reads state
    ``i`` only, so that a long series is looked at state by state without being
    loaded. ``numpy.asarray``, NumPy's functions and operators, and the methods of
    an array (``.mean()``, ``.reshape()``...) read the whole.

    Parameters
    ----------
    path : str or os.PathLike
        The result file.
    names : str or tuple of str
        The variable, or the variables stacked along the component axis.
    state : int, optional
        One state only (no state axis).
    """

    def __init__(self, path, names, *, state: int | None = None, layout=None):
        self.path = as_path(path, "path")
        self._names = names
        self._state = state
        if layout is None:  # (n_states, H, W, dtype) of the variables
            with h5py.File(self.path, "r") as h5:
                first = h5[names if isinstance(names, str) else names[0]]
                layout = (*first.shape, first.dtype)
        n, H, W, self.dtype = layout
        comp = () if isinstance(names, str) else (len(names),)
        self.shape = (*(() if state is not None else (n,)), *comp, H, W)

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def __len__(self) -> int:
        return self.shape[0]

    def _read(self, states) -> np.ndarray:
        with h5py.File(self.path, "r") as h5:
            if isinstance(self._names, str):
                return np.asarray(h5[self._names][states])
            axis = 0 if isinstance(states, numbers.Integral) else 1
            return np.stack([np.asarray(h5[n][states]) for n in self._names], axis=axis)

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        if self._state is not None:
            return self._read(self._state)[key]
        first, rest = key[0], key[1:]
        if isinstance(first, numbers.Integral) and not isinstance(first, bool):
            i = int(first)
            if not -self.shape[0] <= i < self.shape[0]:
                raise IndexError(f"state {i} out of range for {self.shape[0]} states")
            out = self._read(i % self.shape[0])
        elif isinstance(first, slice):
            out = self._read(first)
            return out[(slice(None), *rest)] if rest else out
        else:  # anything else: from the whole
            return np.asarray(self)[key]
        return out[rest] if rest else out

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        inputs = tuple(np.asarray(x) if isinstance(x, StoredMaps) else x for x in inputs)
        return getattr(ufunc, method)(*inputs, **kwargs)

    def __getattr__(self, name):
        # an array's other attributes and methods, on the whole read from the file
        if name.startswith("_") or not hasattr(np.ndarray, name):
            raise AttributeError(f"'StoredMaps' object has no attribute {name!r}")
        return getattr(np.asarray(self), name)

    def __array__(self, dtype=None, copy=None):
        arr = self._read(self._state if self._state is not None else slice(None))
        return arr if dtype is None else arr.astype(dtype)

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        return f"StoredMaps({self._names!r}, shape={self.shape}, file={str(self.path)!r})"


class _Streamed:
    """The sink of :func:`gridstrain.pipeline.measure_series` that writes each state
    into a :class:`ResultFile` as it comes (see :class:`ResultFile`)."""

    def __init__(self, spec: ResultFile, n_states: int):
        self.spec, self.n = spec, n_states
        self.path = as_path(spec.path, "path")
        self._cm = hdf5_stream(self.path, overwrite=spec.overwrite)
        self.stream = self._cm.__enter__()
        self.h5 = self.stream.file
        self.measurements, self.orders, self.floors, self.smoothing = [], [], [], []
        self.unc_names: list[str] = []
        self._lossless: dict[int, bool] = {}  # state -> u stored in its own precision

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if exc[0] is not None and self._cm is not None:
            cm, self._cm = self._cm, None
            cm.__exit__(*exc)  # the temporary file is removed
        return False

    def add(self, i: int, res, rec, unc, floors: dict, smooth: dict) -> None:
        try:
            self._add(i, res, rec, unc, floors, smooth)
        except BaseException as exc:
            self.__exit__(type(exc), exc, exc.__traceback__)
            raise

    def _add(self, i: int, res, rec, unc, floors: dict, smooth: dict) -> None:
        arrays = _state_arrays(res, unc)
        if unc and not self.unc_names:
            self.unc_names = list(unc)
        _create_maps(self.h5, arrays, self.n, self.spec.pixel_size, self.spec.dtype)
        _put_state(self.h5, i, arrays, self.spec.pixel_size)
        self._lossless[i] = self.h5["ux"].dtype == res.u.dtype
        self.stream.check()  # a full disk is reported now, not after the last state
        # the measurement without its maps (they are in the file) and phase maps
        self.measurements.append(dataclasses.replace(
            res, **dict.fromkeys(("u", "strain", "rotation", "valid"), _EMPTY),
            reference=None, deformed=None))
        self.orders.append(rec)
        self.floors.append(floors)
        self.smoothing.append(smooth)

    def reader(self, i: int):
        """A callable reading state ``i``'s ``(u, valid)`` back from the file (the
        measured numbers, bit for bit), or None where the file keeps u in a lower
        precision than it was measured in."""
        if not self._lossless.get(i, False):
            return None
        h5 = self.h5
        return lambda: (np.stack([h5["ux"][i], h5["uy"][i]]), h5["valid"][i])

    def result(self, **fields) -> SeriesResult:
        spec, h5 = self.spec, self.h5
        # the result's maps are those of the file, read from it once it is in place
        def lazy(names, state=None):
            first = h5[names if isinstance(names, str) else names[0]]
            return StoredMaps(self.path, names, state=state,
                              layout=(*first.shape, first.dtype))

        ms = tuple(dataclasses.replace(m, u=lazy(("ux", "uy"), i),
                                       strain=lazy(("exx", "eyy", "exy"), i),
                                       rotation=lazy("rotation", i), valid=lazy("valid", i))
                   for i, m in enumerate(self.measurements))
        result = SeriesResult(
            u=lazy(("ux", "uy")), strain=lazy(("exx", "eyy", "exy")), valid=lazy("valid"),
            measurements=ms,
            guesses=tuple(tuple(float(v) for v in r.guess) for r in self.orders),
            guess_sources=tuple(r.source for r in self.orders),
            fringe_orders=tuple(self.orders),
            uncertainty={k: lazy(k) for k in self.unc_names} or None, **fields)
        H, W = result.shape
        ps, unit = spec.pixel_size, spec.unit
        _write_dimensions(h5, result, H, W)
        _describe_maps(h5, ps, unit, H, W, self.unc_names)
        _write_images(h5, result, ps)
        _write_tables(h5, result, ps, unit, spec.attrs, len(result.names))
        _write_group(h5, result, spec.attrs, phase_maps=False)
        cm, self._cm = self._cm, None
        cm.__exit__(None, None, None)  # closed, and put at its path
        return result


_EMPTY = np.zeros((0, 0))
_EMPTY.flags.writeable = False


# --------------------------------------------------------------------------- load


def _open(path) -> h5py.File:
    p = as_path(path, "path")
    if not p.is_file():
        raise FileNotFoundError(f"result file {p} does not exist")
    try:
        h5 = h5py.File(p, "r")
    except OSError:
        raise ValueError(f"{p} is not a gridstrain result file (not HDF5)") from None
    try:
        group = h5.get(_GROUP, getlink=True)
        if not isinstance(group, h5py.HardLink) or not isinstance(h5[_GROUP], h5py.Group) \
                or "format_version" not in h5[_GROUP].attrs:
            raise _Bad(f"{p} is not a gridstrain result file (no '{_GROUP}' group; files "
                       "of gridstrain before 0.2 are read with gridstrain.io.read_hdf5)")
        version = _attr(h5[_GROUP], "format_version")
        if version != FORMAT_VERSION:
            raise _Bad(f"{p} is a gridstrain result file of format {version!r}; this "
                       f"gridstrain reads format {FORMAT_VERSION}")
    except BaseException:
        h5.close()
        raise
    return h5


_MAP_NAMES = ("ux", "uy", "exx", "eyy", "exy", "rotation", "valid")


def _map_datasets(h5) -> tuple[dict, dict, tuple]:
    """The per-state maps, the uncertainty maps and ``(n_states, H, W)``, each checked
    (a dataset of the file itself, of numbers or booleans, of one shape) before a byte
    of them is read."""
    maps = {}
    for name in _MAP_NAMES:
        if name not in h5:
            raise _Bad(f"{_where(h5, name)}: missing (every result file has the maps "
                       f"{', '.join(_MAP_NAMES)})")
        maps[name] = _member(h5, name)
    unc = {}
    for name in h5:
        obj = _member(h5, name)
        if isinstance(obj, h5py.Dataset) and "uncertainty_of" in obj.attrs:
            unc[name] = obj
    layout = maps["ux"].shape
    if len(layout) != 3:
        raise _Bad(f"{_where(maps['ux'])}: expected (state, y, x) maps, got shape {layout}")
    for name, ds in (*maps.items(), *unc.items()):
        if not isinstance(ds, h5py.Dataset) or ds.shape != layout:
            got = ds.shape if isinstance(ds, h5py.Dataset) else "a group"
            raise _Bad(f"{_where(ds)}: expected the shape {layout} of ux (state, y, x), "
                       f"got {got}")
        want = "b" if name == "valid" else "f"
        if ds.dtype.kind != want:
            raise _Bad(f"{_where(ds)}: dtype {ds.dtype}, expected "
                       + ("bool" if want == "b" else "floating point"))
    for name, want in (("mask", "b"), ("reference_image", "f")):
        if name not in h5:
            raise _Bad(f"{_where(h5, name)}: missing")
        ds = _member(h5, name)
        if not isinstance(ds, h5py.Dataset) or ds.shape != layout[1:] \
                or ds.dtype.kind != want:
            raise _Bad(f"{_where(ds)}: expected a {layout[1:]} "
                       + ("bool" if want == "b" else "floating-point") + " image, got "
                       + (f"shape {ds.shape} dtype {ds.dtype}"
                          if isinstance(ds, h5py.Dataset) else "a group"))
    return maps, unc, layout


def _declared_bytes(h5) -> int:
    """The bytes the file's datasets hold once read (what they declare, not what
    they take compressed on disk)."""
    total = 0

    def add(_name, obj):
        nonlocal total
        if isinstance(obj, h5py.Dataset):
            total += int(obj.size) * obj.dtype.itemsize

    h5.visititems(add)
    return total


def _check_result(path, result: SeriesResult) -> SeriesResult:
    """The counts of series and states agree across the fields, and the numbers a
    reader computes with are finite."""
    n = result.n_states
    per = {"names": n + 1, "sources": n + 1, "n_frames": n + 1, "bit_depth": n + 1,
           "scale": n + 1, "saturation": n + 1, "vibration": n + 1,
           "measurements": n, "guesses": n, "guess_sources": n}
    if result.fringe_orders:
        per["fringe_orders"] = n
    for name, count in per.items():
        if len(getattr(result, name)) != count:
            raise _Bad(f"{path}: /{_GROUP}/result/{name}: expected {count} entries "
                       f"({n} states, {n + 1} series), got {len(getattr(result, name))}")
    nf = result.noise
    for name, shape in (("theory_u", (n, 2)), ("theory_strain", (n, 3)),
                        ("split_u", (n, 2)), ("split_strain", (n, 3)),
                        ("vibration_u", (n, 2)), ("modulus", (n + 1, 2))):
        got = np.shape(getattr(nf, name))
        if got != shape:
            raise _Bad(f"{path}: /{_GROUP}/result/noise/{name}: expected shape {shape}, "
                       f"got {got}")
    for name, value, positive in (("sigma", result.sigma, True),
                                  ("margin", result.margin, False),
                                  ("noise/sigma", nf.sigma, True)):
        if not math.isfinite(value) or (positive and value <= 0):
            raise _Bad(f"{path}: /{_GROUP}/result/{name}: expected a finite "
                       + ("positive " if positive else "") + f"number, got {value!r}")
    if result.method not in ("A", "B", "C"):
        raise _Bad(f"{path}: /{_GROUP}/result/method: expected 'A', 'B' or 'C', got "
                   f"{result.method!r}")
    for i, v in enumerate(result.vibration):
        if np.ndim(v.shifts) != 2 or np.shape(v.shifts)[1:] != (2,) \
                or len(v.shifts) != v.n_frames:
            raise _Bad(f"{path}: /{_GROUP}/result/vibration/{i}/shifts: expected shape "
                       f"({v.n_frames}, 2), got {np.shape(v.shifts)}")
    return result


def load(path) -> SeriesResult:
    """Read a result file written by :func:`save_result`.

    Nothing in the file is run or imported: the classes it may hold are a fixed
    list (gridstrain's result classes, and subclasses of them the program defined
    already), and every value is checked (type, shape, dtype, the size it declares
    against the memory available) before it is used.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    SeriesResult
        Equal, field by field, to the result that was saved (arrays bit for bit);
        the measurements' ``reference`` and ``deformed`` phase maps are ``None``
        unless they were saved (``save_result(..., phase_maps=True)``).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        The file is not a gridstrain result file, or a field of it is not what
        the layout says (the message names the file and the field), or it declares
        more data than the memory available.
    """
    with _open(path) as h5:
        maps, unc, (n, H, W) = _map_datasets(h5)
        # read once, then copied into the stacks and the measurements
        _check_memory(h5.filename, 2 * _declared_bytes(h5), "its datasets")

        def stack(names):
            out = np.empty((n, len(names), H, W),
                           np.result_type(*(maps[k].dtype for k in names)))
            for j, k in enumerate(names):
                out[:, j] = _read_dataset(maps[k], kinds="f")
            return out

        u, strain = stack(("ux", "uy")), stack(("exx", "eyy", "exy"))
        valid = _read_dataset(maps["valid"], kinds="b")
        rotation = _read_dataset(maps["rotation"], kinds="f")
        root = {"u": u, "strain": strain, "valid": valid,
                "mask": _read_dataset(h5["mask"], kinds="b"),
                "reference_image": _read_dataset(h5["reference_image"], kinds="f"),
                "uncertainty": ({k: _read_dataset(unc[k]) for k in _UNC_KEYS if k in unc}
                                | {k: _read_dataset(unc[k]) for k in unc
                                   if k not in _UNC_KEYS}) if unc else None}

        def fill(cls, group, values):
            if cls.__name__ == "SeriesResult":
                values.update(root)
            elif cls.__name__ == "Measurement" and group.parent.name.endswith(
                    "/measurements"):
                i = group.name.rsplit("/", 1)[1]
                if not i.isdigit() or int(i) >= n:
                    raise _Bad(f"{_where(group)}: a measurement beyond the {n} states of "
                               "the maps")
                i = int(i)
                values.update(u=u[i].copy(), strain=strain[i].copy(),
                              rotation=rotation[i].copy(), valid=valid[i].copy())
                values.setdefault("reference", None)  # saved without the phase maps
                values.setdefault("deformed", None)
            elif cls.__name__ == "NoiseFloor":
                # files of format 2 stored the window's FWHM; it follows from sigma
                values.pop("resolution", None)
            return values

        if "result" not in h5[_GROUP]:
            raise _Bad(f"{_where(h5[_GROUP], 'result')}: missing")
        result = _decode(_member(h5[_GROUP], "result"), {}, fill)
        if not isinstance(result, SeriesResult):
            raise _Bad(f"{_where(h5[_GROUP], 'result')}: expected a SeriesResult, got "
                       f"{_received(result)}")
        return _check_result(h5.filename, result)


#: Root attributes whose type a reader relies on (the report, the plots, the replay).
_ATTR_TYPES = {"pixel_size": float, "unit": str, "config": str, "config_file": str,
               "mask_file": str, "created": str, "gridstrain_version": str,
               "conventions": str}


def read_attrs(path) -> dict:
    """The root attributes of a result file (pixel size, unit, config...), decoded.

    Lists come back as lists, NaN as NaN; see :func:`save_result`. The attributes
    a reader computes with are checked: ``pixel_size`` a finite positive number with
    a short ``unit``, ``config`` and the provenance strings text.
    """
    with _open(path) as h5:
        out = {k: _attr(h5, k) for k in h5.attrs}
        for key, kind in _ATTR_TYPES.items():
            v = out.get(key)
            if v is None:
                continue
            ok = isinstance(v, str) if kind is str else (
                isinstance(v, int | float) and not isinstance(v, bool)
                and math.isfinite(v) and v > 0)
            if not ok:
                raise _Bad(f"{_where(h5, key)}: expected "
                           + ("text" if kind is str else "a finite positive number")
                           + f", got {_received(v)}")
        if out.get("pixel_size") is not None:
            try:
                _check_pixel_size(out["pixel_size"], out.get("unit"))
            except ValueError as exc:
                raise _Bad(f"{_where(h5, 'unit')}: {exc}") from None
        if "attrs" in h5[_GROUP]:
            group = _member(h5[_GROUP], "attrs")
            if isinstance(group, h5py.Group):  # else refused by _decode
                _check_memory(h5.filename, _declared_bytes(group), "its attributes")
            extra = _decode(group, {}, lambda c, g, v: v)
            if not isinstance(extra, dict):
                raise _Bad(f"{_where(h5[_GROUP], 'attrs')}: expected a dict, got "
                           f"{_received(extra)}")
            out.update(extra)
    return out


def to_xarray(result_or_path, *, pixel_size: float | None = None, unit: str | None = None):
    """An ``xarray.Dataset`` of a result (or of a result file).

    Needs ``xarray`` and ``h5netcdf`` (``pip install 'gridstrain[xarray]'``). A
    result in memory is written to an in-memory file with :func:`save_result`'s
    layout, so that both give the same Dataset.
    """
    try:
        import xarray as xr
    except ImportError as exc:
        raise ImportError("to_xarray needs xarray and h5netcdf: pip install "
                          "'gridstrain[xarray]'") from exc
    if isinstance(result_or_path, SeriesResult):
        import tempfile

        with tempfile.TemporaryDirectory() as d:
            p = save_result(result_or_path, Path(d) / "result.h5", pixel_size=pixel_size,
                            unit=unit)
            with xr.open_dataset(p, engine="h5netcdf") as ds:
                return ds.load()
    with xr.open_dataset(as_path(result_or_path, "path"), engine="h5netcdf") as ds:
        return ds.load()


# --------------------------------------------------------------------------- exports


def _phys(result, pixel_size, unit):
    return _check_pixel_size(pixel_size, unit)


def export_mat(result: SeriesResult, path, *, pixel_size: float | None = None,
               unit: str | None = None, overwrite: bool = False) -> Path:
    """Write the maps to a MATLAB ``.mat`` file (version 5, compressed), atomically.

    Maps are ``(H, W, n_states)`` (``ux(:, :, k)`` is state ``k``, row ``y`` and
    column ``x`` as in the image), NaN where not ``valid`` (a logical array).
    Also ``x``, ``y`` (px), ``x_phys``, ``y_phys`` with a pixel size, ``states``
    (cell array of names), ``units`` (a struct), ``k1``, ``k2`` (cycles/px),
    ``sigma`` (px), ``method``.
    """
    from scipy.io import savemat

    check_type(result, "result", SeriesResult)
    ps, unit = _phys(result, pixel_size, unit)
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


def export_vtk(result: SeriesResult, path, *, pixel_size: float | None = None,
               unit: str | None = None, overwrite: bool = False) -> Path:
    """Write the states as a ParaView time series (``.pvd`` and a folder of ``.vti``).

    See :func:`gridstrain.post.export_pvd`: one ``.vti`` per state as a time step
    (time, else load, else index), the displacement as one vector in ``unit``,
    the image upright in ParaView, units in the field names.
    """
    from .post import export_pvd

    return export_pvd(result, path, pixel_size=pixel_size, unit=unit, overwrite=overwrite)


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
    ps, unit = _phys(result, pixel_size, unit)
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


def export(result: SeriesResult, stem, formats, *, pixel_size: float | None = None,
           unit: str | None = None, overwrite: bool = False) -> dict:
    """Write ``stem.mat``, ``stem.pvd`` (with ``stem_vti/``) and/or ``stem.csv``;
    returns ``{format: path}``."""
    writers = {"mat": (export_mat, ".mat"), "vtk": (export_vtk, ".pvd"),
               "csv": (save_csv, ".csv")}
    out = {}
    for f in formats:
        if f not in writers:
            raise ValueError(f"export format must be one of {', '.join(writers)}, got "
                             f"{f!r}")
    stem = as_path(stem, "stem")
    for f in formats:
        fn, ext = writers[f]
        out[f] = fn(result, stem.with_name(stem.name + ext), pixel_size=pixel_size,
                    unit=unit, overwrite=overwrite)
    return out


def _nan_equal(a, b) -> bool:
    """Equality of two values, arrays compared element-wise with NaN equal to NaN."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and a.dtype == b.dtype and bool(
            np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(
            _nan_equal(getattr(a, f.name), getattr(b, f.name))
            for f in dataclasses.fields(a))
    if isinstance(a, Mapping):
        return isinstance(b, Mapping) and list(a) == list(b) and all(
            _nan_equal(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return type(a) is type(b) and len(a) == len(b) and all(
            _nan_equal(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b
