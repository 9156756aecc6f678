"""Argument checks shared by the public functions.

Every error names the parameter, says what was expected and what was received.
A wrong kind of value (a string, ``None``, a bool where a number is wanted, an
array of strings) is a ``TypeError``; a value of the right kind that is out of
range (NaN, infinity, a negative count, a shape that does not match) is a
``ValueError``. Python and numpy scalars are accepted alike; ``bool`` never counts
as a number. Each check returns the converted value, so that a call site reads
``sigma = check_positive(sigma, "sigma")``.

Scalars: :func:`check_finite`, :func:`check_nonnegative`, :func:`check_positive`,
:func:`check_range`, :func:`check_fraction`, :func:`check_frequency`,
:func:`check_int`, :func:`check_choice`, :func:`check_sigma`,
:func:`check_workers`. Shapes and objects: :func:`check_shape`,
:func:`check_same_shape`, :func:`check_type`. Arrays: :func:`as_float_array`,
:func:`as_pair`, :func:`as_shifts`, :func:`as_image`, :func:`image_array`,
:func:`check_mask`, with the dtype policy of :func:`float_dtype`.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

__all__ = [
    "SIGMA_PITCH_RTOL",
    "as_float_array",
    "as_image",
    "as_pair",
    "as_shifts",
    "check_choice",
    "check_finite",
    "check_fraction",
    "check_frequency",
    "check_int",
    "check_mask",
    "check_nonnegative",
    "check_positive",
    "check_range",
    "check_same_shape",
    "check_shape",
    "check_sigma",
    "check_type",
    "check_workers",
    "exact_in_float32",
    "float_dtype",
    "freeze_arrays",
    "image_array",
]


def float_dtype(dtype) -> np.dtype:
    """The computation dtype for input of ``dtype`` (float32 stays float32)."""
    return np.dtype(np.float32) if np.dtype(dtype) == np.float32 else np.dtype(np.float64)


def exact_in_float32(dtype) -> bool:
    """Whether every value of ``dtype`` is exact in float32: integers of at most 16
    bits, the frames that are transformed (method B) or summed (the compiled pass) as
    they are stored (:mod:`gridstrain.conventions`, precision)."""
    dt = np.dtype(dtype)
    return dt.kind in "ui" and dt.itemsize <= 2


def as_image(image, name: str = "image", *, allow_uniform: bool = False,
             dtype=None) -> np.ndarray:
    """Return ``image`` as a finite real 2-D float array (float32 or float64).

    ``dtype`` overrides the precision of :func:`float_dtype` (for integer images
    known to be exact in float32). The input is never modified: a new array is
    returned when a conversion is needed, and the caller must not write into the
    result.
    """
    arr = image_array(image, name)
    dt = float_dtype(arr.dtype) if dtype is None else np.dtype(dtype)
    if arr.dtype.kind in "ui":  # finite whatever its values: checked as stored
        if not allow_uniform and arr.min() == arr.max():
            raise ValueError(f"{name} is uniform (every pixel equals "
                             f"{float(arr.flat[0]):g}): no grid")
        return arr.astype(dt)
    arr = arr.astype(dt, copy=False)
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


# ----------------------------------------------------------------- numbers

def _real(value, name: str, expected: str) -> float:
    """``value`` as a float if it is a real number (bool is not), else TypeError."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be {expected}, got {value!r}")
    return float(value)


def check_finite(value, name: str) -> float:
    """Return ``value`` as a finite float.

    Parameters
    ----------
    value : real number
        A Python or numpy real scalar. ``bool`` is refused: ``True`` typed for a
        number is a mistake, not a 1.
    name : str
        The parameter's name, used in the error message.

    Returns
    -------
    float

    Raises
    ------
    TypeError
        If ``value`` is not a real number (a string, ``None``, a bool, an array).
    ValueError
        If ``value`` is NaN or infinite.

    Examples
    --------
    >>> check_finite(np.float32(2.5), "offset")
    2.5
    """
    v = _real(value, name, "a finite number")
    if not math.isfinite(v):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return v


def check_nonnegative(value, name: str) -> float:
    """Return ``value`` as a finite float ``>= 0``.

    Parameters
    ----------
    value : real number
        A Python or numpy real scalar (not a bool).
    name : str
        The parameter's name, used in the error message.

    Returns
    -------
    float

    Raises
    ------
    TypeError
        If ``value`` is not a real number.
    ValueError
        If ``value`` is negative, NaN or infinite.
    """
    v = _real(value, name, "a finite non-negative number")
    if not math.isfinite(v) or v < 0:
        raise ValueError(f"{name} must be a finite non-negative number, got {value!r}")
    return v


