"""Argument checks shared by the public functions.

Every error names the parameter, says what was expected and what was received.
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

__all__ = [
    "SIGMA_PITCH_RTOL",
    "as_image",
    "check_choice",
    "check_mask",
    "check_positive",
    "check_sigma",
    "float_dtype",
    "image_array",
]


def float_dtype(dtype) -> np.dtype:
    """The computation dtype for input of ``dtype`` (float32 stays float32)."""
    return np.dtype(np.float32) if np.dtype(dtype) == np.float32 else np.dtype(np.float64)


def as_image(image, name: str = "image", *, allow_uniform: bool = False) -> np.ndarray:
    """Return ``image`` as a finite real 2-D float array (float32 or float64).

    The input is never modified: a new array is returned when a conversion is
    needed, and the caller must not write into the result.
    """
    arr = image_array(image, name)
    arr = arr.astype(float_dtype(arr.dtype), copy=False)
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise ValueError(f"{name} must be finite, got {bad} NaN or infinite pixel(s)")
    if not allow_uniform and np.ptp(arr) == 0:
        raise ValueError(f"{name} is uniform (every pixel equals {float(arr.flat[0]):g}): no grid")
    return arr


def image_array(image, name: str = "image") -> np.ndarray:
    """``image`` as a real 2-D numeric array of at least 8 x 8, unconverted and
    unchecked for finiteness (:func:`as_image` does both); for callers that convert
    while copying into their own buffer."""
    if isinstance(image, np.ndarray | list | tuple) or hasattr(image, "__array__"):
        arr = np.asarray(image)
    else:
        raise TypeError(f"{name} must be a 2-D array, got {type(image).__name__}")
    if arr.dtype == bool or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.ndim != 2:
        raise ValueError(f"{name} must be 2-D (H, W), got shape {arr.shape}")
    if arr.size == 0 or min(arr.shape) < 8:
        raise ValueError(f"{name} must be at least 8 x 8 pixels, got shape {arr.shape}")
    return arr


def check_mask(mask, shape: tuple[int, int], name: str = "mask") -> np.ndarray:
    """Return ``mask`` as a boolean array of ``shape`` (``None`` gives all True)."""
    if mask is None:
        return np.ones(shape, dtype=bool)
    m = np.asarray(mask)
    if m.ndim != 2 or m.shape != tuple(shape):
        raise ValueError(f"{name} must be a 2-D boolean array of shape {tuple(shape)}, "
                         f"got shape {m.shape}")
    if m.dtype != bool:
        if not (np.issubdtype(m.dtype, np.integer) or np.issubdtype(m.dtype, np.floating)):
            raise TypeError(f"{name} must be boolean, got dtype {m.dtype}")
        if not np.all(np.isin(m, (0, 1))):
            raise ValueError(f"{name} must hold only 0/1 or True/False values")
        m = m.astype(bool)
    if not m.any():
        raise ValueError(f"{name} selects no pixel")
    return m


def check_positive(value, name: str, *, allow_none: bool = False) -> float | None:
    """Return ``value`` as a finite positive float."""
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a positive number, got {value!r}")
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return v


#: Relative tolerance under which a window standard deviation below the pitch is
#: taken as the pitch itself: a sigma typed as "6" for a pitch detected at
#: 6.000003 px is the user's "one pitch", not a request for a narrower window.
SIGMA_PITCH_RTOL = 1e-3


def check_sigma(sigma, pitch: float, name: str = "sigma") -> float:
    """Return the window standard deviation ``sigma`` checked against ``pitch``.

    ``None`` gives the pitch. A value within a relative :data:`SIGMA_PITCH_RTOL`
    below the pitch is snapped to the pitch; anything smaller is refused, since
    the window must hold one period (paper §2.2).
    """
    pitch = float(pitch)
    if sigma is None:
        return pitch
    s = check_positive(sigma, name)
    if s < pitch * (1 - SIGMA_PITCH_RTOL):
        raise ValueError(f"{name} must be at least the pitch ({pitch:.6g} px) so that the "
                         f"window holds one period, got {s:.6g}")
    return max(s, pitch)


def check_choice(value, name: str, choices) -> str:
    """Return ``value`` if it is one of ``choices``."""
    if value not in choices:
        allowed = ", ".join(repr(c) for c in choices)
        raise ValueError(f"{name} must be one of {allowed}, got {value!r}")
    return value


def check_workers(workers) -> int:
    """Return ``workers`` (a positive integer), or the usable cores for None."""
    if workers is None:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
            os.cpu_count() or 1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer or None, got {workers!r}")
    return workers


# ------------------------------------------------------------------ scalars, pairs, lists


def check_finite(value, name: str) -> float:
    """Return ``value`` as a finite real float (any sign)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a finite number, got {value!r}")
    v = float(value)
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


