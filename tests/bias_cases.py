"""Noise-free images of a printed grid for the systematic-error bounds (aliasing and the
window's smoothing), written with numpy alone. It shares no code and no model with
``gridstrain.models.synthetic``, ``tests/independent_grid.py`` or
``tests/world_camera.py``. Its assumptions:

- the print is two crossed families of dark lines (ink reflectance ``ink`` on paper
  of reflectance 1), wave vectors ``k1 = (cos t, sin t) / pitch`` and ``k2 = (-sin t,
  cos t) / pitch``; a line is a sharp box covering a fraction ``f`` of the pitch,
  ``L = sum_n a_n exp(2 pi i n phi)`` with ``a_0 = f``, ``a_n = sin(pi n f) / (pi n)``
  (its exact Fourier series); the crossings are ink once:
  ``R = 1 - (1 - ink) (L1 + L2 - L1 L2)``;
- the line width varies along the specimen: ``f(X) = f0 (1 + dw (2 X / W - 1))``, a
  ramp of ``+-dw`` across the frame, in the material's coordinate ``X`` (it moves with
  the specimen); the coefficients ``a_n`` follow ``f`` point by point;
- the optics: each harmonic ``n k1 + m k2`` is multiplied by the pixel's area
  integration, ``sinc(h_x) sinc(h_y)`` (perfect optics, ``blur = 0``), times a
  Gaussian point-spread function's transfer ``exp(-2 pi^2 b^2 |h|^2)`` (``blur = b``
  px std); the transfer is taken at the undeformed frequency (strains of 2 % change
  it by under 1 % of itself); harmonics whose amplitude bound ``|a_n a_m|`` times the
  transfer is under ``1e-5`` are left out (each moves the phase by under 1e-4 rad);
- a pure sine print (``kind="sine"``): ``R = 1/2 + 1/4 (cos 2 pi phi1 + cos 2 pi
  phi2)``, no harmonics, for the smoothing cases;
- vignetting, fixed to the camera: ``(1 + r^2 / F^2)^-2`` (the cos^4 law), ``F`` set
  so that the corners fall by ``vignetting`` (0 to 0.5);
- the deformation: the material point ``X`` is seen at ``x = X + u(X)`` (Lagrangian);
  the camera pixel ``x`` sees ``X`` found by the fixed-point iteration
  ``X <- x - u(X)`` (30 iterations); the phases are ``phi_j = k_j . X`` exactly, so the
  truth ``u`` is exact whatever the print;
- no noise, no quantisation: the errors measured are the method's bias alone.
"""

from __future__ import annotations

import numpy as np

LEVEL = 1000.0  # grey levels of white paper at the frame's centre
INK = 0.1
_SMALL = 1e-5  # the smallest harmonic amplitude kept, of the paper's level


def lattice_vectors(pitch, angle_deg):
    t = np.deg2rad(angle_deg)
    k1 = np.array([np.cos(t), np.sin(t)]) / pitch
    k2 = np.array([-np.sin(t), np.cos(t)]) / pitch
    return k1, k2


def material_points(shape, displacement):
    """``(X, Y)`` seen at each pixel (Lagrangian ``displacement(X, Y) -> (ux, uy)``)."""
    H, W = shape
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    X, Y = x.copy(), y.copy()
    if displacement is not None:
        for _ in range(30):
            ux, uy = displacement(X, Y)
            X, Y = x - ux, y - uy
    return X, Y


def _transfer(h, blur):
    return np.sinc(h[0]) * np.sinc(h[1]) * np.exp(-2 * np.pi**2 * blur**2 * (h @ h))


