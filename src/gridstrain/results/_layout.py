"""The layout of a result file: CF-style variables with their dimensions, units and long
names (the maps, the images, the coordinates, the per-series tables, the noise floor and the
metrology), written the same way by a whole result and by a file written state by state.
"""

from __future__ import annotations

import dataclasses
import os
import zlib
from collections.abc import Mapping

import h5py
import numpy as np

from .. import __version__
from ..io import provenance
from ._codec import (
    _FILTERS,
    _ROOT_FIELDS,
    _array,
    _check_key,
    _dataset,
    _encode,
    _scalar_kind,
    _utf8,
)
from ._precision import (
    MAX_ERROR_ATTR,
    STD_BITS,
    STD_FRACTION,
    STD_OF,
    _kernels,
    round_relative,
    round_to_least_std,
)
from ._result import MAP_FIELDS

#: Version of the file layout; :func:`load` refuses other versions by name. Format 3 writes
#: the lists of states and series by columns (:mod:`._codec`); format 2 wrote them value by
#: value, which the reader of format 3 reads too.
FORMAT_VERSION = 3
_READ_VERSIONS = (2, 3)
_GROUP = "gridstrain"
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


# The per-state float maps of a lossless file: checksummed, stored as they are.
_CHECKSUM = {"fletcher32": True}


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


#: How a rounded file's maps are stored, in words (its ``maps_precision``).
ROUNDED_TEXT = (f"float32, each map rounded to {STD_FRACTION:g} of its std at each pixel "
                f"(rotation: of exy's), the std maps to {STD_BITS} mantissa bits (relative "
                f"{2.0 ** -(STD_BITS + 1):.2g}); see each variable's rounding attributes")


def _write_tables(h5, result, ps, unit, attrs: Mapping, n_series: int, *,
                  lossless: bool) -> None:
    """The variables of the series and states (vibrations, noise floor, metrology) and
    the root attributes (see the module's layout)."""
    lat = result.lattice
    _write_vibrations(h5, result, n_series)
    _write_noise(h5, result, lat)
    _write_metrology(h5, result)
    root = _root_attributes(result, ps, unit, lat)
    rounded_before = getattr(result, "maps_precision", None)
    # maps read from a rounded file are not made lossless by being written as they are
    root["maps_lossless"] = bool(lossless) and rounded_before is None
    root["maps_precision"] = (
        f"written as read from a file that had rounded them: {rounded_before}"
        if lossless and rounded_before is not None else
        "lossless: the maps as measured" if lossless else ROUNDED_TEXT)
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


def _write_maps(h5, result, ps, unit, H: int, W: int, *, lossless: bool) -> None:
    """Maps of every state (px values, and physical ones with a pixel size), their
    predicted standard deviations, the mean reference frame and the mask.

    The displacement, strain and validity maps are the result's own (``result.u``,
    ``.strain``, ``.valid``), not its measurements' copies: a result changed with
    ``dataclasses.replace(result, u=...)`` is saved as it is, and its measurements
    come back from the file with those maps. The rotation, which the result does
    not hold, is the measurement's."""
    unc = result.uncertainty or {}
    kept = _Kept()  # the largest rounding errors, written once, and open variables
    for k, m in enumerate(result.measurements):
        own = dataclasses.replace(m, u=np.asarray(result.u[k]),
                                  strain=np.asarray(result.strain[k]),
                                  valid=np.asarray(result.valid[k]))
        arrays = _state_arrays(own, {n: a[k] for n, a in unc.items()})
        if k == 0:
            _create_maps(h5, arrays, result.n_states, ps, lossless=lossless)
        _put_state(h5, k, arrays, ps, lossless=lossless, kept=kept)
    _put_errors(h5, kept)
    _describe_maps(h5, ps, unit, H, W, list(unc))
    _write_images(h5, result, ps)


def _write_images(h5, result, ps) -> None:
    """The mean reference frame and the mask."""
    extra = {"coordinates": "x_phys y_phys"} if ps is not None else {}
    _var(h5, "reference_image", result.reference_image, ("y", "x"), "1",
         "mean reference frame, raw grey levels", **extra)
    _var(h5, "mask", result.mask, ("y", "x"), None,
         "specimen mask used (given mask less regions without a grid)", **extra)


