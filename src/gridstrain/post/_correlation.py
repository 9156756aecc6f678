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

import hashlib
import math
import threading

import numpy as np
import scipy.fft as sfft

#: Half-width of the correlation kernels, in sigma: exp(-8^2/4) (1 + 8^2/2) ~ 4e-6.
_RADIUS_SIGMAS = 8.0

_COMPONENTS = {"exx": (0, 0), "eyy": (1, 1), "exy": (0, 1)}
_GRADIENT = {"uxy": (0, 1), "uyx": (1, 0)}


def _grid(sigma: float):
    r = math.ceil(_RADIUS_SIGMAS * sigma)
    d = np.arange(-r, r + 1, dtype=np.float64)
    return d[None, :], d[:, None]  # dx along columns, dy along rows


def displacement_correlation(sigma: float, d2) -> np.ndarray:
    """Correlation of the displacement noise at squared distances ``d2`` (px^2)."""
    return np.exp(-np.asarray(d2, dtype=np.float64) / (4.0 * sigma * sigma))


def strain_kernel(lattice, sigma: float, component: str) -> np.ndarray:
    """``(2R+1, 2R+1)`` correlation of the noise of a strain component, 1 at its centre.

    ``component``: ``exx``, ``eyy``, ``exy``; or a component of the displacement
    gradient ``uxy`` (``du_x/dy``), ``uyx`` (``du_y/dx``), or the ``rotation``
    ``(du_y/dx - du_x/dy) / 2``: each a sum of the phases' derivatives along the
    vectors ``c_n`` of the module's docstring.
    """
    minv = np.linalg.inv(np.array([lattice.k1, lattice.k2], dtype=np.float64))
    dx, dy = _grid(sigma)
    base = np.exp(-(dx * dx + dy * dy) / (4.0 * sigma * sigma))
    total = np.zeros_like(base)
    weight = 0.0
    for n in range(2):
        c = np.zeros(2)
        if component in _COMPONENTS:
            i, j = _COMPONENTS[component]
            c[j] += minv[i, n] / 2
            c[i] += minv[j, n] / 2
        elif component == "rotation":
            c[0] += minv[1, n] / 2
            c[1] -= minv[0, n] / 2
        else:  # du_i/dx_j
            i, j = _GRADIENT[component]
            c[j] += minv[i, n]
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
    ``inside``, ``s`` zero outside it. The double sum is ``sum_d rho(d) A(d)``, ``A``
    the autocorrelation of ``s``; by the Wiener-Khinchin theorem it is
    ``sum_f K(f) |S(f)|^2 / P`` over the ``P`` frequencies of one FFT of ``s``
    zero-padded by the kernel's radius (so that no lag the kernel reaches wraps
    around), ``K`` the transform of the even kernel, real, computed once per padded
    size: one transform per call where a convolution takes three.
    """
    rows, cols = np.nonzero(inside)
    n = rows.size
    if n == 0:
        return math.nan
    if n == 1:
        return float(std[rows[0], cols[0]])
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    s = np.where(inside[box], std[box], 0.0).astype(np.float64)
    # lags beyond the box pair no pixels: the kernel cut to them
    r = kernel.shape[0] // 2
    ry, rx = min(r, s.shape[0] - 1), min(r, s.shape[1] - 1)
    kernel = kernel[r - ry:r + ry + 1, r - rx:r + rx + 1]
    shape = (sfft.next_fast_len(s.shape[0] + ry, real=True),
             sfft.next_fast_len(s.shape[1] + rx, real=True))
    power = np.abs(sfft.rfft2(s, s=shape)) ** 2
    spectrum = _kernel_spectrum(kernel, shape)
    # the half spectrum: the columns but the first (and the Nyquist one) twice
    weights = np.full(power.shape[1], 2.0)
    weights[0] = 1.0
    if shape[1] % 2 == 0:
        weights[-1] = 1.0
    total = float(np.sum((power * spectrum) @ weights)) / (shape[0] * shape[1])
    return math.sqrt(max(total / (n * n), 0.0))


_SPECTRA: dict = {}
_SPECTRA_LOCK = threading.Lock()


def _kernel_spectrum(kernel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The real half spectrum of ``kernel`` (odd sides, centred, even: ``k(-d) =
    k(d)``, each side at most ``shape``'s plus one over two) placed with its centre at
    the origin of a periodic ``shape``; the last few kept (a gauge's states share
    theirs)."""
    key = (kernel.shape, hashlib.sha1(np.ascontiguousarray(kernel).tobytes()).hexdigest(),
           shape)
    with _SPECTRA_LOCK:
        found = _SPECTRA.get(key)
    if found is None:
        placed = np.zeros(shape)
        ry, rx = kernel.shape[0] // 2, kernel.shape[1] // 2
        placed[np.ix_(np.arange(-ry, ry + 1) % shape[0],
                      np.arange(-rx, rx + 1) % shape[1])] = kernel
        found = sfft.rfft2(placed).real  # an even kernel's transform is real
        with _SPECTRA_LOCK:
            if len(_SPECTRA) >= 8:
                _SPECTRA.pop(next(iter(_SPECTRA)))
            _SPECTRA[key] = found
    return found


def strain_noise_correlation(result) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The correlation of a result's strain noise between two pixels, per component.

    Parameters
    ----------
    result : SeriesResult
        Its lattice and window (``sigma``) set the correlation.

    Returns
    -------
    exx, eyy, exy : (2R+1, 2R+1) float64 ndarray
        The correlation of the noise of two pixels ``[dy, dx]`` apart (the centre is
        ``[R, R]``, 1 there), ``R = ceil(8 sigma)``: the window's smoothing, derived in
        this module's docstring. The same kernels weigh the double sums of a gauge's
        std (:func:`gridstrain.post.gauge`).
    """
    return tuple(strain_kernel(result.lattice, result.sigma, name)
                 for name in ("exx", "eyy", "exy"))
