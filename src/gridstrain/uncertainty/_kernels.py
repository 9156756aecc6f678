"""Compiled loops of the uncertainty maps (numba, the ``fast`` extra).

Imported only by :func:`gridstrain.uncertainty._maps._load_kernels`, on the first
uncertainty map that uses them, never when gridstrain is imported (numba's own import
takes a few hundred milliseconds).

:func:`gaussian_nearest` is ``scipy.ndimage.gaussian_filter(a, mode="nearest")`` of a
float64 map with scipy's kernel: its sums in scipy's order for a symmetric kernel
(``correlate1d``: the centre tap, then each pair of taps from the outermost in, the
pair added before it is weighted), along the rows' axis first, each product and sum
rounded on its own (no fused multiply-add), so that the values are the same bits
(``tests/test_fast.py`` compares them). The loops run along contiguous rows, which LLVM
vectorises without changing any value's arithmetic.

:func:`phase_variance_sum` and :func:`std_from_variance` are the two halves of
:func:`gridstrain.uncertainty.std_from_phase_variance` around its product by the
lattice's matrix (BLAS's, left to numpy): one pass each over the maps where numpy makes
about ten, with the same operations on each value in the same order, the same bits
(``tests/test_uncertainty.py`` compares both paths). The moduli ``|Psi|`` come from
numpy (its complex modulus is not libm's ``hypot``, which numba's would be).

:func:`steepest_change` is the contrast step's bound
(:func:`gridstrain.uncertainty.contrast_step_bound`) at the material points ``x + u``:
where the numpy path calls ``scipy.ndimage.map_coordinates(order=1, mode="nearest")``
twice per carrier, each computing every point's weights again, then the differences,
their norm and the running maximum, each a pass over the image, one loop does it all
with the weights once per point and scipy's arithmetic, the same bits
(``tests/test_contrast_kernel.py`` compares it with the numpy path).
"""

from __future__ import annotations

import math

import numpy as np

try:
    from numba import njit
except ImportError:  # the module stays importable (its doctests are collected)
    njit = None

__all__: list[str] = []

# whether the loops below are compiled; without numba they stay plain Python
# functions, which gridstrain.uncertainty._maps never calls (it runs scipy instead)
AVAILABLE = njit is not None

# no fast-math licence at all: each product and sum rounded as scipy's C loop rounds it
_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False}
_jit = njit(**_OPTIONS) if AVAILABLE else (lambda func: func)


@_jit
def gaussian_nearest(a, w, tmp, out):  # pragma: no cover
    """``out`` (H, W) float64: ``a`` (H, W) float64 correlated with the symmetric
    kernel of half ``w`` (``w[0]`` the centre tap, ``w[d]`` the two taps at distance
    ``d``) along axis 0 into ``tmp`` (H, W), then along axis 1; the borders continued
    by their nearest value. H and W at least 1."""
    H, W = a.shape
    gaussian_nearest_box(a, w, tmp, out, 0, H, 0, W)


@_jit
def gaussian_nearest_box(a, w, tmp, out, i0, i1, j0, j1):  # pragma: no cover
    """:func:`gaussian_nearest` at the pixels of rows ``i0 <= i < i1`` and columns
    ``j0 <= j < j1`` alone, each the same sums as the whole map's (``out`` and ``tmp``
    left as they are elsewhere): the first pass over those rows and the columns the
    second reads, the second over the box. The box non-empty, within the map. Every
    loop runs over 1-D slices (a loop over a 2-D array's columns from a bound known
    only at run time did not vectorise: twice the time)."""
    H, W = a.shape
    r = w.size - 1
    lo = max(j0 - r, 0)  # the columns of tmp the second pass reads
    hi = min(j1 + r, W)
    m = hi - lo
    for i in range(i0, i1):
        row = tmp[i, lo:hi]
        centre = a[i, lo:hi]
        for j in range(m):
            row[j] = centre[j] * w[0]
        for d in range(r, 0, -1):
            up = a[max(i - d, 0), lo:hi]
            down = a[min(i + d, H - 1), lo:hi]
            wd = w[d]
            for j in range(m):
                row[j] += (up[j] + down[j]) * wd
    # each row continued by r copies of its end values, then correlated along it;
    # the taps read as two shifted slices of that line, so that the loop over the
    # columns vectorises
    line = np.empty(W + 2 * r)
    n = j1 - j0
    for i in range(i0, i1):
        src = tmp[i]
        for j in range(r):
            line[j] = src[lo]  # src[0] where it is read (lo = 0)
            line[r + W + j] = src[hi - 1]  # src[W - 1] where it is read
        for j in range(lo, hi):
            line[r + j] = src[j]
        dst = out[i, j0:j1]
        centre = src[j0:j1]
        for j in range(n):
            dst[j] = centre[j] * w[0]
        for d in range(r, 0, -1):
            wd = w[d]
            left = line[r - d + j0:r - d + j1]
            right = line[r + d + j0:r + d + j1]
            for j in range(n):
                dst[j] += (left[j] + right[j]) * wd