def _create_maps(h5, arrays: dict, n: int, ps, dtype=None, *, lossless: bool = True) -> None:
    """Empty (n, H, W) variables for the maps of ``arrays`` (one state's), chunked by
    state; NaN (False for ``valid``) until a state is written. Lossless: in ``dtype``
    (None: the maps' own), the floating-point maps checksummed and not compressed.
    Otherwise in float32, rounded by :func:`_put_state` (:mod:`._precision`) and
    compressed, with the rounding in each variable's attributes."""
    names = list(arrays)
    if ps is not None:
        names += [f"{k}_phys" for k in ("ux", "uy") if k in arrays]
    for name in names:
        if name in h5:
            continue
        arr = arrays[name.removesuffix("_phys")]
        shape = (n, *arr.shape)
        if arr.dtype == bool:
            # the validity maps shrink 100-fold
            h5.create_dataset(name, shape=shape, dtype=bool, chunks=(1, *arr.shape),
                              fillvalue=False, **_FILTERS)
            continue
        if lossless:
            # the measured maps' lower bytes are noise: deflate would spend CPU on
            # them for little size (benchmarks/README.md)
            h5.create_dataset(name, shape=shape, dtype=np.dtype(dtype or arr.dtype),
                              chunks=(1, *arr.shape), fillvalue=np.nan, **_CHECKSUM)
            continue
        ds = h5.create_dataset(name, shape=shape, dtype=np.float32, chunks=(1, *arr.shape),
                               fillvalue=np.nan, **_FILTERS)
        ds.attrs.update(_rounding_attrs(name, arrays, n))


def _rounding_attrs(name: str, arrays: dict, n: int) -> dict:
    """The attributes saying how the float32 map ``name`` is rounded."""
    if name.endswith("_std"):
        return {"rounding": "relative", "rounding_mantissa_bits": np.int64(STD_BITS),
                "rounding_relative_error": np.float64(2.0 ** -(STD_BITS + 1))}
    std = STD_OF.get(name)
    if std is None or std not in arrays:
        return {"rounding": "float32"}
    return {"rounding": "std", "rounding_std_variable": std,
            "rounding_std_fraction": np.float64(STD_FRACTION),
            MAX_ERROR_ATTR: np.full(n, np.nan)}


class _Kept:
    """What a writer of many states keeps from one state to the next: a rounded
    file's largest errors (``errors``, see :func:`_rounded`), written once by
    :func:`_put_errors`, and its compressed variables opened for
    :func:`_put_compressed` (``opened``: name -> the dataset and its deflate level)."""

    def __init__(self):
        self.errors: dict = {}
        self.opened: dict = {}


def _put_state(h5, k: int, arrays: dict, ps, *, lossless: bool = True,
               kept: _Kept | None = None) -> None:
    """Write state ``k``'s maps into the variables of :func:`_create_maps`. A rounded
    file's largest errors go to ``kept``, which the caller writing many states
    then writes once (:func:`_put_errors`); into the file at once without it."""
    if not lossless:
        now = kept is None
        kept = _Kept() if now else kept
        arrays = _rounded(h5, k, arrays, ps, kept.errors)
        if now:
            _put_errors(h5, kept)
    for name, arr in arrays.items():
        if not lossless:
            _put_compressed(h5, name, k, arr, kept.opened)
            continue
        h5[name][k] = arr
        if ps is not None and name in ("ux", "uy"):
            h5[f"{name}_phys"][k] = np.asarray(arr) * ps


# A compressed map's filters in HDF5's pipeline order, as _FILTERS creates them
_PIPELINE = (h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_DEFLATE, h5py.h5z.FILTER_FLETCHER32)


def _put_compressed(h5, name: str, k: int, arr: np.ndarray, opened: dict) -> None:
    """State ``k``'s map ``arr`` into the compressed variable ``name``, one chunk. With
    the compiled loops, the chunk is encoded here and written as it is: shuffled,
    deflated (:func:`_deflate`) and checksummed as HDF5's filters do
    (:mod:`gridstrain.results._kernels`), so that HDF5 decodes it to the same values,
    without the copies of the map that HDF5's pipeline makes; through the pipeline
    otherwise, or for a variable whose filters or chunks are not a compressed map's.
    ``opened``: the variables opened for earlier states, name -> (dataset, deflate
    level or None, the dtype and shape of the map it was found for), kept for the
    next."""
    kern = _kernels()
    if name not in opened:
        ds = _uncached(h5, name)
        level = None if kern is None else _deflate_level(ds, arr)
        opened[name] = ds, level, getattr(arr, "dtype", None), getattr(arr, "shape", None)
    ds, level, dtype, shape = opened[name]
    if level is None or kern is None or not (
            isinstance(arr, np.ndarray) and arr.dtype == dtype and arr.shape == shape):
        ds[k] = arr
        return
    raw = np.ascontiguousarray(arr).reshape(-1).view(np.uint8)
    shuffled = np.empty_like(raw)
    kern.shuffle(raw, arr.dtype.itemsize, shuffled)
    data = _deflate()(shuffled, level)
    check = int(kern.fletcher32(np.frombuffer(data, dtype=np.uint8)))
    ds.id.write_direct_chunk((k, *(0,) * arr.ndim), data + check.to_bytes(4, "little"))


