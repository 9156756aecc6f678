"""Compiled loops of the maps' rounding (numba, the ``fast`` extra).

Imported only by :mod:`gridstrain.results._precision`, on the first rounding, never
when gridstrain is imported. Each loop makes one pass over a map where the numpy path
of :func:`~gridstrain.results._precision.round_to_std` and
:func:`~gridstrain.results._precision.round_relative` makes about ten over whole
temporaries (the step, the quotient, its rounding, the product, the choice, the cast,
the error and its maximum), with the same operations on each value in the same order:
the same bits (``tests/test_compact_results.py`` compares both paths and a search of
the powers of two).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__: list[str] = []

_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False}

# the exponent bits of a float64
_EXPONENT = np.uint64(0x7FF0_0000_0000_0000)


@njit(**_OPTIONS)
def _leading_bit(x, cell, bits):  # pragma: no cover
    """``2**floor(log2(|x|))`` of a normal float64 (its exponent bits with a zero
    mantissa), 0 for zeros and subnormals, inf for infinities and NaN; ``cell`` (1,)
    float64 and ``bits`` its uint64 view, to read the bits through."""
    cell[0] = x
    bits[0] &= _EXPONENT
    return cell[0]


@njit(**_OPTIONS)
def round_to_std(v, s, two_f, f32_max, out):  # pragma: no cover
    """``out`` (n,) float32: ``v`` (n,) rounded to the power of two ``q <= two_f s``
    where the std ``s`` (n,) is a positive number and ``v`` finite, ``float32(v)``
    elsewhere; returns ``(largest |out - v| / s over those pixels or -inf, their
    number, whether a finite |v| exceeds f32_max)``."""
    cell = np.empty(1)
    bits = cell.view(np.uint64)
    worst = -math.inf
    used = 0
    over = False
    for i in range(v.size):
        x = v[i]
        si = s[i]
        a = abs(x)
        if a > f32_max and math.isfinite(a):
            over = True
        if math.isfinite(si) and si > 0.0 and math.isfinite(x):
            t = two_f * si
            q = _leading_bit(t, cell, bits)
            if not q > 0.0:  # subnormal: the power of two from the exponent frexp gives
                q = math.ldexp(0.5, math.frexp(t)[1])
            r = np.float32(np.rint(x / q) * q)
            e = abs(np.float64(r) - x) / si
            if e > worst:
                worst = e
            used += 1
            out[i] = r
        else:
            out[i] = np.float32(x)
    return worst, used, over


@njit(**_OPTIONS)
def round_relative(v, scale, out):  # pragma: no cover
    """``out`` (n,) float32: ``v`` (n,) with the mantissa bits below ``scale`` times
    its leading bit dropped (round to nearest even); NaN, infinities, zeros and
    subnormals as float32 casts them."""
    cell = np.empty(1)
    bits = cell.view(np.uint64)
    for i in range(v.size):
        x = v[i]
        q = _leading_bit(x, cell, bits) * scale
        if math.isfinite(q) and q > 0.0:
            out[i] = np.float32(np.rint(x / q) * q)
        else:
            out[i] = np.float32(x)
