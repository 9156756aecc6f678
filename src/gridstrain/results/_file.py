"""Result files: saving a result, loading it back, and the file written state by state
(:class:`ResultFile`). The layout is described in :mod:`gridstrain.results`.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
import math
import numbers
import os
import shutil
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from .._runtime.memory import format_size
from .._validation import as_path, check_float_dtype, check_mapping, check_pixel_size, check_type
from ..io import hdf5_file, hdf5_stream
from ._codec import (
    _attr,
    _Bad,
    _check_memory,
    _member,
    _read_dataset,
    _received,
    _where,
    decoded,
)
from ._layout import (
    _GROUP,
    _READ_VERSIONS,
    _UNC_KEYS,
    FORMAT_VERSION,
    ROUNDED_TEXT,
    _create_maps,
    _describe_maps,
    _Kept,
    _put_errors,
    _put_state,
    _state_arrays,
    _write_dimensions,
    _write_group,
    _write_images,
    _write_maps,
    _write_tables,
)
from ._result import SeriesResult

__all__ = ["FORMAT_VERSION", "ResultFile", "StoredMaps", "load", "read_attrs", "save_result",
           "to_xarray"]





def _file_errors(func):
    """``func(path, ...)`` (or a method of an object with ``.path``) with the errors
    HDF5 raises on a damaged file (bytes flipped, truncated: a ``RuntimeError`` or an
    ``OSError`` from deep in h5py) turned into one ``ValueError`` naming the file."""
    @functools.wraps(func)
    def wrapped(first, *args, **kwargs):
        try:
            return func(first, *args, **kwargs)
        except (FileNotFoundError, RecursionError):
            raise
        except (RuntimeError, OSError, KeyError) as exc:
            path = getattr(first, "path", first)
            text = " ".join(str(exc).split()) or type(exc).__name__
            raise ValueError(f"{os.fspath(path)}: damaged result file, cannot be read "
                             f"(HDF5: {text})") from None
    return wrapped


def _identity(path) -> tuple:
    """What tells a file from the one that replaces it at the same path: its device,
    inode, size and modification time."""
    st = os.stat(path)
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


# --------------------------------------------------------------------------- save



def save_result(result: SeriesResult, path, *, pixel_size: float | None = None,
                unit: str | None = None, overwrite: bool = False,
                attrs: Mapping | None = None, phase_maps: bool = False,
                lossless: bool = False) -> Path:
    """Write a :class:`~gridstrain.results.SeriesResult` to one HDF5 file, atomically.

    Parameters
    ----------
    result : SeriesResult
    path : str or os.PathLike
        Destination (``.h5`` or ``.nc``).
    pixel_size : float, optional
        Size of a pixel on the specimen, in ``unit``: adds ``x_phys``, ``y_phys``,
        ``ux_phys`` and ``uy_phys``. Default the result's own
        (:attr:`SeriesResult.pixel_size`); given, it is the saved result's (loaded
        back with it).
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
    lossless : bool
        Store the per-state maps exactly as measured (float64 unless the
        measurement is float32), uncompressed. By default they are stored in
        float32, each map rounded to a tenth of its own std at each pixel and the
        std maps to a relative 1.6 %, then compressed (see Notes).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ValueError
        ``result.u``, ``.strain`` or ``.valid`` not of one state per measurement and
        the maps' shape.

    Notes
    -----
    The layout is described in :mod:`gridstrain.results`; ``xarray.open_dataset``
    opens it, :func:`load` reads it back. The maps stored are the result's own
    ``u``, ``strain`` and ``valid`` (a result changed with ``dataclasses.replace``
    is saved as it is); the measurements come back with them.

    The rounding of the default file: each
    map ``ux, uy, exx, eyy, exy`` (and ``ux_phys, uy_phys``) is rounded at each pixel
    to the nearest multiple of the largest power of two ``q <= 0.2 s``, ``s`` its
    predicted std there (``ux_std``...; the rotation uses ``exy_std``, its std under
    the same noise model), so that the error is at most ``0.1 s``: the mantissa bits
    below ``q`` are zero, which the compressor (HDF5 shuffle and deflate) then drops.
    The std maps keep 5 mantissa bits (relative error at most ``2**-6`` = 1.6 %). Where a
    map has no std (none predicted, or NaN), its values keep float32's precision
    (relative ``2**-24``). Each variable's attributes say how it was rounded
    (``rounding``, ``rounding_std_variable``, ``rounding_std_fraction``, and
    ``rounding_max_error_over_std``: the largest error over the std actually made,
    per state), the root attribute ``maps_lossless`` which of the two the file is.
    The validity maps, the mask and every other variable are stored losslessly.
    """
    check_type(result, "result", SeriesResult)
    lossless = check_type(lossless, "lossless", bool)
    ps, unit = check_pixel_size(pixel_size, unit)
    if ps is None:  # the result's own, stored as the file's
        ps, unit = result.pixel_size, result.unit
    elif (ps, unit) != (result.pixel_size, result.unit):
        result = dataclasses.replace(result, pixel_size=ps, unit=unit)
    attrs = check_mapping(attrs, "attrs", allow_none=True)
    H, W = result.shape
    _check_own_maps(result)
    n_series = len(result.names)
    with hdf5_file(path, overwrite=overwrite) as h5:
        _write_dimensions(h5, result, H, W)
        _write_maps(h5, result, ps, unit, H, W, lossless=lossless)
        _write_tables(h5, result, ps, unit, attrs, n_series, lossless=lossless)
        _write_group(h5, result, attrs, phase_maps=phase_maps)
    return as_path(path, "path")



def _check_own_maps(result: SeriesResult) -> None:
    """The result's maps, which the file stores, have one state per measurement and
    the shapes the layout lays out (a result changed with ``dataclasses.replace`` is
    saved as it is, or refused here, never saved with its measurements' maps)."""
    n, (H, W) = len(result.measurements), result.shape
    for name, shape, kinds in (("u", (n, 2, H, W), "f"), ("strain", (n, 3, H, W), "f"),
                               ("valid", (n, H, W), "b")):
        arr = getattr(result, name)
        if tuple(arr.shape) != shape or np.dtype(arr.dtype).kind not in kinds:
            raise ValueError(f"result.{name} must be a {shape} "
                             f"{'bool' if kinds == 'b' else 'floating-point'} array (one "
                             f"state per measurement, {n}), got shape {tuple(arr.shape)} "
                             f"dtype {arr.dtype}")


# --------------------------------------------------------------------------- streaming


@dataclass(frozen=True)
class ResultFile:
    """Where and how :func:`gridstrain.series.measure_series` writes its result
    while it measures (``output=``): each state's maps go to the file as soon as they
    are measured and leave memory, so that memory does not grow with the number of
    states. The file is the one :func:`save_result` writes (put at ``path``
    atomically when the measurement ends; nothing there if it fails).

    Attributes
    ----------
    path : str or os.PathLike
        Destination (``.h5`` or ``.nc``).
    pixel_size, unit, overwrite, attrs, lossless
        As for :func:`save_result`: by default the maps are stored in float32,
        rounded to a tenth of their std and compressed.
    dtype : {None, "float32", "float64"}
        Precision of the maps of a lossless file; None keeps that of the
        measurement (:mod:`gridstrain.conventions`). float32 halves the lossless
        file and keeps a displacement below 1024 px to 3.1e-5 px (half the spacing
        of float32 numbers below 1024, 2^-14) and a strain below 1 to 3e-8; the
        measurement itself is computed as without it. A dtype needs
        ``lossless=True`` (a rounded file's maps are float32).
    """

    path: object
    pixel_size: float | None = None
    unit: str | None = None
    overwrite: bool = False
    attrs: Mapping | None = None
    dtype: object = None
    lossless: bool = False

    def __post_init__(self):
        check_type(self.lossless, "lossless", bool)
        if self.dtype is not None and not self.lossless:
            raise ValueError(f"dtype={self.dtype!r} is the precision of a lossless file's "
                             "maps: give lossless=True with it (a rounded file's maps "
                             "are float32)")
        as_path(self.path, "path")
        ps, unit = check_pixel_size(self.pixel_size, self.unit)
        object.__setattr__(self, "pixel_size", ps)
        object.__setattr__(self, "unit", unit)
        object.__setattr__(self, "attrs", dict(check_mapping(self.attrs, "attrs",
                                                             allow_none=True)))
        object.__setattr__(self, "dtype", check_float_dtype(self.dtype, "dtype"))


class StoredMaps(np.lib.mixins.NDArrayOperatorsMixin):
    """Maps of a result file, read from it when indexed: a read-only array of shape
    ``(n_states, [components,] H, W)`` (or of one state) whose ``[i]`` reads state
    ``i`` only, ``[[i, j, ...]]`` those states only and ``[:, c]`` is component ``c``'s
    own view (``result.ux``), so that a long series is looked at state by state
    without being loaded. ``numpy.asarray``, NumPy's functions and operators, and the
    methods of an array (``.mean()``, ``.reshape()``...) read the whole. A variable
    that is no longer of the shape and type it had when the view was made (the file
    replaced) is refused, not read.

    Parameters
    ----------
    path : str or os.PathLike
        The result file.
    names : str or tuple of str
        The variable, or the variables stacked along the component axis.
    state : int, optional
        One state only (no state axis).
    identity : tuple, optional
        The file's :func:`_identity` when it was opened: a file replaced (or changed)
        since is refused, not read.
    """

    def __init__(self, path, names, *, state: int | None = None, layout=None,
                 identity: tuple | None = None):
        self.path = as_path(path, "path")
        self._names = names
        self._state = state
        self._identity = identity
        if layout is None:  # (n_states, H, W, dtype) of the variables
            with h5py.File(self.path, "r") as h5:
                first = _member(h5, names if isinstance(names, str) else names[0])
                layout = (*first.shape, first.dtype)
        n, H, W, dtype = layout
        self._n, self.dtype = n, np.dtype(dtype)
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

    def _layout(self) -> tuple:
        return (self._n, *self.shape[-2:], self.dtype)

    def _dataset(self, h5, name: str):
        """The variable ``name``, still of the shape and type it had when this view
        was made (the file may have been replaced since: refused, not misread)."""
        ds = _member(h5, name)
        n, H, W, dtype = self._layout()
        if not isinstance(ds, h5py.Dataset) or ds.shape != (n, H, W) \
                or ds.dtype.kind != dtype.kind:
            raise ValueError(f"{self.path}: /{name} is no longer the ({n}, {H}, {W}) "
                             f"{dtype} variable it was when the file was opened")
        return ds

    @_file_errors
    def _read(self, states) -> np.ndarray:
        with _opened(self.path, self._identity) as h5:
            if isinstance(self._names, str):
                return np.asarray(self._dataset(h5, self._names)[states])
            axis = 0 if isinstance(states, numbers.Integral) else 1
            return np.stack([np.asarray(self._dataset(h5, n)[states]) for n in self._names],
                            axis=axis)

    def _read_states(self, which) -> np.ndarray:
        """The states ``which`` (a sequence of indices, any order, repeats allowed),
        reading those only."""
        n = self.shape[0]
        idx = np.asarray(which)
        if idx.size == 0:
            return np.empty((0, *self.shape[1:]), self.dtype)
        if idx.ndim != 1 or idx.dtype.kind not in "iu":
            return np.asarray(self)[idx]  # a mask or anything else: from the whole
        if not -n <= idx.min() <= idx.max() < n:
            raise IndexError(f"states {which!r} out of range for {n} states")
        # HDF5 reads increasing indices only: each state once, then put in order
        unique, back = np.unique(idx % n, return_inverse=True)
        return self._read(list(unique))[back]

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        if self._state is not None:
            return self._read(self._state)[key]
        first, rest = key[0], key[1:]
        if isinstance(first, slice) and first == slice(None) and rest \
                and not isinstance(self._names, str) \
                and isinstance(rest[0], numbers.Integral) and not isinstance(rest[0], bool):
            # one component of every state (result.ux): a view, read when indexed
            j = int(rest[0])
            if not -len(self._names) <= j < len(self._names):
                raise IndexError(f"component {j} out of range for {len(self._names)}")
            view = StoredMaps(self.path, self._names[j], layout=self._layout(),
                              identity=self._identity)
            return view[(slice(None), *rest[1:])] if len(rest) > 1 else view
        if isinstance(first, numbers.Integral) and not isinstance(first, bool):
            i = int(first)
            if not -self.shape[0] <= i < self.shape[0]:
                raise IndexError(f"state {i} out of range for {self.shape[0]} states")
            out = self._read(i % self.shape[0])
        elif isinstance(first, slice):
            out = self._read(first)
            return out[(slice(None), *rest)] if rest else out
        elif isinstance(first, list | tuple | np.ndarray) and all(
                isinstance(k, slice | numbers.Integral) for k in rest):
            # chosen states (the rest basic indices: the same as on the whole)
            out = self._read_states(first)
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


# The files whose handles are kept between reads, in a block of :func:`kept_open`
_KEPT: contextvars.ContextVar[dict | None] = contextvars.ContextVar("kept", default=None)


@contextlib.contextmanager
def kept_open() -> Iterator[None]:
    """Inside the block, the reads of :class:`StoredMaps` in this thread keep one open
    handle per file, closed when the block ends (outside, each read opens and closes
    its file: 0.9 ms a read, more than reading a map of 250 x 400 px). A file
    replaced or changed since :func:`load` read it (another inode, size or time) is
    refused; the maps of a file being written, which have no such record, open it
    again and check each variable's layout."""
    if _KEPT.get() is not None:  # nested: the outer block keeps them
        yield
        return
    kept: dict = {}
    token = _KEPT.set(kept)
    try:
        yield
    finally:
        _KEPT.reset(token)
        for _, h5 in kept.values():
            h5.close()


def _opened(path: Path, identity: tuple | None = None):
    """``path`` opened for reading, as a context: its kept handle inside
    :func:`kept_open`, else a handle of its own, closed after the read. With the
    ``identity`` the file had when it was loaded, a file replaced since (``mv``,
    ``measure --overwrite``) or changed is refused: the states read so far came from
    the other one."""
    key = _identity(path)
    if identity is not None and key != identity:
        raise ValueError(f"{path}: the result file was replaced or changed since it was "
                         "opened; nothing more is read from it (the states read so far "
                         "came from the file as it was): run again on the file as it is "
                         "now")
    kept = _KEPT.get()
    if kept is None:
        return h5py.File(path, "r")
    found = kept.get(path)
    if found is None or found[0] != key:
        if found is not None:
            found[1].close()
        found = kept[path] = (key, h5py.File(path, "r"))
    return contextlib.nullcontext(found[1])


def _stored(path, h5, names, state: int | None = None, identity=None) -> StoredMaps:
    """The maps ``names`` of the result file ``h5`` (open, at ``path``), left in it."""
    first = h5[names if isinstance(names, str) else names[0]]
    return StoredMaps(path, names, state=state, layout=(*first.shape, first.dtype),
                      identity=identity)


class StreamedResult:
    """The sink of :func:`gridstrain.series.measure_series` that writes each state
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
        self._kept = _Kept()  # the largest rounding errors, written at the end
        self._made: set[str] = set()  # the maps whose variables are in the file

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
        lossless = self.spec.lossless
        if not self._made.issuperset(arrays):
            # once per variable: looking each one up in the file cost 0.17 ms a state
            _create_maps(self.h5, arrays, self.n, self.spec.pixel_size, self.spec.dtype,
                         lossless=lossless)
            self._made.update(arrays)
        _put_state(self.h5, i, arrays, self.spec.pixel_size, lossless=lossless,
                   kept=self._kept)
        self._lossless[i] = lossless and self.h5["ux"].dtype == res.u.dtype
        self.stream.check()  # a full disk is reported now, not after the last state
        if not self.measurements:
            self._check_room()
        # the measurement without its maps (they are in the file) and phase maps
        self.measurements.append(dataclasses.replace(
            res, **dict.fromkeys(("u", "strain", "rotation", "valid"), _EMPTY),
            reference=None, deformed=None))
        self.orders.append(rec)
        self.floors.append(floors)
        self.smoothing.append(smooth)

    def _check_room(self) -> None:
        """Once the first state is written: refuse a record whose other states' maps
        cannot fit on the disk it is written to, rather than fail hours later. A state
        is taken to need what the first one took (compressed, where it is)."""
        self.h5.flush()
        per_state = sum(ds.id.get_storage_size() for ds in self.h5.values()
                        if isinstance(ds, h5py.Dataset) and ds.ndim == 3)
        need = per_state * (self.n - 1)
        try:
            free = shutil.disk_usage(self.path.resolve().parent).free
        except OSError:  # no figure from this file system: nothing to compare
            return
        if need > free:
            raise OSError(f"cannot write {self.path}: the maps of its {self.n - 1} other "
                          f"states need about {format_size(need)} more on that disk, and "
                          f"{format_size(free)} are free; nothing was written; free some "
                          "space or write elsewhere" + (
                              ", or store the maps rounded to a tenth of their std (leave "
                              "out --lossless; ResultFile(lossless=False)), a fraction of "
                              "their lossless size" if self.spec.lossless else ""))

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
            return _stored(self.path, h5, names, state)

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
            uncertainty={k: lazy(k) for k in self.unc_names} or None,
            # read from the file: its pixel size, and its rounding when it rounds
            **{"pixel_size": spec.pixel_size, "unit": spec.unit,
               "maps_precision": None if spec.lossless else ROUNDED_TEXT, **fields})
        H, W = result.shape
        ps, unit = spec.pixel_size, spec.unit
        _put_errors(h5, self._kept)
        _write_dimensions(h5, result, H, W)
        _describe_maps(h5, ps, unit, H, W, self.unc_names)
        _write_images(h5, result, ps)
        _write_tables(h5, result, ps, unit, spec.attrs, len(result.names),
                      lossless=spec.lossless)
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
        if version not in _READ_VERSIONS or isinstance(version, bool):
            raise _Bad(f"{p} is a gridstrain result file of format {version!r}; this "
                       "gridstrain reads formats "
                       + ", ".join(map(str, _READ_VERSIONS)))
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
            # the row of the series in the column (vibration/{i}/shifts in format 2)
            raise _Bad(f"{path}: /{_GROUP}/result/vibration/shifts[{i}]: expected shape "
                       f"({v.n_frames}, 2), got {np.shape(v.shifts)}")
    return result


@_file_errors
def load(path, *, in_memory: bool = True) -> SeriesResult:
    """Read a result file written by :func:`save_result`.

    Nothing in the file is run or imported: the classes it may hold are a fixed
    list (gridstrain's result classes, and subclasses of them the program defined
    already), and every value is checked (type, shape, dtype, the size it declares
    against the memory available) before it is used.

    Parameters
    ----------
    path : str or os.PathLike
    in_memory : bool
        Read every map into memory (the default). False leaves the per-state maps
        (displacement, strain, rotation, validity, uncertainty; the result's and each
        measurement's) in the file as :class:`StoredMaps`, read state by state when
        indexed: a record of thousands of states is then looked at, gauged or
        reported on in the memory of a few states. The file must stay in place
        while the result is used: once it is replaced or changed, the maps' reads
        are refused (ValueError naming the file), never read from the other file.

    Returns
    -------
    SeriesResult
        Equal, field by field, to the result that was saved (arrays bit for bit),
        with the pixel size it was saved with (:attr:`SeriesResult.pixel_size`);
        the measurements' ``reference`` and ``deformed`` phase maps are ``None``
        unless they were saved (``save_result(..., phase_maps=True)``).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        The file is not a gridstrain result file, or is damaged (HDF5 cannot read
        it), or a field of it is not what the layout says (the message names the
        file and the field), or it declares more data than the memory available.
    """
    in_memory = check_type(in_memory, "in_memory", bool)
    with _open(path) as h5:
        maps, unc, (n, H, W) = _map_datasets(h5)
        stored = sum(int(ds.size) * ds.dtype.itemsize for ds in (*maps.values(),
                                                                  *unc.values()))
        # read once, then copied into the stacks and the measurements; left in the
        # file, the maps take no memory
        _check_memory(h5.filename, 2 * (_declared_bytes(h5) - (0 if in_memory else stored)),
                      "its datasets")
        if in_memory:
            def stack(names):
                out = np.empty((n, len(names), H, W),
                               np.result_type(*(maps[k].dtype for k in names)))
                for j, k in enumerate(names):
                    out[:, j] = _read_dataset(maps[k], kinds="f")
                return out

            def read(k, kinds="biufc"):
                return _read_dataset(maps[k] if k in maps else unc[k], kinds=kinds)

            def state(arr, i):
                return arr[i].copy()
        else:
            # their types checked already (_map_datasets)
            where = Path(h5.filename).resolve()
            identity = _identity(where)  # the file read now, and only it later

            def stack(names):
                return _stored(where, h5, names, identity=identity)

            def read(k, kinds=None):
                return _stored(where, h5, k, identity=identity)

            def state(arr, i):
                return _stored(where, h5, arr._names, i, identity=identity)

        own_ps, own_unit = _file_pixel_size(h5)
        own_precision = _file_precision(h5)
        u, strain = stack(("ux", "uy")), stack(("exx", "eyy", "exy"))
        valid = read("valid", kinds="b")
        rotation = read("rotation", kinds="f")
        root = {"u": u, "strain": strain, "valid": valid,
                "mask": _read_dataset(h5["mask"], kinds="b"),
                "reference_image": _read_dataset(h5["reference_image"], kinds="f"),
                "uncertainty": ({k: read(k) for k in _UNC_KEYS if k in unc}
                                | {k: read(k) for k in unc if k not in _UNC_KEYS})
                if unc else None}

        def fill(cls, group, values, row):
            if cls.__name__ == "SeriesResult":
                values.update(root)
                # the file's root attributes say its pixel size (files that stored it
                # there only, or none, load all the same)
                values.update(pixel_size=own_ps, unit=own_unit,
                              maps_precision=own_precision)
            elif cls.__name__ == "Measurement" and (
                    row is not None or group.parent.name.endswith("/measurements")):
                # the state: its row in the measurements written by columns (format 3),
                # or the name of its group (format 2)
                i = str(row) if row is not None else group.name.rsplit("/", 1)[1]
                if not i.isdigit() or int(i) >= n:
                    raise _Bad(f"{_where(group)}: a measurement beyond the {n} states of "
                               "the maps")
                i = int(i)
                values.update(u=state(u, i), strain=state(strain, i),
                              rotation=state(rotation, i), valid=state(valid, i))
                values.setdefault("reference", None)  # saved without the phase maps
                values.setdefault("deformed", None)
            elif cls.__name__ == "NoiseFloor":
                # files of format 2 stored the window's FWHM; it follows from sigma
                values.pop("resolution", None)
            return values

        if "result" not in h5[_GROUP]:
            raise _Bad(f"{_where(h5[_GROUP], 'result')}: missing")
        result = decoded(_member(h5[_GROUP], "result"), {}, fill)
        if not isinstance(result, SeriesResult):
            raise _Bad(f"{_where(h5[_GROUP], 'result')}: expected a SeriesResult, got "
                       f"{_received(result)}")
        return _check_result(h5.filename, result)


def _file_precision(h5) -> str | None:
    """None for a file whose maps are as measured; else how they were rounded (its
    ``maps_precision``, or a word for a file that says only ``maps_lossless``)."""
    lossless = _attr(h5, "maps_lossless") if "maps_lossless" in h5.attrs else True
    if bool(lossless):
        return None
    text = _attr(h5, "maps_precision") if "maps_precision" in h5.attrs else None
    return str(text) if text else "rounded (float32)"


def _file_pixel_size(h5) -> tuple[float | None, str | None]:
    """The root attributes ``pixel_size`` and ``unit``, checked; ``(None, None)`` when
    the file has none."""
    ps, unit = (_attr(h5, k) if k in h5.attrs else None for k in ("pixel_size", "unit"))
    if ps is None or unit is None:
        return None, None
    try:
        return check_pixel_size(float(ps), str(unit))
    except (TypeError, ValueError) as exc:
        raise _Bad(f"{_where(h5, 'pixel_size')}: {exc}") from None


#: Root attributes whose type a reader relies on (the report, the plots, the replay).
_ATTR_TYPES = {"pixel_size": float, "unit": str, "config": str, "config_file": str,
               "mask_file": str, "created": str, "gridstrain_version": str,
               "conventions": str}


@_file_errors
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
                check_pixel_size(out["pixel_size"], out.get("unit"))
            except ValueError as exc:
                raise _Bad(f"{_where(h5, 'unit')}: {exc}") from None
        if "attrs" in h5[_GROUP]:
            group = _member(h5[_GROUP], "attrs")
            if isinstance(group, h5py.Group):  # else refused by decoded
                _check_memory(h5.filename, _declared_bytes(group), "its attributes")
            extra = decoded(group, {}, lambda c, g, v, row: v)
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
                            unit=unit, lossless=True)
            with xr.open_dataset(p, engine="h5netcdf") as ds:
                return ds.load()
    with xr.open_dataset(as_path(result_or_path, "path"), engine="h5netcdf") as ds:
        return ds.load()





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