def _deflate():
    """The deflate of a chunk written directly: ISA-L's (``isal``, the ``fast`` extra,
    PSF-2.0 over Intel's BSD-3-Clause library) when it is installed, zlib's otherwise.
    Both write the zlib format that HDF5's deflate filter inflates, so that any HDF5
    reader decodes the file; ISA-L's levels 0 to 3 are its own (level 1, the file's, is
    about 6 times faster than zlib's on a state's shuffled maps, and its chunks about
    a tenth smaller), and a level above 3 is zlib's."""
    global _DEFLATE
    if _DEFLATE is None:
        try:
            from isal import isal_zlib
        except ImportError:
            _DEFLATE = zlib.compress
        else:
            def _DEFLATE(data, level):
                if level > isal_zlib.ISAL_BEST_COMPRESSION:
                    return zlib.compress(data, level)
                return isal_zlib.compress(data, level)
    return _DEFLATE


_DEFLATE = None


def _deflate_level(ds: h5py.Dataset, arr) -> int | None:
    """The deflate level of ``ds`` when a state's map ``arr`` is one whole chunk of it
    in its own dtype and its filters are :data:`_PIPELINE`; None otherwise."""
    if not (isinstance(arr, np.ndarray) and arr.dtype == ds.dtype and arr.size > 1
            and ds.chunks == (1, *arr.shape)):
        return None
    dcpl = ds.id.get_create_plist()
    filters = [dcpl.get_filter(i) for i in range(dcpl.get_nfilters())]
    if tuple(f[0] for f in filters) != _PIPELINE:
        return None
    return int(filters[1][2][0])


def _uncached(h5, name: str) -> h5py.Dataset:
    """Variable ``name`` of ``h5`` opened without a chunk cache: a state's compressed
    map is one whole chunk, written once, so that it goes to its filters and the file
    at once rather than through a cache buffer allocated, filled and copied for it
    (the same bytes in the file; the uncompressed maps of a lossless file gained
    nothing from it)."""
    dapl = h5py.h5p.create(h5py.h5p.DATASET_ACCESS)
    dapl.set_chunk_cache(0, 0, 1.0)  # slots, bytes, preemption
    return h5py.Dataset(h5py.h5d.open(h5.id, name.encode(), dapl))


def _rounded(h5, k: int, arrays: dict, ps, errors: dict) -> dict:
    """State ``k``'s maps as a rounded file stores them (``*_phys`` included), the
    largest error over the std of each put at ``k`` in ``errors[name]``: its
    variable's attribute :data:`MAX_ERROR_ATTR` as read from the file on its first
    state, to be written back by :func:`_put_errors` (an attribute read and written
    for every map of every state cost about 1 ms a state)."""
    out = {}
    stds = {}
    for name, arr in arrays.items():
        if name.endswith("_std"):
            out[name] = round_relative(arr)
            # the bound holds against the measured std and the stored one alike: the
            # smaller of the two, taken pixel by pixel as each map is rounded
            stds[name] = arr
    todo = [(n, a, 1.0) for n, a in arrays.items() if not n.endswith("_std")]
    if ps is not None:
        todo += [(f"{n}_phys", arrays[n], ps) for n in ("ux", "uy")]
    for name, arr, scale in todo:
        if arr.dtype == bool:
            out[name] = arr
            continue
        values = np.asarray(arr, dtype=np.float64)
        if name not in errors:  # None: a variable not rounded to a std
            attrs = h5[name].attrs
            errors[name] = np.array(attrs[MAX_ERROR_ATTR], dtype=np.float64) \
                if attrs.get("rounding") == "std" else None
        if errors[name] is None or STD_OF[name] not in stds:
            # no std: float32's own precision
            out[name] = (values * scale if scale != 1.0 else values).astype(np.float32)
            continue
        std = STD_OF[name]
        out[name], errors[name][k] = round_to_least_std(values, stds[std], out[std],
                                                        scale=scale)
    return out


def _put_errors(h5, kept: _Kept) -> None:
    """The largest rounding errors gathered by :func:`_rounded` into their variables'
    attributes."""
    for name, e in kept.errors.items():
        if e is not None:
            h5[name].attrs[MAX_ERROR_ATTR] = e


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
        # each warning's code (gridstrain.FINDINGS), in the same order: what a reader of
        # the attributes alone selects them by
        "warning_codes": [w.code for w in result.warnings],
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
             "window smoothing of strain gradients, bound on the peak error: the larger "
             "of 3 x the largest sigma^2/2 lap(e) and 1.5 x the sharpest feature's "
             "deconvolved peak error")
        h5.attrs["systematic_aliasing_u_px"] = float(sy["aliasing"]["u_px"])
        h5.attrs["systematic_aliasing_strain_per_strain"] = float(
            sy["aliasing"]["strain_per_strain"])
