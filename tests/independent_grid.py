"""Grid images from a generator written with numpy alone, independent of
gridstrain.models.synthetic. Its assumptions:

- the specimen carries a printed pattern: a checkerboard (product of two tanh
  edges, edges about half a pixel wide, the blur of a good lens) or a grid of
  dark lines 0.3 period wide (tanh edges) or a pure sine grid;
- the pixel integrates the light over its area (3 x 3 sub-samples);
- the lighting is fixed to the camera, a broad Gaussian falling to about 40 %;
- a hole shows a uniform dark background (level 300 sensor grey levels);
- optional reflectance ``R(X, Y)`` of the specimen (a factor, a function of the
  material point: a stain, a wood grain, printing defects), moving with it;
- optional print texture: a reflectance factor ``1 + c t`` with ``t`` white noise
  smoothed by a Gaussian (20 px by default), normalised to unit std;
- the sensor is Poisson-Gaussian: ``K`` times a Poisson count plus normal read
  noise of variance ``L``, rounded to integers (quantisation adds 1/12), clipped
  to 12 bits and stored x16 in 16-bit integers.
"""

from __future__ import annotations

import numpy as np


def _pattern(a, b, kind, edge):
    if kind == "checker":
        c = 3.0  # edge width ~ p / (pi c): half a pixel at pitch 5
        return 0.5 + 0.5 * np.tanh(c * np.sin(np.pi * (a + b))) * np.tanh(
            c * np.sin(np.pi * (a - b))) / np.tanh(c) ** 2
    if kind == "lines":
        def line(t):  # dark lines 0.3 period wide; edge 4: ~0.3 px edges at pitch 4
            return 0.5 + 0.5 * np.tanh(edge * (np.cos(2 * np.pi * t) - np.cos(0.3 * np.pi)))
        return 1 - 0.5 * (line(a) + line(b))
    return 0.5 + 0.25 * (np.sin(2 * np.pi * a) + np.sin(2 * np.pi * b))


def scene(shape, *, pitch, angle, kind="checker", amplitude=2000.0, contrast=0.9,
           light=True, hole=True, texture=0.0, displacement=None, over=3, seed=0,
           edge=4.0, texture_scale=20.0, reflectance=None):
    """Noise-free expected sensor levels (float), and the hole mask."""
    H, W = shape
    th = np.deg2rad(angle)
    ys, xs = np.mgrid[0:H * over, 0:W * over].astype(np.float64)
    x, y = (xs + 0.5) / over - 0.5, (ys + 0.5) / over - 0.5
    X, Y = x, y
    if displacement is not None:  # Lagrangian: the point X is seen at X + u(X)
        for _ in range(8):
            ux, uy = displacement(X, Y)
            X, Y = x - ux, y - uy
    a = (np.cos(th) * X + np.sin(th) * Y) / pitch
    b = (-np.sin(th) * X + np.cos(th) * Y) / pitch
    img = amplitude * ((1 - contrast) + contrast * _pattern(a, b, kind, edge))
    if reflectance is not None:
        img = img * reflectance(X, Y)
    if light:
        img = img * (0.35 + 0.75 * np.exp(-((x - 0.4 * W) ** 2 + (y - 0.6 * H) ** 2)
                                           / (2 * (0.5 * W) ** 2)))
    inside = (0.075 * min(H, W) * 1.3) ** 2 > (X - 0.7 * W) ** 2 + (Y - 0.35 * H) ** 2
    img = img.reshape(H, over, W, over).mean(axis=(1, 3))
    inside = inside.reshape(H, over, W, over).mean(axis=(1, 3)) > 0.5
    if texture:
        rng = np.random.default_rng(seed + 1000)
        f2 = np.fft.fftfreq(H)[:, None] ** 2 + np.fft.fftfreq(W)[None] ** 2
        t = np.real(np.fft.ifft2(np.fft.fft2(rng.normal(size=(H, W)))
                                 * np.exp(-2 * np.pi**2 * texture_scale**2 * f2)))
        img = img * (1 + texture * t / t.std())
    if hole:
        img[inside] = 300.0
    return img, inside if hole else np.zeros((H, W), dtype=bool)


def camera(level, K, L, rng, scale=16):
    """Poisson-Gaussian 12-bit sensor, stored x ``scale`` in uint16."""
    e = rng.poisson(level / K)
    out = np.clip(np.round(K * e + rng.normal(0.0, np.sqrt(L), level.shape)), 0, 4095)
    return (out * scale).astype(np.uint16)


def stains(shape, *, sigma=25.0, amplitude=0.12):
    """Reflectance ``(X, Y) -> factor`` of two broad stains on the specimen, one
    brighter (std ``sigma`` px) and one darker (0.7 ``sigma``): no detail as sharp as
    a pitch."""
    H, W = shape

    def R(X, Y):
        return (1 + amplitude * np.exp(-((X - 0.3 * W) ** 2 + (Y - 0.45 * H) ** 2)
                                       / (2 * sigma**2))
                - 0.8 * amplitude * np.exp(-((X - 0.7 * W) ** 2 + (Y - 0.6 * H) ** 2)
                                           / (2 * (0.7 * sigma) ** 2)))

    return R


def grain(seed, *, along=40.0, across=3.0, amplitude=0.08, angle=90.0, n=300):
    """Reflectance ``(X, Y) -> factor`` of a wood-like grain: ``n`` random cosines whose
    wave vectors are drawn from a Gaussian spectrum ``along`` px wide along the grain
    (at ``angle`` degrees from x) and ``across`` px across it, normalised to a std of
    ``amplitude``."""
    rng = np.random.default_rng(seed)
    th = np.deg2rad(angle)
    d, nrm = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
    f = (rng.normal(0, 1 / (2 * np.pi * along), n)[:, None] * d
         + rng.normal(0, 1 / (2 * np.pi * across), n)[:, None] * nrm)
    phase = rng.uniform(0, 2 * np.pi, n)

    def R(X, Y):
        out = np.zeros_like(X)
        for (fx, fy), p in zip(f, phase, strict=True):
            out += np.cos(2 * np.pi * (fx * X + fy * Y) + p)
        return 1 + amplitude * np.sqrt(2 / n) * out

    return R
