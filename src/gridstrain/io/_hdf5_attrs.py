"""HDF5 attributes and datasets read and checked: attributes as JSON where they are lists,
dicts or None, names checked, a file's datasets and attributes read back whole, and a
stored noise model read from its file.
"""

from __future__ import annotations

import json
import numbers
import os
from collections.abc import Mapping

import h5py
import numpy as np

from .._validation import as_path, check_mapping, check_name
from ._series import _JSON_ATTRS, _UNITS_ATTR


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _encode_attr(key, value, where: str):
    """``(value to store, stored as JSON?)`` for one HDF5 attribute."""
    check_name(key, f"{where} keys")
    if key == _JSON_ATTRS:
        raise ValueError(f"{where}[{key!r}]: the name {_JSON_ATTRS!r} is reserved")
    label = f"{where}[{key!r}]"
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            # a path with a byte that is not UTF-8 (decoded by Python with
            # surrogateescape): HDF5 stores UTF-8 only, JSON escapes it exactly
            return json.dumps(value), True
        return value, False
    if isinstance(value, bool | np.bool_):
        return np.bool_(value), False
    if isinstance(value, numbers.Integral):
        if -(2**63) <= int(value) < 2**63:
            return np.int64(value), False
        return json.dumps(int(value)), True
    if isinstance(value, numbers.Real):
        return np.float64(value), False
    if isinstance(value, numbers.Complex):
        return np.complex128(value), False
    if isinstance(value, np.ndarray) and value.dtype.kind in "biufc":
        return value, False
    if value is None or isinstance(value, list | tuple | dict | np.ndarray):
        try:
            return json.dumps(value, default=_json_default), True
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{label} cannot be stored as JSON: {exc}") from exc
    raise TypeError(f"{label} has unsupported type {type(value).__name__}; use str, "
                    "numbers, numeric arrays, lists or dicts")


def _write_attrs(obj, attrs: Mapping, where: str) -> None:
    json_keys = []
    for key, value in attrs.items():
        stored, is_json = _encode_attr(key, value, where)
        obj.attrs[key] = stored
        if is_json:
            json_keys.append(key)
    if json_keys:
        obj.attrs[_JSON_ATTRS] = json.dumps(json_keys)


def _read_attrs(obj) -> dict:
    raw = dict(obj.attrs)
    json_keys = set(json.loads(raw.pop(_JSON_ATTRS))) if _JSON_ATTRS in raw else set()
    out = {}
    for key, value in raw.items():
        if isinstance(value, bytes):
            value = value.decode("utf-8")
        if key in json_keys:
            value = json.loads(value)
        elif isinstance(value, np.generic):
            value = value.item()
        out[key] = value
    return out


def _check_h5_name(key, what: str) -> str:
    if not isinstance(key, str) or not key or key.startswith("/") or key.endswith("/") \
            or "//" in key or key in (".", ".."):
        raise ValueError(f"{what} names must be non-empty relative HDF5 paths such as "
                         f"'maps/u', got {key!r}")
    return key


def _dataset_arrays(datasets: Mapping) -> dict[str, np.ndarray]:
    """The arrays of :func:`write_hdf5`'s ``datasets``, their names and types checked."""
    arrays = {}
    for key, value in datasets.items():
        _check_h5_name(key, "datasets")
        arr = np.asarray(value)
        if arr.dtype.kind not in "biufc":
            raise TypeError(f"datasets[{key!r}] must be a numeric or boolean array, got "
                            f"dtype {arr.dtype}")
        arrays[key] = arr
    for key in arrays:
        parts = key.split("/")
        for i in range(1, len(parts)):
            if "/".join(parts[:i]) in arrays:
                raise ValueError(f"datasets[{key!r}] would sit inside dataset "
                                 f"{'/'.join(parts[:i])!r}")
    return arrays


