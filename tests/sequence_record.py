"""A high-speed record of a coupon under increasing homogeneous strain with a rigid
drift, drawn by the numpy-only generator of ``tests/independent_grid.py``.

Frame ``t`` (from 0) shows the Lagrangian displacement

    u_x(X, Y) = a t + e_t (X - x_c),   u_y(X, Y) = b t - nu e_t (Y - y_c),
    e_t = strain * t / (n - 1),

about the image centre ``(x_c, y_c)``, through a Poisson-Gaussian 12-bit camera
stored x16. ``static`` frames come first (``e_t = 0``, no drift, vibrations only).
"""

from __future__ import annotations

import numpy as np

from independent_grid import camera, scene

PITCH = 5.0
ANGLE = 0.0
K, L = 0.5, 5.0


def truth(t: int, n: int, shape, *, strain: float, drift=(0.03, -0.02), nu: float = 0.3,
          static: int = 0):
    """The displacement function ``(X, Y) -> (u_x, u_y)`` of frame ``t``, px."""
    H, W = shape
    k = max(t - static, 0)
    span = max(n - static - 1, 1)
    e = strain * k / span
    a, b = drift[0] * k, drift[1] * k

    def u(X, Y):
        return a + e * (X - (W - 1) / 2), b - nu * e * (Y - (H - 1) / 2)

    return u


def record(n: int, shape=(128, 160), *, strain: float = 2e-3, drift=(0.03, -0.02),
           nu: float = 0.3, static: int = 0, vibration: float = 0.0,
           seed: int = 0) -> np.ndarray:
    """(n, H, W) uint16 frames of the record (see the module docstring)."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, *shape), dtype=np.uint16)
    for t in range(n):
        u = truth(t, n, shape, strain=strain, drift=drift, nu=nu, static=static)
        va, vb = rng.normal(0.0, vibration, 2) if vibration else (0.0, 0.0)

        def moved(X, Y, u=u, va=va, vb=vb):
            ux, uy = u(X, Y)
            return ux + va, uy + vb

        level, _ = scene(shape, pitch=PITCH, angle=ANGLE, hole=False, displacement=moved,
                         seed=seed)
        out[t] = camera(level, K, L, rng)
    return out


def static_series(n: int, shape=(128, 160), *, vibration: float = 0.05, seed: int = 0,
                  displacement=None) -> np.ndarray:
    """(n, H, W) uint16 frames of one static state shaken by rigid vibrations of
    ``vibration`` px std per axis (independent frame to frame)."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, *shape), dtype=np.uint16)
    for t in range(n):
        va, vb = rng.normal(0.0, vibration, 2)

        def moved(X, Y, va=va, vb=vb):
            ux, uy = displacement(X, Y) if displacement is not None else (0.0 * X, 0.0 * Y)
            return ux + va, uy + vb

        level, _ = scene(shape, pitch=PITCH, angle=ANGLE, hole=False, displacement=moved,
                         seed=seed)
        out[t] = camera(level, K, L, rng)
    return out
