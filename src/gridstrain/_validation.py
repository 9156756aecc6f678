"""Argument checks shared by the public functions.

Every error names the parameter, says what was expected and what was received.
"""

from __future__ import annotations

import numbers
import os

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