def check_range(value, name: str, low: float, high: float, *, include_low: bool = True,
                include_high: bool = True, what: str = "a number", unit: str = "") -> float:
    """Return ``value`` as a finite float in the interval from ``low`` to ``high``.

    Parameters
    ----------
    value : real number
        A Python or numpy real scalar (not a bool).
    name : str
        The parameter's name, used in the error message.
    low, high : float
        Ends of the interval.
    include_low, include_high : bool
        Whether each end belongs to the interval (``[`` or ``(``).
    what : str
        What the value is, for the message (``"a carrier frequency"``).
    unit : str
        Unit (and any hint) written after the interval, for the message.

    Returns
    -------
    float

    Raises
    ------
    TypeError
        If ``value`` is not a real number.
    ValueError
        If ``value`` is NaN or outside the interval.

    Examples
    --------
    >>> check_range(0.3, "poisson_ratio", -1, 0.5, include_low=False)
    0.3
    """
    interval = (f"{'[' if include_low else '('}{low:g}, {high:g}{']' if include_high else ')'}"
                + (f" {unit}" if unit else ""))
    v = _real(value, name, f"{what} in {interval}")
    above = v >= low if include_low else v > low
    below = v <= high if include_high else v < high
    if not (above and below):  # NaN fails both
        raise ValueError(f"{name} must be {what} in {interval}, got {value!r}")
    return v


def check_fraction(value, name: str) -> float:
    """Return ``value`` as a float in ``[0, 1]`` (a contrast, a proportion).

    Parameters
    ----------
    value : real number
        A Python or numpy real scalar (not a bool).
    name : str
        The parameter's name, used in the error message.

    Returns
    -------
    float

    Raises
    ------
    TypeError
        If ``value`` is not a real number.
    ValueError
        If ``value`` is NaN or outside ``[0, 1]``.
    """
    return check_range(value, name, 0.0, 1.0)


def check_frequency(value, name: str = "frequency") -> float:
    """Return ``value`` as a carrier frequency in ``(0, 0.5)`` cycles/px.

    A frequency of 0.5 or above is beyond the Nyquist limit: the grid's pitch
    must exceed 2 px to be sampled at all.

    Parameters
    ----------
    value : real number
        A Python or numpy real scalar (not a bool), cycles/px.
    name : str
        The parameter's name, used in the error message.

    Returns
    -------
    float

    Raises
    ------
    TypeError
        If ``value`` is not a real number.
    ValueError
        If ``value`` is NaN or outside ``(0, 0.5)``.
    """
    return check_range(value, name, 0.0, 0.5, include_low=False, include_high=False,
                       what="a carrier frequency", unit="cycles/px (a pitch above 2 px)")


def check_int(value, name: str, *, minimum: int | None = 1) -> int:
    """Return ``value`` as an int of at least ``minimum``.

    Parameters
    ----------
    value : integer
        A Python or numpy integer. ``bool`` is refused, and so is a float even
        when it holds a whole number: a count typed as ``2.5`` or ``True`` is a
        mistake to report, not to round.
    name : str
        The parameter's name, used in the error message.
    minimum : int or None
        Smallest value allowed (None: any integer, e.g. an index).

    Returns
    -------
    int

    Raises
    ------
    TypeError
        If ``value`` is not a real number at all (a string, ``None``, a bool).
    ValueError
        If ``value`` is a real number that is not an integer, or is below
        ``minimum``.

    Examples
    --------
    >>> check_int(np.int64(16), "n_bins", minimum=3)
    16
    """
    expected = ("an integer" if minimum is None else "a positive integer" if minimum == 1
                else f"an integer of at least {minimum}")
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be {expected}, got {value!r}")
    if not isinstance(value, numbers.Integral) or (minimum is not None and value < minimum):
        raise ValueError(f"{name} must be {expected}, got {value!r}")
    return int(value)


def check_shape(value, name: str = "shape", *, minimum: int = 1) -> tuple[int, int]:
    """Return ``value`` as an image shape ``(H, W)`` of two ints of at least ``minimum``.

    Parameters
    ----------
    value : sequence of two integers
        Rows and columns, px (Python or numpy integers).
    name : str
        The parameter's name, used in the error message.
    minimum : int
        Smallest number of rows and columns, px.

    Returns
    -------
    (int, int)

    Raises
    ------
    ValueError
        If ``value`` is not two positive integers.
    """
    try:
        H, W = value
        H, W = check_int(H, name), check_int(W, name)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be two positive integers, got {value!r}") from None
    if min(H, W) < minimum:
        raise ValueError(f"{name} must be at least {minimum} x {minimum} px (H, W), got "
                         f"{value!r}")
    return H, W


# ----------------------------------------------------------------- objects and arrays

def check_same_shape(shape, expected, name: str, of: str) -> None:
    """Raise unless the shape ``shape`` of ``name`` equals ``expected``, that of ``of``.

    Parameters
    ----------
    shape, expected : tuple of int
        The shape received and the shape it must have.
    name : str
        The parameter's name, used in the error message.
    of : str
        What ``expected`` is the shape of, for the message (``"reference"``,
        ``"the frames"``).

    Raises
    ------
    ValueError
        ``"deformed must have the shape of reference (512, 512), got (512, 511)"``.
    """
    if tuple(shape) != tuple(expected):
        raise ValueError(f"{name} must have the shape of {of} {tuple(expected)}, "
                         f"got {tuple(shape)}")


