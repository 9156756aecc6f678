"""The generic codec of a result file: dataclasses, tuples, lists, dicts, numbers, strings and
arrays written to HDF5 groups and read back safely (only registered classes are built; every
value's type, size and the file's declared sizes are checked before anything is read).
"""

from __future__ import annotations

import dataclasses
import numbers
import os
import types
import typing
from collections.abc import Mapping

import h5py
import numpy as np

from .._memory import available_memory, format_size
from ._result import SeriesResult

# Lossless filters of the images, masks and tables: gzip is read everywhere. Level 1:
# the 1040 x 1376 reference image in 40 ms and 2.25 MB, against 54 ms and 2.19 MB at
# level 4 (gridstrain.io.write_hdf5's level, for data written once and kept)
_FILTERS = {"compression": "gzip", "compression_opts": 1, "shuffle": True,
            "fletcher32": True}
_TYPE, _CLASS, _KEYS, _TUPLES, _LISTS = "_type", "_class", "_keys", "_tuple_attrs", "_list_attrs"


_RESERVED = {_TYPE, _CLASS, _KEYS, _TUPLES, _LISTS}


# Fields of the result classes stored as the file's CF variables, not in its group.
_ROOT_FIELDS = {"SeriesResult": ("u", "strain", "valid", "mask", "reference_image",
                                 "uncertainty"),
                "Measurement": ("u", "strain", "rotation", "valid")}


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


# How each scalar kind is stored as an attribute.
_SCALAR_TYPES = {"b": np.bool_, "i": np.int64, "f": np.float64, "s": _utf8}


def _encode(group: h5py.Group, items, memo: dict, skip: Mapping = _ROOT_FIELDS) -> None:
    """Write ``(key, value)`` pairs into ``group`` (see the module docstring);
    ``skip`` names, per class name, the fields not written."""
    tuples, lists = [], []
    where, attrs = group.name, group.attrs  # one lookup each for all the members
    for key, value in items:
        _check_key(key, where)
        kind = _scalar_kind(value)
        if kind is not None or isinstance(value, os.PathLike):
            if isinstance(value, os.PathLike):
                value = os.fspath(value)
                kind = _scalar_kind(value)
            elif kind == "i" and not -(2**63) <= int(value) < 2**63:
                raise TypeError(f"{where}/{key}: integer {value} too large to store")
            attrs[key] = _SCALAR_TYPES[kind](value)
        elif isinstance(value, np.ndarray):
            if id(value) in memo:
                group[key] = h5py.SoftLink(memo[id(value)])
            else:
                memo[id(value)] = _dataset(group, key, value).name
        elif isinstance(value, list | tuple):
            kinds = {_scalar_kind(v) for v in value}
            if value and None not in kinds and (len(kinds) == 1 or kinds <= {"i", "f"}):
                attrs[key] = _array(list(value), kinds)
                (tuples if isinstance(value, tuple) else lists).append(key)
            else:
                g = group.create_group(key, track_order=True)
                g.attrs[_TYPE] = "tuple" if isinstance(value, tuple) else "list"
                _encode(g, ((str(i), v) for i, v in enumerate(value)), memo, skip)
        elif value is None:
            group.create_group(key).attrs[_TYPE] = "none"
        elif isinstance(value, Mapping):
            g = group.create_group(key, track_order=True)
            g_attrs = g.attrs
            g_attrs[_TYPE] = "dict"
            keys = [_check_key(k, f"{where}/{key}") for k in value]
            g_attrs[_KEYS] = np.array(keys, dtype=h5py.string_dtype())
            _encode(g, value.items(), memo, skip)
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            if id(value) in memo:
                group[key] = h5py.SoftLink(memo[id(value)])
                continue
            cls = type(value)
            name = _class_name(cls, f"{where}/{key}")
            g = group.create_group(key, track_order=True)
            memo[id(value)] = g.name
            g_attrs = g.attrs
            g_attrs[_TYPE] = "dataclass"
            g_attrs[_CLASS] = name
            left = skip.get(cls.__name__, ())
            _encode(g, ((f.name, getattr(value, f.name)) for f in dataclasses.fields(value)
                        if f.init and f.name not in left), memo, skip)
        elif isinstance(value, np.generic):
            attrs[key] = value
        else:
            raise TypeError(f"{where}/{key}: cannot store a {type(value).__name__} "
                            "(arrays, numbers, strings, None, tuples, lists, dicts and "
                            "dataclasses are stored)")
    if tuples:
        attrs[_TUPLES] = np.array(tuples, dtype=h5py.string_dtype())
    if lists:
        attrs[_LISTS] = np.array(lists, dtype=h5py.string_dtype())


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
    from ..kinematics import FringeOrder, Measurement
    from ..phase import Lattice, PhaseMaps
    from ..stacks.screening import FrameScreen, Trend
    from ..stacks.vibration import VibrationReport
    from ..uncertainty import NoiseFloor

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