def check_int(value, name: str, *, minimum: int | None = None) -> int:
    """Return ``value`` as an ``int`` (Python or NumPy integer, not bool), at least
    ``minimum`` when given."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if minimum is not None and value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_fraction(value, name: str) -> float:
    """Return ``value`` as a float in [0, 1]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a number in [0, 1], got {value!r}")
    v = float(value)
    if not 0.0 <= v <= 1.0:
        raise ValueError(f"{name} must be in [0, 1], got {value!r}")
    return v


def as_pair(value, name: str) -> tuple[float, float]:
    """Return ``value`` (two real numbers: a tuple, list or array) as a pair of finite
    floats."""
    try:
        items = (list(value) if isinstance(value, tuple | list)
                 else list(np.asarray(value).ravel()) if np.ndim(value) == 1 else None)
    except (TypeError, ValueError):
        items = None
    if (items is None or len(items) != 2
            or any(isinstance(v, bool | np.bool_) or not isinstance(v, numbers.Real)
                   for v in items)):
        raise TypeError(f"{name} must be a pair of numbers, got {value!r}")
    a, b = (float(v) for v in items)
    if not (np.isfinite(a) and np.isfinite(b)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return a, b


def check_shape(shape, name: str = "shape", *, minimum: int = 1) -> tuple[int, int]:
    """Return ``shape`` (a tuple, list or 1-D array) as ``(H, W)``, two integers of at
    least ``minimum`` px."""
    if isinstance(shape, np.ndarray) and shape.ndim == 1:
        shape = tuple(shape.tolist())
    if (not isinstance(shape, tuple | list) or len(shape) != 2
            or any(isinstance(s, bool) or not isinstance(s, numbers.Integral) for s in shape)):
        raise TypeError(f"{name} must be a pair of integers (H, W), got {shape!r}")
    rows, cols = int(shape[0]), int(shape[1])
    if min(rows, cols) < minimum:
        raise ValueError(f"{name} must be at least {minimum} x {minimum} px (H, W), got "
                         f"{shape!r}")
    return rows, cols


def as_int_tuple(values, name: str, *, minimum: int | None = None) -> tuple[int, ...]:
    """Return ``values`` (an iterable of integers, at least one) as a tuple of ints, in
    the order given, each at least ``minimum``."""
    try:
        if isinstance(values, str | bytes):  # iterable, but of characters
            raise TypeError
        items = list(values)
    except TypeError:
        raise TypeError(f"{name} must be a list of integers, got {values!r}") from None
    if not items:
        raise ValueError(f"{name} must hold at least one integer, got {values!r}")
    return tuple(check_int(v, f"{name} values", minimum=minimum) for v in items)


# ------------------------------------------------------------------ objects


def check_name(value, name: str = "name") -> str:
    """Return ``value`` if it is a non-empty string."""
    if not isinstance(value, str) or not value:
        raise TypeError(f"{name} must be a non-empty string, got {value!r}")
    return value


def as_path(value, name: str = "path") -> Path:
    """Return ``value`` (``str`` or ``os.PathLike``) as a Path, ``~`` expanded."""
    if isinstance(value, str | os.PathLike):
        return Path(os.path.expanduser(os.fspath(value)))
    raise TypeError(f"{name} must be a path (str or os.PathLike), got "
                    f"{type(value).__name__}")


def check_mapping(value, name: str, *, allow_none: bool = False) -> Mapping:
    """Return ``value`` if it is a mapping (``None`` gives ``{}`` with ``allow_none``)."""
    if value is None and allow_none:
        return {}
    if not isinstance(value, Mapping):
        raise TypeError(f"{name} must be a dict, got {type(value).__name__}")
    return value


def check_instance(value, cls: type, name: str):
    """Return ``value`` if it is an instance of ``cls``."""
    if not isinstance(value, cls):
        raise TypeError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")
    return value


def check_callable(value, name: str = "progress"):
    """Return ``value`` if it is callable or ``None``."""
    if value is not None and not callable(value):
        raise TypeError(f"{name} must be callable or None, got {value!r}")
    return value


def check_float_dtype(dtype, name: str = "dtype", *, allow_none: bool = True
                      ) -> np.dtype | None:
    """Return ``dtype`` as ``numpy.float32`` or ``numpy.float64`` (or ``None``, which
    means "the stored type", with ``allow_none``)."""
    if dtype is None and allow_none:
        return None
    allowed = "float32, float64 or None" if allow_none else "float32 or float64"
    if dtype is None:  # np.dtype(None) would silently mean float64
        raise ValueError(f"{name} must be {allowed}, got None")
    try:
        dt = np.dtype(dtype)
    except TypeError:
        dt = None
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"{name} must be {allowed}, got {dtype!r}")
    return dt