def check_type(value, name: str, cls: type, *, allow_none: bool = False):
    """Return ``value`` if it is an instance of ``cls`` (or ``None`` if allowed).

    Parameters
    ----------
    value : object
    name : str
        The parameter's name, used in the error message.
    cls : type
        The expected class (``Lattice``, ``PhaseMaps``).
    allow_none : bool
        Whether ``None`` is accepted (and returned).

    Returns
    -------
    object
        ``value`` itself.

    Raises
    ------
    TypeError
        ``"lattice must be a Lattice or None, got tuple"``.
    """
    if value is None and allow_none:
        return None
    if not isinstance(value, cls):
        article = "an" if cls.__name__[:1].lower() in "aeiou" else "a"
        expected = f"{article} {cls.__name__}" + (" or None" if allow_none else "")
        raise TypeError(f"{name} must be {expected}, got {type(value).__name__}")
    return value


def as_float_array(value, name: str, *, dtype=None) -> np.ndarray:
    """Return ``value`` as a real floating-point array of any shape.

    Parameters
    ----------
    value : array_like
        Real numbers (integers or floats, Python or numpy, any shape). Booleans,
        strings, complex numbers and ragged sequences are refused. Not modified:
        a new array is returned when a conversion is needed, and the caller must
        not write into the result.
    name : str
        The parameter's name, used in the error message.
    dtype : dtype, optional
        Dtype of the result. Default: :func:`float_dtype` of the input (float32
        stays float32, anything else becomes float64).

    Returns
    -------
    ndarray
        Not checked for finiteness.

    Raises
    ------
    TypeError
        If ``value`` does not hold real numbers.
    ValueError
        If ``value`` is a ragged sequence.
    """
    try:
        arr = np.asarray(value)
    except ValueError:
        raise ValueError(f"{name} must be a regular array of real numbers, got a ragged "
                         f"{type(value).__name__}") from None
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer)
                                 or np.issubdtype(arr.dtype, np.floating)):
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    return arr.astype(float_dtype(arr.dtype) if dtype is None else dtype, copy=False)


def as_pair(value, name: str, *, labels: str = "(x, y)", unit: str = "") -> np.ndarray:
    """Return ``value`` as a finite (2,) float64 array.

    Parameters
    ----------
    value : sequence of two real numbers
        A tuple, list or (2,) array (Python or numpy numbers).
    name : str
        The parameter's name, used in the error message.
    labels : str
        The components' names, for the message (``"(u_x, u_y)"``).
    unit : str
        Unit of the components, for the message (``"px"``).

    Returns
    -------
    (2,) float64 ndarray
        A new array.

    Raises
    ------
    TypeError
        If ``value`` does not hold real numbers.
    ValueError
        If ``value`` does not hold exactly two numbers, or they are not finite.

    Examples
    --------
    >>> as_pair((1, np.float32(2.5)), "centre")
    array([1. , 2.5])
    """
    expected = f"a finite {labels} pair" + (f" in {unit}" if unit else "")
    try:
        arr = as_float_array(value, name, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be {expected}, got {value!r}") from None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be {expected}, got {value!r}")
    return np.array(arr)


def as_shifts(value, name: str = "shifts", *, ndim: int = 2) -> np.ndarray:
    """Return per-frame rigid shifts as a finite float64 array of ``T >= 1`` rows.

    Parameters
    ----------
    value : (T, 2) or (T,) array_like
        Shifts ``(alpha_t, beta_t)`` of each frame (``ndim=2``), or shifts along
        one axis (``ndim=1``), px.
    name : str
        The parameter's name, used in the error message.
    ndim : {1, 2}
        Expected number of dimensions.

    Returns
    -------
    (T, 2) or (T,) float64 ndarray

    Raises
    ------
    TypeError
        If ``value`` does not hold real numbers.
    ValueError
        If its shape is wrong, it has no row, or it holds NaN or infinity.
    """
    arr = as_float_array(value, name, dtype=np.float64)
    want = "(T,)" if ndim == 1 else "(T, 2)"
    if (arr.ndim != ndim or arr.shape[0] < 1 or (ndim == 2 and arr.shape[1] != 2)
            or not np.all(np.isfinite(arr))):
        bad = "" if arr.ndim != ndim or arr.size == 0 or np.all(np.isfinite(arr)) else \
            " with NaN or infinite values"
        raise ValueError(f"{name} must be a finite {want} array of px with T >= 1, got "
                         f"shape {arr.shape}{bad}")
    return arr


# ----------------------------------------------------------------- collections, paths, objects


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


def check_pixel_size(pixel_size, unit):
    """``(pixel_size, unit)`` checked: both None, or a positive size and a short unit name."""
    if pixel_size is None:
        if unit is not None:
            raise ValueError(f"unit needs a pixel_size, got unit={unit!r} without one")
        return None, None
    ps = check_positive(pixel_size, "pixel_size")
    if not isinstance(unit, str) or not unit.strip() or len(unit) > 32 \
            or not unit.isprintable():
        raise ValueError(f"unit must be a short name such as 'mm' when pixel_size is "
                         f"given, got {unit!r}")
    return ps, unit.strip()


def freeze_arrays(obj) -> None:
    """Make the array fields of a frozen dataclass read-only (a result is data)."""
    for name in obj.__dataclass_fields__:
        value = getattr(obj, name)
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
