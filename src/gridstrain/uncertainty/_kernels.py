"""Compiled loop of the contrast step's bound (numba, the ``fast`` extra).

Imported only by :mod:`gridstrain.uncertainty._contrast`, on the first bound, never
when gridstrain is imported (numba's import and its cached machine code cost a
fresh process about 0.4 s of CPU, shared with every other compiled loop).

The bound reads the deformed state's log-modulus gradients at the material points
``x + u``: two calls of ``scipy.ndimage.map_coordinates(order=1, mode="nearest")``
per carrier, each computing every point's weights again, then the differences, their
norm and the running maximum, each a pass over the image. Here one loop does it all,
with the weights once per point and scipy's arithmetic, so that the values are the
same bits (``tests/test_contrast_kernel.py`` compares it with the numpy path that runs
without numba).
"""

from __future__ import annotations

import math

from numba import njit

__all__: list[str] = []

_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False}


@njit(**_OPTIONS)
def _clamped(k, n):  # pragma: no cover
    """A neighbour's index as scipy's mode "nearest" takes it: within ``[0, n - 1]``."""
    return min(max(k, 0), n - 1)


@njit(**_OPTIONS)
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
