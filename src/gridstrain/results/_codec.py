"""The generic codec of a result file: dataclasses, tuples, lists, dicts, numbers, strings and
arrays written to HDF5 groups and read back safely (only registered classes are built; every
value's type, size and the file's declared sizes are checked before anything is read).

A list or tuple of :data:`_MIN_ROWS` values or more (the states, the series) is written by
columns: one group for the whole list, in which each field of its records (dataclasses
of one class, or dicts of the same keys) is one column of ``n`` values, whatever ``n``:

- scalars of one kind: one attribute array (bool, int64, float64 or UTF-8 text);
- arrays of one shape and dtype: one dataset ``(n, ...)``;
- records again: a group of ``_type`` ``"records"`` (``_class`` or ``_keys``);
- tuples or lists: a group ``"ragged"``, their ``lengths`` and the column of their
  concatenated ``values``;
- values of several kinds (None among floats, a subclass among its base class): a group
  ``"union"``, the ``part`` each row is in and one column per part (``"0"``, ``"1"``...);
- all None: named in the container's ``_none``; one object for every row (the lattice
  of every measurement): named in ``_const``, written once;
- anything else (an array or a dataclass written elsewhere in the file, which a link
  names): a group ``"list"`` of the values one by one, as a short list is written.

Every column group records its ``_n`` rows; a list written by columns records whether it
was a tuple or a list in ``_rows`` (a column that is not a group is wrapped in a group of
``_type`` ``"rows"`` holding the column ``values``).
"""

from __future__ import annotations

import dataclasses
import itertools
import numbers
import os
import types
import typing
from collections.abc import Mapping

import h5py
import numpy as np

from .._runtime.memory import available_memory, format_size
from ._result import SeriesResult

# Lossless filters of the images, masks and tables: gzip is read everywhere. Level 1:
# nearly the size of level 4 (gridstrain.io.write_hdf5's level, for data written once
# and kept) for less CPU (benchmarks/README.md)
_FILTERS = {"compression": "gzip", "compression_opts": 1, "shuffle": True,
            "fletcher32": True}
_TYPE, _CLASS, _KEYS, _TUPLES, _LISTS = "_type", "_class", "_keys", "_tuple_attrs", "_list_attrs"
# the attributes of a list written by columns (see the module docstring)
_N, _ROWS, _NONE, _CONST = "_n", "_rows", "_none", "_const"


_RESERVED = {_TYPE, _CLASS, _KEYS, _TUPLES, _LISTS, _N, _ROWS, _NONE, _CONST}

# A list of this many values or more is written by columns: its number of HDF5 objects
# and attributes does not grow with its length (a record of thousands of states).
_MIN_ROWS = 2
# More kinds of value than this in one column: the column is written value by value.
_MAX_PARTS = 8
# Above this many bytes a column of arrays is written row by row into its dataset,
# instead of being stacked in memory first (the phase maps of every state).
_STACK_BYTES = 64 * 2**20


# Fields of the result classes stored as the file's CF variables, not in its group.
_ROOT_FIELDS = {"SeriesResult": ("u", "strain", "valid", "mask", "reference_image",
                                 "uncertainty"),
                "Measurement": ("u", "strain", "rotation", "valid")}


def _storable_key(key) -> bool:
    return isinstance(key, str) and bool(key) and "/" not in key \
        and key not in (".", "..") and key not in _RESERVED


def _check_key(key, where: str) -> str:
    if not _storable_key(key):
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
            rows = "tuple" if isinstance(value, tuple) else "list"
            if value and None not in kinds and (len(kinds) == 1 or kinds <= {"i", "f"}):
                attrs[key] = _array(list(value), kinds)
                (tuples if isinstance(value, tuple) else lists).append(key)
            elif len(value) >= _MIN_ROWS:
                _put_column(group, key, list(value), memo, skip, None, rows=rows)
            else:
                _put_items(group, key, value, memo, skip, rows)
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


def _put_items(group, key: str, values, memo: dict, skip: Mapping, kind: str) -> None:
    """A list or tuple written value by value: a group of members ``0``, ``1``..."""
    g = group.create_group(key, track_order=True)
    g.attrs[_TYPE] = kind
    _encode(g, ((str(i), v) for i, v in enumerate(values)), memo, skip)


