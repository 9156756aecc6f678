"""Spatial correlation of the noise of the maps, from the Gaussian window.

The windowed Fourier transform of a grid image ``I = I0 + n`` at wave vector
``k`` is ``W(x) = sum_x' I(x') g(x - x') exp(-2i pi k.x')`` with ``g`` the
centred, unit-sum Gaussian of standard deviation ``sigma``. Demodulated, the
white sensor noise ``m(x') = n(x') exp(-2i pi k.x')`` is circular (its real and
imaginary parts uncorrelated, of equal variance) once the carrier is far from 0
and from the Nyquist frequency. To first order the phase noise is
``Im(exp(-i phi) (m * g)) / |W|`` and the noise of its derivative along a unit
vector ``c`` is ``Im(exp(-i phi) (m * d_c g)) / |W|``. For circular ``m``
``E[Im(a z1) Im(b z2)] = Re(a conj(b) E[z1 conj(z2)]) / 2``, so, with the
modulus and phase of ``W`` slowly varying, the correlation between two pixels
``d`` apart is the autocorrelation of the kernel, normalised:

- phase (hence displacement): ``(g * g)(d) / (g * g)(0) = exp(-|d|^2 / (4 sigma^2))``,
  the autocorrelation of a Gaussian being a Gaussian of variance ``2 sigma^2``;
- phase derivative along ``c``: ``-d_c^2 (g * g)(d) / (-d_c^2 (g * g))(0)
  = exp(-|d|^2 / (4 sigma^2)) (1 - (c.d)^2 / (2 sigma^2))``.

The second integrates to zero over the plane (a derivative kernel has no mean):
the mean of a phase derivative over a segment is the difference of the phase
at its ends divided by its length, so the std of a region's mean strain falls
as 1 / size, not as 1 / sqrt(number of pixels). No "effective number of
independent pixels" describes that; the double sum below does.

A strain component is a sum over the two wave vectors of derivatives of their
phases: with ``M`` the matrix of rows ``k1``, ``k2`` (cycles/px), ``u = -M^-1
(phi_def - phi_ref) / 2 pi`` (:mod:`gridstrain.conventions`), hence
``e_ij = -1/(2 pi) sum_n c_n . grad phi_n`` with
``c_n = (M^-1[i, n] e_j + M^-1[j, n] e_i) / 2``. The phases of the two wave
vectors are demodulated at different carriers, so their noises are
uncorrelated; with noise of equal variance on both (a square grid), the
correlation of ``e_ij`` is the average of the two derivative correlations
weighted by ``|c_n|^2``. The reference and the deformed image add their noises
through the same kernels.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import fftconvolve

#: Half-width of the correlation kernels, in sigma: exp(-8^2/4) (1 + 8^2/2) ~ 4e-6.
_RADIUS_SIGMAS = 8.0

_COMPONENTS = {"exx": (0, 0), "eyy": (1, 1), "exy": (0, 1)}


def _grid(sigma: float):
    r = math.ceil(_RADIUS_SIGMAS * sigma)
    d = np.arange(-r, r + 1, dtype=np.float64)
    return d[None, :], d[:, None]  # dx along columns, dy along rows


def displacement_correlation(sigma: float, d2) -> np.ndarray:
    """Correlation of the displacement noise at squared distances ``d2`` (px^2)."""
    return np.exp(-np.asarray(d2, dtype=np.float64) / (4.0 * sigma * sigma))


def strain_kernel(lattice, sigma: float, component: str) -> np.ndarray:
    """``(2R+1, 2R+1)`` correlation of the noise of a strain component, 1 at its centre."""
    minv = np.linalg.inv(np.array([lattice.k1, lattice.k2], dtype=np.float64))
    i, j = _COMPONENTS[component]
    dx, dy = _grid(sigma)
    base = np.exp(-(dx * dx + dy * dy) / (4.0 * sigma * sigma))
    total = np.zeros_like(base)
    weight = 0.0
    for n in range(2):
        c = np.zeros(2)
        c[j] += minv[i, n] / 2
        c[i] += minv[j, n] / 2
        w = float(c @ c)
        if w == 0.0:
            continue
        cx, cy = c / math.sqrt(w)
        total += w * base * (1.0 - (cx * dx + cy * dy) ** 2 / (2.0 * sigma * sigma))
        weight += w
    return total / weight


def displacement_kernel(sigma: float) -> np.ndarray:
    """``(2R+1, 2R+1)`` correlation of the noise of a displacement component."""
    dx, dy = _grid(sigma)
    return displacement_correlation(sigma, dx * dx + dy * dy)


def std_of_mean(std: np.ndarray, inside: np.ndarray, kernel: np.ndarray) -> float:
    """Std of the mean of a map over ``inside``, its pixels' noise correlated by ``kernel``.

    ``Var = sum_ij s_i s_j rho(x_i - x_j) / N^2`` over the ``N`` pixels of
    ``inside``, the sum computed as ``sum_i s_i (s * rho)(x_i)`` with an FFT
    convolution over the bounding box of ``inside``.
    """
    rows, cols = np.nonzero(inside)
    n = rows.size
    if n == 0:
        return math.nan
    if n == 1:
        return float(std[rows[0], cols[0]])
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    s = np.where(inside[box], std[box], 0.0).astype(np.float64)
    var = float(np.sum(s * fftconvolve(s, kernel, mode="same"))) / (n * n)
    return math.sqrt(max(var, 0.0))