def image(shape, *, pitch, angle=0.6, width=0.35, dw=0.0, blur=0.0, vignetting=0.0,
          displacement=None, kind="lines"):
    """Noise-free sensor levels (float64, ``shape``) of the print seen through the
    camera, deformed by ``displacement`` (None: the reference)."""
    H, W = shape
    k1, k2 = lattice_vectors(pitch, angle)
    X, Y = material_points(shape, displacement)
    p1 = np.exp(2j * np.pi * (k1[0] * X + k1[1] * Y))
    p2 = np.exp(2j * np.pi * (k2[0] * X + k2[1] * Y))
    if kind == "sine":
        R = 0.5 + 0.25 * (np.real(p1) * _transfer(k1, blur) + np.real(p2) * _transfer(k2, blur))
    else:
        f = width * (1 + dw * (2 * X / W - 1))
        R = _lines(p1, p2, f, k1, k2, blur)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    r2 = (x - (W - 1) / 2) ** 2 + (y - (H - 1) / 2) ** 2
    corner = ((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2
    if vignetting > 0:
        # (1 + c / F^2)^-2 = 1 - vignetting at the corner
        F2 = corner / ((1 - vignetting) ** -0.5 - 1)
        R = R * (1 + r2 / F2) ** -2
    return LEVEL * R


def _coef(n, f):
    return f if n == 0 else np.sin(np.pi * n * f) / (np.pi * n)


def _lines(p1, p2, f, k1, k2, blur):
    """``R`` of the crossed lines as its Fourier sum, each harmonic through the optics."""
    # the sum of the families, and their product (the crossings) less
    L1L2 = np.zeros(p1.shape, dtype=np.complex128)
    R = np.ones(p1.shape) - (1 - INK) * (2 * f - f * f)  # the (0, 0) terms
    nmax = 1
    while True:  # the largest order of one family worth keeping
        h = nmax * k1
        if abs(_transfer(h, blur)) / (np.pi * nmax) < _SMALL and nmax * np.hypot(*k1) > 1:
            break
        nmax += 1
    # the crossings' orders worth keeping: |a_n a_m| <= 1 / (pi^2 n m)
    ncross = 1
    while max(abs(_transfer(ncross * k1 + s * k2, blur)) for s in (1, -1)) \
            / (np.pi**2 * ncross) >= _SMALL or ncross * np.hypot(*k1) <= 1:
        ncross += 1
    ncross = min(ncross, nmax)
    # one family alone: a_n (e^{i n phi} + e^{-i n phi}), times (1 - a_0 of the other)
    pw1, pw2 = np.ones_like(p1), np.ones_like(p2)
    pows1, pows2 = [pw1], [pw2]
    for n in range(1, nmax + 1):
        pw1 = pw1 * p1
        pw2 = pw2 * p2
        if n <= ncross:
            pows1.append(pw1)
            pows2.append(pw2)
        a = _coef(n, f)
        t1, t2 = _transfer(n * k1, blur), _transfer(n * k2, blur)
        # L1 + L2 - L1 L2 on the pure orders: a_n (1 - a_0(other))
        R -= (1 - INK) * 2 * a * (1 - f) * (t1 * np.real(pw1) + t2 * np.real(pw2))
    for n in range(1, ncross + 1):
        an = _coef(n, f)
        for m in range(1, ncross + 1):
            tp = _transfer(n * k1 + m * k2, blur)
            tm = _transfer(n * k1 - m * k2, blur)
            if max(abs(tp), abs(tm)) / (np.pi**2 * n * m) < _SMALL:
                continue
            am = _coef(m, f)
            # e^{i(n phi1 + m phi2)} and e^{i(n phi1 - m phi2)} and their conjugates
            L1L2 += an * am * (tp * pows1[n] * pows2[m] + tm * pows1[n] * np.conj(pows2[m]))
    R += (1 - INK) * 2 * np.real(L1L2)
    return R


def stretch(ex, ey, centre):
    """A homogeneous stretch about ``centre``: ``u = (ex (X - cx), ey (Y - cy))``."""
    cx, cy = centre

    def disp(X, Y):
        return ex * (X - cx), ey * (Y - cy)
    return disp


def gaussian_feature(amplitude, width, x0, *, y0=None):
    """``u_x`` whose ``e_xx`` is ``amplitude exp(-(X - x0)^2 / 2 width^2)`` (a band
    across the frame), or, with ``y0``, that band times ``exp(-(Y - y0)^2 / 2 width^2)``
    (``e_xx`` then a round bump at its centre, ``u_x`` fading along ``Y``); and the exact
    ``e_xx`` of that ``u_x`` (its derivative along ``X``, Lagrangian)."""
    from scipy.special import erf

    s = width * np.sqrt(np.pi / 2)

    def fade(Y):
        return 1.0 if y0 is None else np.exp(-(Y - y0) ** 2 / (2 * width**2))

    def disp(X, Y):
        return amplitude * s * erf((X - x0) / (np.sqrt(2) * width)) * fade(Y), 0 * Y

    def exx(X, Y):
        return amplitude * np.exp(-(X - x0) ** 2 / (2 * width**2)) * fade(Y)
    return disp, exx