def _part(v, memo: dict):
    """The part of a column that ``v`` belongs to: the values of one part are written
    together (one kind of scalar, one shape and dtype of array, one class...);
    ``"item"``: written on its own, as in a short list."""
    if v is None:
        return "none"
    kind = _scalar_kind(v)
    if kind is not None:
        return kind if kind != "i" or -(2**63) <= int(v) < 2**63 else "item"
    if id(v) in memo:  # an array or a dataclass written already: a link names it
        return "item"
    if isinstance(v, np.ndarray):
        return ("array", v.shape, v.dtype.str) if v.dtype.kind in "biufc" else "item"
    if type(v) is tuple or type(v) is list:
        return type(v).__name__
    if type(v) is dict:
        keys = tuple(v)
        return ("dict", keys) if all(map(_storable_key, keys)) else "item"
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return ("class", type(v))
    return "item"


def _plan(values: list, memo: dict) -> tuple[str, list]:
    """How a column is written (see the module docstring), and the part of each value."""
    if len(values) >= _MIN_ROWS:
        if ("rows", tuple(map(id, values))) in memo:
            return "link", []
        first = values[0]
        if (isinstance(first, np.ndarray) or (dataclasses.is_dataclass(first)
                                              and not isinstance(first, type))) \
                and all(v is first for v in values):
            return "const", []
    parts = [_part(v, memo) for v in values]
    for kind in set(parts):
        # a dataclass twice in a column is written value by value: the second is a
        # link to the first, which a reader gives back as one object
        if isinstance(kind, tuple) and kind[0] == "class":
            rows = [id(v) for v, p in zip(values, parts, strict=True) if p == kind]
            if len(set(rows)) < len(rows):
                parts = ["item" if p == kind else p for p in parts]
    kinds = list(dict.fromkeys(parts))
    if not kinds or kinds == ["none"]:
        return "none", parts
    if len(kinds) > 1:
        return ("union" if len(kinds) <= _MAX_PARTS else "items"), parts
    kind = kinds[0]
    if kind == "item":
        return "items", parts
    if kind in _SCALAR_TYPES:
        return "scalar", parts
    if kind in ("tuple", "list"):
        return "ragged", parts
    return ("stack" if kind[0] == "array" else "records"), parts


def _put_columns(group, columns, memo: dict, skip: Mapping) -> None:
    """Write the ``(name, values)`` columns into ``group``, then the names of those that
    are all None (``_none``) or one object (``_const``)."""
    marks: dict = {_NONE: [], _CONST: []}
    for name, values in columns:
        _put_column(group, name, values, memo, skip, marks)
    for attr, names in marks.items():
        if names:
            group.attrs[attr] = np.array(names, dtype=h5py.string_dtype())


def _column_group(group, key: str, kind: str, n: int, rows: str | None) -> h5py.Group:
    g = group.create_group(key, track_order=True)
    g.attrs[_TYPE] = kind
    g.attrs[_N] = np.int64(n)
    if rows is not None:
        g.attrs[_ROWS] = rows
    return g


def _put_column(group, key: str, values: list, memo: dict, skip: Mapping, marks,
                *, rows: str | None = None) -> None:
    """Write the column ``values`` as ``key`` of ``group``; ``rows`` (``"tuple"`` or
    ``"list"``): ``values`` is a whole list, read back as one."""
    form, parts = _plan(values, memo)
    n = len(values)
    if rows is not None and form in ("link", "none", "const", "scalar", "stack"):
        g = _column_group(group, key, "rows", n, rows)
        _put_columns(g, [("values", values)], memo, skip)
    elif form == "link":
        group[key] = h5py.SoftLink(memo["rows", tuple(map(id, values))])
    elif form in ("none", "const"):
        if form == "const":
            _encode(group, [(key, values[0])], memo, skip)
        marks[_NONE if form == "none" else _CONST].append(key)
    elif form == "scalar":
        group.attrs[key] = _array(values, {parts[0]})
    elif form == "stack":
        _stack(group, key, values)
    elif form == "items":
        _put_items(group, key, values, memo, skip, rows or "list")
    elif form == "ragged":
        g = _column_group(group, key, "ragged", n, rows)
        g.attrs["kind"] = parts[0]
        g.attrs["lengths"] = np.array([len(v) for v in values], dtype=np.int64)
        _put_columns(g, [("values", [x for v in values for x in v])], memo, skip)
    elif form == "union":
        g = _column_group(group, key, "union", n, rows)
        kinds = list(dict.fromkeys(parts))
        number = {kind: j for j, kind in enumerate(kinds)}
        g.attrs["part"] = np.array([number[p] for p in parts], dtype=np.int64)
        _put_columns(g, [(str(j), [v for v, p in zip(values, parts, strict=True)
                                   if p == kind]) for j, kind in enumerate(kinds)],
                     memo, skip)
    else:
        _put_records(group, key, values, parts[0], memo, skip, rows)