@_jit
def phase_variance_sum(var_ref, variance, mod, half_g2, out):  # pragma: no cover
    """``out`` (2, n): ``var_ref`` (2, n) plus each wave vector's phase variance of the
    deformed maps, ``variance * half_g2 / mod**2`` (``mod`` (2, n) the moduli
    ``|Psi|``, ``variance`` (n,) the sensor's), each operation rounded as numpy
    rounds it in :func:`gridstrain.uncertainty.std_from_phase_variance`."""
    n = variance.size
    for j in range(2):
        r = var_ref[j]
        m = mod[j]
        o = out[j]
        for i in range(n):
            mi = m[i]
            o[i] = r[i] + (variance[i] * half_g2) / (mi * mi)


@_jit
def std_from_variance(var_u, valid, ratio, u_std, strain_std):  # pragma: no cover
    """``u_std`` (2, n) and ``strain_std`` (3, n) from the displacement variances
    ``var_u`` (2, n), NaN off ``valid`` (n,): ``sqrt(var_u)``, ``sqrt(var_u ratio)``
    and ``sqrt((var_u[0] ratio + var_u[1] ratio) / 4)`` (eq. 35)."""
    n = valid.size
    for i in range(n):
        v0 = var_u[0, i]
        v1 = var_u[1, i]
        s0 = v0 * ratio
        s1 = v1 * ratio
        s2 = (s0 + s1) * 0.25
        # every value computed, then chosen: no branch, the loop vectorises. math.sqrt
        # is LLVM's sqrt, which vectorises; numba's np.sqrt of a scalar kept the loop
        # scalar (1.27 -> 0.35 ms at 250 x 400 px, one core). Both are IEEE's square
        # root, correctly rounded: the same bits.
        ok = valid[i]
        r0 = math.sqrt(v0)
        r1 = math.sqrt(v1)
        q0 = math.sqrt(s0)
        q1 = math.sqrt(s1)
        q2 = math.sqrt(s2)
        u_std[0, i] = r0 if ok else np.nan
        u_std[1, i] = r1 if ok else np.nan
        strain_std[0, i] = q0 if ok else np.nan
        strain_std[1, i] = q1 if ok else np.nan
        strain_std[2, i] = q2 if ok else np.nan


@_jit
def _clamped(k, n):  # pragma: no cover
    """A neighbour's index as scipy's mode "nearest" takes it: within ``[0, n - 1]``."""
    return min(max(k, 0), n - 1)


@_jit
def steepest_change(s, rx, ry, dx, dy, u, v, i0, i1):  # pragma: no cover
    """``s = max(s, |(dx, dy)(x + u) - (rx, ry)(x)|)`` on the rows ``i0 <= i < i1``, in
    place: ``(dx, dy)`` read at ``x + u`` (``x`` where not ``v``) by bilinear
    interpolation as ``scipy.ndimage.map_coordinates(order=1, mode="nearest")`` makes
    it (weights ``1 - f`` and ``1 - (1 - f)`` of the coordinate as it is, the four
    neighbours summed row by row from 0 as ``value * w_row * w_col``, each neighbour's
    index clamped to the image); the maximum as ``np.maximum`` takes it (NaN wins).
    ``s``, ``rx``, ``ry``, ``dx``, ``dy`` (H, W) float64; ``u`` (2, H, W); ``v`` (H, W)
    bool."""
    H, W = v.shape
    for i in range(i0, i1):
        for j in range(W):
            if v[i, j]:
                y = i + u[1, i, j]
                x = j + u[0, i, j]
            else:
                y = i + 0.0
                x = j + 0.0
            fy = math.floor(y)
            fx = math.floor(x)
            wy0 = 1.0 - (y - fy)
            wy1 = 1.0 - wy0
            wx0 = 1.0 - (x - fx)
            wx1 = 1.0 - wx0
            r0 = _clamped(int(fy), H)
            c0 = _clamped(int(fx), W)
            r1 = _clamped(int(fy) + 1, H)
            c1 = _clamped(int(fx) + 1, W)
            gx = 0.0
            gx += dx[r0, c0] * wy0 * wx0
            gx += dx[r0, c1] * wy0 * wx1
            gx += dx[r1, c0] * wy1 * wx0
            gx += dx[r1, c1] * wy1 * wx1
            gy = 0.0
            gy += dy[r0, c0] * wy0 * wx0
            gy += dy[r0, c1] * wy0 * wx1
            gy += dy[r1, c0] * wy1 * wx0
            gy += dy[r1, c1] * wy1 * wx1
            h = math.hypot(gx - rx[i, j], gy - ry[i, j])
            old = s[i, j]
            if math.isnan(old) or math.isnan(h):
                s[i, j] = math.nan
            elif h > old:
                s[i, j] = h
