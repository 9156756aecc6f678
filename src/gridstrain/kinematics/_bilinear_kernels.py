"""Compiled bilinear reads (numba, the ``fast`` extra) for the comparison of the
images' content at whole-period offsets (:mod:`gridstrain.kinematics._grid_free`).

Imported only on the first comparison, never when gridstrain is imported. The
comparison reads the deformed image's low-passed content at every sample for every
offset searched: ``scipy.ndimage.map_coordinates(order=1, mode="nearest")`` computes
the same numbers through its general n-dimensional loop. Here one loop per point,
with scipy's arithmetic (``tests/test_bilinear_kernels.py`` compares them bit for
bit).
"""

from __future__ import annotations

import math

from numba import njit

__all__: list[str] = []

_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False}


@njit(**_OPTIONS)
def bilinear_at(img, ys, xs, out):  # pragma: no cover
    """``out[k]`` = ``img`` at ``(ys[k], xs[k])`` as
    ``scipy.ndimage.map_coordinates(img, [ys, xs], order=1, mode="nearest")`` gives it:
    weights ``1 - f`` and ``1 - (1 - f)`` of the coordinate as it is, the four
    neighbours summed row by row from 0 as ``value * w_row * w_col``, each neighbour's
    index clamped to the image. ``img`` (H, W) float64; ``ys``, ``xs``, ``out`` (n,)
    float64."""
    H, W = img.shape
    for k in range(ys.size):
        y = ys[k]
        x = xs[k]
        fy = math.floor(y)
        fx = math.floor(x)
        wy0 = 1.0 - (y - fy)
        wy1 = 1.0 - wy0
        wx0 = 1.0 - (x - fx)
        wx1 = 1.0 - wx0
        r0 = min(max(int(fy), 0), H - 1)
        r1 = min(max(int(fy) + 1, 0), H - 1)
        c0 = min(max(int(fx), 0), W - 1)
        c1 = min(max(int(fx) + 1, 0), W - 1)
        t = 0.0
        t += img[r0, c0] * wy0 * wx0
        t += img[r0, c1] * wy0 * wx1
        t += img[r1, c0] * wy1 * wx0
        t += img[r1, c1] * wy1 * wx1
        out[k] = t