def _check_hdf5_metadata(arrays: Mapping, attrs: Mapping, groups: Mapping,
                         units: Mapping) -> None:
    """Refuse units naming no dataset, attributes HDF5 cannot hold, and groups that
    clash with a dataset, before any file is created."""
    for key, value in units.items():
        if key not in arrays:
            raise ValueError(f"units[{key!r}] names no dataset; datasets are "
                             f"{sorted(arrays)}")
        if not isinstance(value, str):
            raise TypeError(f"units[{key!r}] must be a string, got {value!r}")
    for key, value in attrs.items():
        _encode_attr(key, value, "attrs")
    for g, gattrs in groups.items():
        _check_h5_name(g, "groups")
        if g in arrays:
            raise ValueError(f"groups[{g!r}] is also a dataset name")
        for key, value in check_mapping(gattrs, f"groups[{g!r}]").items():
            _encode_attr(key, value, f"groups[{g!r}]")


def _create_dataset(h5, key: str, arr: np.ndarray, compression: str | None):
    """Dataset ``key`` of ``arr``: chunked, compressed and checksummed (Fletcher-32)
    when it holds two elements or more and ``compression`` is given."""
    if arr.ndim > 0 and arr.size > 1 and compression is not None:
        opts = {"chunks": True, "compression": compression, "shuffle": True,
                "fletcher32": True}
        if compression == "gzip":
            opts["compression_opts"] = 4
        return h5.create_dataset(key, data=arr, **opts)
    return h5.create_dataset(key, data=arr)


def read_hdf5(path) -> dict:
    """Read a file written by :func:`write_hdf5` (or any simple HDF5 file).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    dict
        ``{"datasets": {name: ndarray}, "attrs": {...}, "groups": {name: {...}},
        "units": {name: str}}``, the arguments of :func:`write_hdf5`: dataset and
        group names are full paths (``"maps/u"``), every group is listed (with
        ``{}`` when it has no attribute), JSON attributes are decoded.
    """
    p = as_path(path, "path")
    if not p.exists():
        raise FileNotFoundError(f"HDF5 file {p} does not exist")
    try:
        h5 = h5py.File(p, "r")
    except OSError as exc:
        raise OSError(f"cannot read {p} as an HDF5 file ({exc})") from exc
    out = {"datasets": {}, "attrs": {}, "groups": {}, "units": {}}
    with h5:
        out["attrs"] = _read_attrs(h5)

        def visit(key, obj):
            if isinstance(obj, h5py.Dataset):
                out["datasets"][key] = np.asarray(obj[()])
                if _UNITS_ATTR in obj.attrs:
                    u = obj.attrs[_UNITS_ATTR]
                    out["units"][key] = u.decode() if isinstance(u, bytes) else str(u)
            elif isinstance(obj, h5py.Group):
                out["groups"][key] = _read_attrs(obj)

        h5.visititems(visit)
    return out


def read_noise_model(path):
    """The camera noise model saved by ``gridstrain noise -o FILE.h5`` (or ``.json``).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    gridstrain.uncertainty.NoiseModel
        ``K``, ``L`` in the stored grey levels of the images it was estimated on,
        with their ``scale`` and ``bit_depth``.

    Raises
    ------
    ValueError
        The file is not a noise result, or holds an unusable model (``K <= 0``).
    """
    from ..uncertainty import NOISE_RESULT_KIND, NoiseModel

    p = as_path(path, "path")
    if not p.is_file():
        raise FileNotFoundError(f"noise file {p} does not exist")
    if p.suffix.lower() == ".json":
        try:
            attrs = json.loads(p.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"noise file {p} is not JSON ({exc})") from None
    else:
        attrs = read_hdf5(p)["attrs"]
    d = attrs.get("noise_model") if isinstance(attrs, dict) else None
    if not isinstance(attrs, dict) or attrs.get("result_kind") != NOISE_RESULT_KIND \
            or not isinstance(d, dict):
        raise ValueError(f"noise file {p} is not a noise result of 'gridstrain noise -o' "
                         "(no noise_model in it)")
    try:
        model = NoiseModel(K=d["K"], L=d["L"], K_ci=d.get("K_ci"), L_ci=d.get("L_ci"),
                           scale=d.get("scale", 1.0), n_frames=d.get("n_frames"),
                           n_pixels=d.get("n_pixels"), reduced_chi2=d.get("reduced_chi2"),
                           method=str(d.get("method", "stack")),
                           filter_gain=d.get("filter_gain"), bit_depth=d.get("bit_depth"))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"noise file {p}: unusable noise model ({exc})") from None
    if not model.K > 0:
        raise ValueError(f"noise file {p}: K must be positive, got {model.K!r}")
    return model
