"""Photographs of a printed grid under the light of a real lab: a hot spot of the lamp
and a specular highlight that move on their own, for the fringe-order evidence tests.

Written with numpy alone; it shares no code with ``gridstrain.models.synthetic`` or the other
generators of the tests. Its model of a picture:

- the specimen (reference configuration ``X`` the column, ``Y`` the row, px, pixel
  centres at integers) carries a grid of dark lines of pitch ``pitch`` turned by
  ``angle`` degrees: each family of lines is ``0.5 + 0.5 tanh(3 (cos 2 pi a - cos 0.35
  pi))`` (lines 0.35 period wide with soft edges), the ink covering ``0.8`` of the
  light where the two families cross or lie; optional print defects (``spots``): dark
  Gaussian spots of 1 to 2.5 px std, one per 400 px^2, darkening by 40 %, attached to
  the specimen;
- the deformation: the material point ``X`` is seen at ``x = X + u(X)`` (``u``
  Lagrangian, as gridstrain defines it), ``X`` found by 30 fixed-point iterations of
  ``X <- x - u(X)``;
- the lighting is fixed to the camera (it does not move with the specimen): a slope of
  10 % across the frame and, optionally, a lamp's hot spot, a Gaussian of std
  ``hot_sd`` px raising the light by ``hot`` at the camera point ``hot_at`` (it
  multiplies the specimen's reflectance);
- a specular highlight, optionally: light reflected by the surface rather than
  diffused by the print, added to the image whatever the ink (a Gaussian of std
  ``glare_sd`` px and height ``glare`` of the diffuse white level, centred at the
  camera point ``glare_at``);
- each pixel integrates its area (3 x 3 sub-samples);
- the sensor: white paper under the unit light gives ``full`` grey levels; a Poisson
  count of electrons at 0.5 grey level each plus a normal read noise of ``read``
  grey levels std, rounded and clipped to 12 bits (``noise=None``: the expected
  levels, noise-free).
"""

from __future__ import annotations

import numpy as np

SUB = 3


def _lines(a):
    return 0.5 + 0.5 * np.tanh(3.0 * (np.cos(2 * np.pi * a) - np.cos(0.35 * np.pi)))


def spots(shape, seed=0, *, density=1 / 400):
    """``(centres (n, 2) as (x, y), stds (n,))`` of print defects over a frame."""
    rng = np.random.default_rng(seed)
    H, W = shape
    n = int(H * W * density)
    return (rng.uniform([-10, -10], [W + 10, H + 10], (n, 2)), rng.uniform(1.0, 2.5, n))


def photograph(shape, pitch, displacement=None, *, angle=0.5, defects=None, hot=0.0,
               hot_at=(0.0, 0.0), hot_sd=25.0, glare=0.0, glare_at=(0.0, 0.0),
               glare_sd=6.0, full=2500.0, read=2.0, noise=None):
    """One photograph, ``(H, W)`` float grey levels (integers once noisy).

    ``displacement(X, Y) -> (u_x, u_y)`` px; ``defects`` from :func:`spots`;
    ``noise``: a ``numpy.random.Generator`` or None.
    """
    H, W = shape
    off = (np.arange(SUB) + 0.5) / SUB - 0.5
    y = (np.arange(H)[:, None] + off[None, :]).reshape(-1)
    x = (np.arange(W)[:, None] + off[None, :]).reshape(-1)
    x, y = np.meshgrid(x, y)
    X, Y = x.copy(), y.copy()
    if displacement is not None:
        for _ in range(30):
            ux, uy = displacement(X, Y)
            X, Y = x - ux, y - uy
    th = np.deg2rad(angle)
    a = (np.cos(th) * X + np.sin(th) * Y) / pitch
    b = (-np.sin(th) * X + np.cos(th) * Y) / pitch
    ink = 1 - (1 - _lines(a)) * (1 - _lines(b))
    refl = 1 - 0.8 * ink
    if defects is not None:
        dark = np.zeros_like(X)
        for (cx, cy), s in zip(*defects, strict=True):
            near = (np.abs(X - cx) < 4 * s) & (np.abs(Y - cy) < 4 * s)
            dark[near] += np.exp(-((X[near] - cx) ** 2 + (Y[near] - cy) ** 2) / (2 * s * s))
        refl = refl * (1 - 0.4 * np.minimum(dark, 1.0))
    light = 1 + 0.1 * (x - W / 2) / W
    if hot:
        light = light + hot * np.exp(-((x - hot_at[0]) ** 2 + (y - hot_at[1]) ** 2)
                                     / (2 * hot_sd**2))
    img = refl * light
    if glare:
        img = img + glare * np.exp(-((x - glare_at[0]) ** 2 + (y - glare_at[1]) ** 2)
                                   / (2 * glare_sd**2))
    level = full * img.reshape(H, SUB, W, SUB).mean(axis=(1, 3))
    if noise is None:
        return level
    e = noise.poisson(level / 0.5)
    return np.clip(np.rint(0.5 * e + noise.normal(0.0, read, level.shape)), 0, 4095)
