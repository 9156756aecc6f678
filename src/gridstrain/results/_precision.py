"""The precision a result file keeps of its maps: each measured map rounded to a tenth of
its own predicted standard deviation, each std map to a relative precision, both stored
in float32 with the dropped mantissa bits zero so that the compressor gains.

A map ``v`` with a std map ``s`` is rounded, pixel by pixel, to the nearest multiple of
the power of two ``q = 2**floor(log2(2 f s))`` (``f`` = :data:`STD_FRACTION`): the
error is at most ``q / 2 <= f s``. Since ``q`` is a power of two, the rounded value is
``v`` with its mantissa bits below ``q`` set to zero (bit rounding, as netCDF-4's
BitRound and Granular BitRound do, with the number of bits kept chosen per value from
its own std rather than per variable), computed exactly in float64 and exactly
representable in float32 while ``|v| / q < 2**24``. Where the std is not a positive
number (a pixel with no prediction), the value keeps float32's own precision (relative
``2**-24``). The largest error over the std actually made is measured on every state
and recorded in the file (:data:`MAX_ERROR_ATTR`), so that a value float32 could not
hold to the bound (``|v|`` above ``2**23 q``) is never hidden.

A std map keeps :data:`STD_BITS` mantissa bits: relative error at most ``2**-(STD_BITS
+ 1)``. A std map is a prediction whose own uncertainty is far larger (the sensor
model's K and L are fitted to a few percent).

References
----------
Klöwer, M., Razinger, M., Dominguez, J. J., Düben, P. D. and Palmer, T. N. (2021).
Compressing atmospheric data into its real information content. *Nature
Computational Science* 1, 713-724. https://doi.org/10.1038/s43588-021-00156-2
"""

from __future__ import annotations

import functools

import numpy as np

from .._runtime import compiled

#: The largest rounding error of a measured map, over its std at the same pixel.
STD_FRACTION = 0.1
#: Mantissa bits a std map keeps (of float32's 23): relative error <= 2**-6 = 1.6 %.
STD_BITS = 5
#: The attribute recording, per state, the largest |stored - measured| / std.
MAX_ERROR_ATTR = "rounding_max_error_over_std"
#: The std map each measured map is rounded from. The rotation
#: ``omega = (duy/dx - dux/dy) / 2`` has the std of ``exy = (dux/dy + duy/dx) / 2``
#: under the noise model of :func:`gridstrain.uncertainty.uncertainty_maps`, in which
#: the two derivatives are independent (``Std = sqrt(Var G01 + Var G10) / 2`` for both).
STD_OF = {"ux": "ux_std", "uy": "uy_std", "exx": "exx_std", "eyy": "eyy_std",
          "exy": "exy_std", "rotation": "exy_std", "ux_phys": "ux_std",
          "uy_phys": "uy_std"}

_F32_MAX = float(np.finfo(np.float32).max)

# The roundings run in the compiled loops of gridstrain.results._kernels (numba,
# the "fast" extra) when installed, loaded on the first rounding: one pass over a map
# instead of about ten, the same bits. False forces the numpy path (what runs without
# numba).
_COMPILED = True

_TOO_LARGE = (f"values must fit float32 (|v| <= {_F32_MAX:.3g}) to be stored rounded; "
              "store the result losslessly")


@functools.cache
def _load_kernels():
    """The module of compiled rounding loops (:func:`gridstrain._runtime.compiled.load`),
    or None."""
    return compiled.load(__package__, "._kernels")


def _kernels():
    return _load_kernels() if _COMPILED else None