def _put_records(group, key: str, values: list, kind: tuple, memo: dict, skip: Mapping,
                 rows: str | None) -> None:
    """Dataclasses of one class, or dicts of the same keys: one column per field."""
    g = _column_group(group, key, "records", len(values), rows)
    where = g.name
    if kind[0] == "class":
        cls = kind[1]
        g.attrs[_CLASS] = _class_name(cls, where)
        left = skip.get(cls.__name__, ())
        names = [_check_key(f.name, where) for f in dataclasses.fields(cls)
                 if f.init and f.name not in left]
        # a list of the same objects, written later, is a link to this group
        memo["rows", tuple(map(id, values))] = where
        _put_columns(g, [(name, [getattr(v, name) for v in values]) for name in names],
                     memo, skip)
    else:
        g.attrs[_KEYS] = np.array(kind[1], dtype=h5py.string_dtype())
        _put_columns(g, [(k, [v[k] for v in values]) for k in kind[1]], memo, skip)


def _stack(group, key: str, values: list) -> None:
    """Arrays of one shape and dtype as one dataset ``(n, ...)``."""
    first = values[0]
    if len(values) * first.nbytes <= _STACK_BYTES:
        _dataset(group, key, np.stack(values))
        return
    # too large to be copied into one array: written a chunk of rows at a time
    step = min(len(values), max(1, 2**20 // max(first.nbytes, 1)))  # chunks of ~1 MiB
    ds = group.create_dataset(key, shape=(len(values), *first.shape), dtype=first.dtype,
                              chunks=(step, *first.shape), **_FILTERS)
    for i in range(0, len(values), step):
        ds[i:i + step] = np.stack(values[i:i + step])


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
        "gridstrain.results.SeriesResult": SeriesResult,
        "gridstrain.kinematics.Measurement": Measurement,
        "gridstrain.kinematics.FringeOrder": FringeOrder,
        "gridstrain.phase.Lattice": Lattice,
        "gridstrain.stacks.screening.FrameScreen": FrameScreen,
        "gridstrain.stacks.screening.Trend": Trend,
        "gridstrain.uncertainty.NoiseFloor": NoiseFloor,
        "gridstrain.stacks.vibration.VibrationReport": VibrationReport,
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


def _check_fields(cls, group, values: dict, row: int | None = None) -> None:
    """The fields stored in ``group`` (its row ``row``, for a list written by columns):
    none unknown, each of its annotated type."""
    _check_known(cls, group, values)
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # annotations this module cannot resolve: no check
        hints = {}
    at = "" if row is None else f"[{row}]"
    for key, value in values.items():
        if key in hints and not _fits(value, hints[key]):
            raise _Bad(f"{_where(group, key)}{at}: expected {_hint_text(hints[key])}, got "
                       f"{_received(value)}")


def _check_known(cls, group, names) -> None:
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(names) - fields)
    if unknown:
        raise _Bad(f"{_where(group)} holds fields {', '.join(unknown)} that this "
                   f"gridstrain's {cls.__name__} does not have (written by a newer "
                   "version?)")


def _hint_text(hint) -> str:
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")


def _received(value) -> str:
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    text = repr(value)
    return f"{type(value).__name__} {text[:60] + '...' if len(text) > 60 else text}"


_KINDS = ("none", "tuple", "list", "dict", "dataclass", "rows", "records", "ragged", "union")
_COLUMNS = ("rows", "records", "ragged", "union")  # the groups of a list written by columns
# What a row of a column costs in memory at least (a list slot and a small object): the
# rows a file declares are checked against the memory before they are built.
_ROW_BYTES = 64


_READING = object()  # the mark of a group being decoded, to refuse links in a cycle


def _member_value(group: h5py.Group, key: str, memo: dict, fill):
    """The value of the member ``key`` of ``group`` (a dataset or a group, through a
    link inside the file), decoded once however many links name it."""
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
    return memo[target]


def decoded(group: h5py.Group, memo: dict, fill):
    """:func:`_decode` of a whole result, a file nested deeper than Python's recursion
    allows refused in one line like any other malformed file (gridstrain's results nest
    a few levels; thousands are a file made to crash its reader)."""
    try:
        return _decode(group, memo, fill)
    except RecursionError:
        raise _Bad(f"{_where(group)}: groups nested too deep to read; a result file nests a "
                   "few levels") from None


def _decode(group: h5py.Group, memo: dict, fill):
    """The object written by :func:`_encode` into ``group``, each value checked: a
    class only from the registry (:func:`_registry`), each field of its annotated
    type, datasets of numbers, no link out of the file, no cycle. ``fill(cls, group,
    values, row)`` completes the fields of a dataclass before it is built (``row``: its
    index in a list written by columns, else None)."""
    if not isinstance(group, h5py.Group):
        raise _Bad(f"{_where(group)}: a dataset where a group is expected")
    kind = _attr(group, _TYPE) if _TYPE in group.attrs else "dict"
    if kind not in _KINDS:
        raise _Bad(f"{_where(group, _TYPE)}: {kind!r} is not one of {', '.join(_KINDS)}")
    if kind == "none":
        return None
    if kind in _COLUMNS:
        rows = _attr(group, _ROWS) if _ROWS in group.attrs else None
        if rows not in ("tuple", "list"):
            raise _Bad(f"{_where(group, _ROWS)}: expected 'tuple' or 'list', got "
                       f"{rows!r}")
        values = _column_rows(group, group.name, memo, fill, None)
        return tuple(values) if rows == "tuple" else list(values)
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
        values[key] = _member_value(group, key, memo, fill)
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
    return _build(_stored_class(group), group, values, fill)


def _stored_class(group) -> type:
    """The registered class that ``group`` names in ``_class``."""
    if _CLASS not in group.attrs:
        raise _Bad(f"{_where(group, _CLASS)}: missing")
    qualname = _attr(group, _CLASS)
    cls = _class_named(qualname) if isinstance(qualname, str) else None
    if cls is None:
        raise _Bad(f"{_where(group, _CLASS)}: {qualname!r} is not a class a result file "
                   "may hold (" + ", ".join(_registry()) + ")")
    return cls


def _build(cls, group, values: dict, fill, row: int | None = None, index=None):
    """An instance of ``cls`` from its checked fields (``row``: its row in the columns of
    ``group``; ``index``: the row given to ``fill``)."""
    _check_fields(cls, group, values, row)
    values = fill(cls, group, values, index)
    missing = [f.name for f in dataclasses.fields(cls) if f.init and f.name not in values
               and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    at = "" if row is None else f"[{row}]"
    if missing:
        raise _Bad(f"{_where(group, missing[0])}{at}: missing (a {cls.__name__} needs it)")
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise _Bad(f"{_where(group)}{at}: not a valid {cls.__name__} ({exc})") from None


# --------------------------------------------------------------------------- columns


def _text_list(group, attr: str) -> list[str]:
    """A structural attribute that lists names: absent, or UTF-8 strings."""
    if attr not in group.attrs:
        return []
    names = _attr(group, attr)
    names = [names] if isinstance(names, str) else names
    if not isinstance(names, list) or not all(isinstance(x, str) for x in names):
        raise _Bad(f"{_where(group, attr)}: expected a list of names, got "
                   f"{_received(names)}")
    return names


def _counts(group, attr: str, n: int | None) -> list[int]:
    """A list of ``n`` whole numbers >= 0 stored as ``attr`` (one per row)."""
    if attr not in group.attrs:
        raise _Bad(f"{_where(group, attr)}: missing")
    got = _attr(group, attr)
    v = [got] if n is None else got
    if not isinstance(v, list) or (n is not None and len(v) != n) or not all(
            isinstance(x, int) and not isinstance(x, bool) and x >= 0 for x in v):
        want = "a whole number >= 0" if n is None else f"{n} whole numbers >= 0"
        raise _Bad(f"{_where(group, attr)}: expected {want}, got {_received(got)}")
    return v


def _column_rows(group: h5py.Group, path: str, memo: dict, fill, index) -> list:
    """The rows of a column group (``records``, ``ragged``, ``union`` or ``rows``), read
    once however many links name it."""
    key = ("column", path)
    if memo.get(key) is _READING:
        raise _Bad(f"{_where(group)}: a link to a group that holds it (a cycle)")
    if key not in memo:
        memo[key] = _READING
        memo[key] = _read_columns(group, memo, fill, index)
    return memo[key]


def _read_columns(g: h5py.Group, memo: dict, fill, index) -> list:
    kind = _attr(g, _TYPE)
    n = _counts(g, _N, None)[0]
    _check_memory(_where(g), n * _ROW_BYTES, f"its {n} rows")
    marks = {m: _text_list(g, m) for m in (_NONE, _CONST)}
    if kind == "rows":
        return _column(g, "values", n, memo, fill, None, marks)
    if kind == "ragged":
        seq = _attr(g, "kind") if "kind" in g.attrs else None
        if seq not in ("tuple", "list"):
            raise _Bad(f"{_where(g, 'kind')}: expected 'tuple' or 'list', got {seq!r}")
        lengths = _counts(g, "lengths", n)
        flat = _column(g, "values", sum(lengths), memo, fill, None, marks)
        ends = np.cumsum([0, *lengths]).tolist()
        return [(tuple if seq == "tuple" else list)(flat[a:b])
                for a, b in itertools.pairwise(ends)]
    if kind == "union":
        part = _counts(g, "part", n)
        if part and max(part) >= _MAX_PARTS:
            raise _Bad(f"{_where(g, 'part')}: part {max(part)}, of at most {_MAX_PARTS}")
        out = [None] * n
        for j in range(max(part, default=-1) + 1):
            rows = [i for i, p in enumerate(part) if p == j]
            sub = [i if index is None else index[i] for i in rows]
            for i, v in zip(rows, _column(g, str(j), len(rows), memo, fill, sub, marks),
                            strict=True):
                out[i] = v
        return out
    if kind == "records":
        return _records(g, n, memo, fill, index, marks)
    raise _Bad(f"{_where(g, _TYPE)}: {kind!r} is not one of {', '.join(_COLUMNS)}")


def _records(g: h5py.Group, n: int, memo: dict, fill, index, marks) -> list:
    """Dataclasses of one class, or dicts of the same keys, from their columns."""
    attrs = [k for k in g.attrs if k not in _RESERVED]
    members = list(g)
    names = attrs + members + marks[_NONE]
    for name in names:
        if names.count(name) > 1:
            raise _Bad(f"{_where(g, name)}: stored twice (as an attribute, a member or "
                       "in _none)")
    for name in marks[_CONST]:
        if name not in members:
            raise _Bad(f"{_where(g, _CONST)}: names {name!r}, which the group does not "
                       "hold")
    cls = _stored_class(g) if _KEYS not in g.attrs else None
    if cls is None:
        keys = _text_list(g, _KEYS)
        if sorted(keys) != sorted(names):
            raise _Bad(f"{_where(g, _KEYS)}: lists {sorted(keys)}, the group holds "
                       f"{sorted(names)}")
    else:
        _check_known(cls, g, names)  # before any column is read
    columns = {name: _column(g, name, n, memo, fill, index, marks) for name in names}
    rows = []
    for i in range(n):
        values = {name: column[i] for name, column in columns.items()}
        if cls is None:
            rows.append({k: values[k] for k in keys})
        else:
            rows.append(_build(cls, g, values, fill, i, i if index is None else index[i]))
    return rows


def _column(group: h5py.Group, name: str, n: int, memo: dict, fill, index, marks) -> list:
    """The ``n`` values of the column ``name`` of ``group`` (see the module docstring),
    their number checked against ``n`` before they are read."""
    where = _where(group, name)
    _check_memory(where, n * _ROW_BYTES, f"its {n} rows")
    if name in marks[_NONE]:
        return [None] * n
    if name in group.attrs:
        values = _attr(group, name)
        if not isinstance(values, list) or len(values) != n:
            raise _Bad(f"{where}: expected a column of {n} values, got "
                       f"{_received(values)}")
        return values
    if name not in group:
        raise _Bad(f"{where}: missing")
    if name in marks[_CONST]:
        return [_member_value(group, name, memo, fill)] * n
    link = group.get(name, getlink=True)
    obj = _member(group, name)
    if isinstance(obj, h5py.Dataset):
        if obj.ndim < 1 or obj.shape[0] != n:
            raise _Bad(f"{where}: expected {n} rows, got a dataset of shape {obj.shape}")
        _check_memory(where, obj.size * obj.dtype.itemsize, "its values")
        stacked = _read_dataset(obj)
        return [stacked[i, ...] for i in range(n)]
    kind = _attr(obj, _TYPE) if _TYPE in obj.attrs else None
    if kind in ("list", "tuple"):  # written value by value
        values = _member_value(group, name, memo, fill)
    elif kind in _COLUMNS:
        target = link.path if isinstance(link, h5py.SoftLink) else obj.name
        values = _column_rows(obj, target, memo, fill, index)
    else:
        raise _Bad(f"{where}: a group of _type {kind!r}, not a column")
    if len(values) != n:
        raise _Bad(f"{where}: expected {n} rows, got {len(values)}")
    return list(values)
