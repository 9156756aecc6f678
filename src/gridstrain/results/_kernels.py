"""Compiled loops of the result file (numba, the ``fast`` extra): the maps' rounding and
the encoding of their chunks.

Imported only by :mod:`gridstrain.results._precision` and
:mod:`gridstrain.results._layout`, on the first rounding or write, never when gridstrain
is imported.

The rounding loops make one pass over a map where the numpy path of
:func:`~gridstrain.results._precision.round_to_std` and
:func:`~gridstrain.results._precision.round_relative` makes about ten over whole
temporaries (the step, the quotient, its rounding, the product, the choice, the cast,
the error and its maximum), with the same operations on each value in the same order:
the same bits (``tests/test_compact_results.py`` compares both paths and a search of
the powers of two).

A compressed map is one chunk that goes through HDF5's filters shuffle, deflate and
Fletcher-32 in that order. :func:`shuffle` and :func:`fletcher32` are HDF5's own
(``H5Zshuffle.c``; ``H5_checksum_fletcher32`` in ``H5checksum.c``, its sum stored after
the data, little-endian), and the deflate between them writes the zlib format HDF5's
filter inflates (ISA-L's when installed, else the same zlib that HDF5 calls, at the
file's level): the chunk written directly decodes through HDF5's filters to the values
its pipeline stores, and with zlib it holds the very bytes the pipeline would have
written (``tests/test_compact_results.py`` compares both), without the pipeline's copies
of each map.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

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


@intrinsic
def _bits(typingctx, x):  # pragma: no cover
    """The uint64 bits of the float64 ``x`` (a register's bitcast, no memory)."""
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.IntType(64))
    return types.uint64(types.float64), codegen


@intrinsic
def _from_bits(typingctx, b):  # pragma: no cover
    """The float64 of the uint64 bits ``b``."""
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.uint64), codegen


_INF = math.inf


@njit(**_OPTIONS)
def round_to_least_std(v, s, stored, scale, two_f, f32_max, out):  # pragma: no cover
    """:func:`round_to_std` of ``v scale`` against the std ``fmin(s, stored) scale``
    (``stored`` (n,), float32 or float64: the std map as the file keeps it), without
    either product or the smaller std in a map of their own; returns :func:`round_to_std`'s
    three figures and the number of pixels whose step ``2 f s`` is subnormal, which this
    loop does not round (:func:`round_to_std` does: the caller's to run it then).

    Branch-free, each value's arithmetic that of :func:`round_to_std` (the exponent bits
    read by a bitcast rather than through memory), so that the loop vectorises: 0.43 ->
    0.25 ms a map of 250 x 400 px, one core. The largest error is taken on the errors'
    bits, which order as the errors do (non-negative)."""
    worst = np.uint64(0)
    used = 0
    counted = 0
    over = False
    slow = 0
    for i in range(v.size):
        x = v[i] * scale
        s0 = s[i]
        s1 = np.float64(stored[i])
        si = (s1 if (s1 < s0 or s0 != s0) else s0) * scale  # np.fmin's choice
        a = abs(x)
        over |= (a > f32_max) & (a < _INF)
        use = (si > 0.0) & (si < _INF) & (a < _INF)
        t = two_f * si
        q = _from_bits(_bits(t) & _EXPONENT)
        slow += use & (q == 0.0) & (t > 0.0)
        step = use & (t > 0.0) & (a < q * 9007199254740992.0)
        rounded = np.float32(np.rint(x / q) * q)
        r = rounded if step else np.float32(x)
        e = abs(np.float64(r) - x) / si
        # a NaN error (a step of inf) is passed over, as round_to_std's comparison does
        counts = use & (e <= _INF)
        worst = max(worst, _bits(e) if counts else np.uint64(0))
        counted += counts
        used += use
        out[i] = r
    return (_from_bits(worst) if counted else -_INF), used, over, slow


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
            if t > 0.0 and a < q * 9007199254740992.0:  # 2**53: else no bit to drop
                r = np.float32(np.rint(x / q) * q)
            else:  # a step of 0 (2 f s underflows) or below x's last bit: x itself
                r = np.float32(x)
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


@njit(**_OPTIONS)
def shuffle(data, itemsize, out):  # pragma: no cover
    """HDF5's shuffle filter: ``out`` (n,) uint8 holds the first byte of every element of
    ``data`` (n,) uint8, then every second byte, and so on; ``itemsize`` bytes an
    element (n a multiple of it)."""
    m = data.size // itemsize
    if itemsize == 4:  # float32 maps: the four planes filled in one pass, 6 times faster
        for i in range(m):
            out[i] = data[4 * i]
            out[m + i] = data[4 * i + 1]
            out[2 * m + i] = data[4 * i + 2]
            out[3 * m + i] = data[4 * i + 3]
        return
    for b in range(itemsize):
        o = b * m
        for i in range(m):
            out[o + i] = data[i * itemsize + b]


@njit(**_OPTIONS)
def fletcher32(data):  # pragma: no cover
    """HDF5's Fletcher-32 checksum of ``data`` (n,) uint8: big-endian 16-bit words,
    the sums folded every 360 words, an odd last byte as a word's high byte."""
    n = data.size // 2
    s1 = 0
    s2 = 0
    i = 0
    while n:
        t = min(n, 360)
        n -= t
        for _ in range(t):
            s1 += (np.int64(data[i]) << 8) | np.int64(data[i + 1])
            i += 2
            s2 += s1
        s1 = (s1 & 0xFFFF) + (s1 >> 16)
        s2 = (s2 & 0xFFFF) + (s2 >> 16)
    if data.size % 2:
        s1 += np.int64(data[i]) << 8
        s2 += s1
        s1 = (s1 & 0xFFFF) + (s1 >> 16)
        s2 = (s2 & 0xFFFF) + (s2 >> 16)
    s1 = (s1 & 0xFFFF) + (s1 >> 16)
    s2 = (s2 & 0xFFFF) + (s2 >> 16)
    return (s2 << 16) | s1