def round_to_std(values, std, *, fraction: float = STD_FRACTION) -> tuple[np.ndarray, float]:
    """``values`` rounded to ``fraction`` of ``std`` at each pixel, in float32.

    Parameters
    ----------
    values, std : (H, W) array_like
        A map and its predicted standard deviation, in the same unit. NaN values
        stay NaN.
    fraction : float
        The largest error, over the std.

    Returns
    -------
    rounded : (H, W) float32 ndarray
    max_error : float
        The largest ``|rounded - values| / std`` over the pixels where both are
        finite and the std positive (NaN where there is none); at most ``fraction``
        unless float32 cannot hold a value to it.
    """
    v = np.asarray(values, dtype=np.float64)
    s = np.asarray(std, dtype=np.float64)
    kern = _kernels()
    if kern is not None and v.shape == s.shape:
        return _compiled_round(kern, v, s, s, 1.0, fraction)
    a = np.abs(v)
    over = a > _F32_MAX
    if over.any() and np.isfinite(a[over]).any():
        raise ValueError(_TOO_LARGE)
    use = np.isfinite(s) & (s > 0) & np.isfinite(v)
    if not use.any():
        return v.astype(np.float32), float("nan")
    # q = 2**floor(log2(2 f s)): the exponent bits of 2 f s alone, on the whole map
    # (a boolean gather of each operand cost twice the arithmetic); exact where
    # np.log2 could round up just below a power of two
    q = _leading_bit(2.0 * fraction * s)
    tiny = use & ~(q > 0)  # 2 f s subnormal: no exponent bits to take
    if tiny.any():
        q[tiny] = np.ldexp(0.5, np.frexp(2.0 * fraction * s[tiny])[1])
    # a step of 0 (2 f s underflows) or below the value's last bit keeps the value
    step = use & (2.0 * fraction * s > 0) & (a < q * 2.0**53)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # q a power of two: v / q, its rounding and the product are exact in float64
        out = np.round(v / q)
        out *= q
        rounded = np.where(step, out, v).astype(np.float32)
        err = np.abs(rounded - v)
        err /= s
    return rounded, float(err.max(where=use, initial=-np.inf))


def round_to_least_std(values, std, stored, *, scale: float = 1.0,
                       fraction: float = STD_FRACTION) -> tuple[np.ndarray, float]:
    """:func:`round_to_std` of ``values * scale`` against the std ``np.fmin(std,
    stored) * scale``: a map in a physical unit (``scale`` the pixel size) rounded to
    the smaller of its measured std ``std`` and the std as the file keeps it
    (``stored``, :func:`round_relative`'s), so that the bound holds against both. The
    same bits as those products and :func:`round_to_std`; by one compiled pass, without
    the products or the smaller std in a map of their own, where numba is installed."""
    v = np.asarray(values, dtype=np.float64)
    s = np.asarray(std, dtype=np.float64)
    kern = _kernels()
    if kern is not None and v.shape == s.shape == np.shape(stored):
        return _compiled_round(kern, v, s, np.asarray(stored), float(scale), fraction)
    s = np.fmin(s, stored)
    if scale != 1.0:
        v, s = v * scale, s * scale
    return round_to_std(v, s, fraction=fraction)


def _compiled_round(kern, v, s, stored, scale: float, fraction: float):
    """:func:`round_to_least_std` by the compiled loops (``v``, ``s`` float64 of one
    shape, ``stored`` of theirs)."""
    out = np.empty(v.shape, dtype=np.float32)
    flat = out.reshape(-1)
    worst, used, over, slow = kern.round_to_least_std(
        np.ravel(v), np.ravel(s), np.ravel(stored), scale, 2.0 * fraction, _F32_MAX, flat)
    if slow:  # a step 2 f s subnormal somewhere: the scalar loop, which rounds to it
        least = np.fmin(s, stored) * scale
        worst, used, over = kern.round_to_std(np.ravel(v * scale), np.ravel(least),
                                              2.0 * fraction, _F32_MAX, flat)
    if over:
        raise ValueError(_TOO_LARGE)
    return out, (float(worst) if used else float("nan"))


def _leading_bit(x: np.ndarray) -> np.ndarray:
    """``2**floor(log2(|x|))`` of each normal float64 of ``x`` (its exponent bits with a
    zero mantissa): 0 for zeros and subnormals, inf for infinities and NaN."""
    return (x.view(np.uint64) & np.uint64(0x7FF0_0000_0000_0000)).view(np.float64)


def round_relative(values, *, bits: int = STD_BITS) -> np.ndarray:
    """``values`` with ``bits`` mantissa bits kept (round to nearest), in float32:
    relative error at most ``2**-(bits + 1)``; NaN, infinities and zeros unchanged.

    Parameters
    ----------
    values : (H, W) array_like
    bits : int
        Explicit mantissa bits kept, 0 to 23.

    Returns
    -------
    (H, W) float32 ndarray
    """
    v = np.asarray(values, dtype=np.float64)
    kern = _kernels()
    if kern is not None:
        out = np.empty(v.shape, dtype=np.float32)
        kern.round_relative(np.ravel(v), 2.0 ** -bits, out.reshape(-1))
        return out
    # |v| = m 2**e with m in [1, 2): the kept bits' last is 2**(e - bits), a power of
    # two, so v / q, its rounding and the product are exact in float64
    q = _leading_bit(v) * 2.0 ** -bits
    use = np.isfinite(q) & (q > 0)  # NaN, infinities, zeros (and subnormals) as given
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.round(v / q)
        out *= q
    return np.where(use, out, v).astype(np.float32)
