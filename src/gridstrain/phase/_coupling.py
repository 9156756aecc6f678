"""The phase-modulus coupling of the windowed Fourier transform, corrected to first order
(:func:`coupling_corrected`).

For a grid component ``a(x) exp(i theta(x))`` and a window centred on the carrier ``k``,
``Psi(x) ~ a exp(i phi) exp(-sigma^2 |omega|^2 / 2) (1 + i sigma^2 omega . grad ln a)``,
with ``phi = theta - 2 pi k . x`` and ``omega = grad phi`` the carrier's mismatch with the
grid's local frequency: the phase is biased by ``sigma^2 omega . grad ln a`` where the
grid's amplitude varies (print, lighting, a hole's edge) and the carrier is off the
local frequency (a rotation, a strain, a crack's field).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ._maps import PhaseMaps
from ._transform import _differentiator

# Passes of the fixed point omega = dphi - grad b: the first leaves the bias's own
# gradient in omega, a relative error of sigma^2 |grad grad ln |Psi||; the second removes it.
_PASSES = 2
# The largest correction, rad: well above the coupling of print defects at a mismatch of
# a few degrees (0.01-0.05 rad, which tanh leaves within 0.2 % at 0.02 / 0.2), well below
# the phase's range, where the window's expansion has failed.
_SATURATION = 0.2
# The steepest amplitude corrected, as sigma |grad ln |Psi||: printed defects, dust and
# lighting stay below 0.1 (the correction then within 1e-3 of itself); a crack's gap or
# a hole's edge reach 0.3 to 2, where the neglected terms are as large as the first.
_STEEPEST = 0.25


def coupling_corrected(pm: PhaseMaps) -> PhaseMaps:
    """``pm`` with the phase-modulus coupling of its window taken out, to first order.

    The transform at the carrier ``k + delta`` and the one at ``k`` are related, to first
    order in ``delta``, through the transform's own spatial derivative:
    ``Psi_{k+delta}(x) exp(2 i pi delta . x) = Psi_k(x) (1 - i sigma^2 2 pi delta . grad
    Psi_k / Psi_k)``, since ``d Psi_k / dk`` is ``-2 i pi`` times the window's first
    moment. Taking ``2 pi delta = omega``, the measured phase gradient (rad/px: the
    mismatch of ``pm``'s carrier with the grid's local frequency), moves each pixel's
    window onto the grid's own carrier and changes the phase by ``-b``, ``b = sigma^2
    omega . grad ln |Psi|`` (``grad ln |Psi| = Re(grad Psi / Psi)``). ``psi`` is
    multiplied by ``exp(-i b)`` and ``grad b`` is taken from ``dphi``.

    Parameters
    ----------
    pm : PhaseMaps
        Maps of one transform, demodulated at the carrier they were transformed at (not
        brought to another one by :func:`demodulated_at`: ``omega`` is the mismatch with
        that carrier).

    Returns
    -------
    PhaseMaps
        The same validity, lattice and window; ``psi`` and ``dphi`` corrected, in their
        dtypes.

    Notes
    -----
    ``grad Psi`` comes from the least-squares differentiator of the fast derivatives
    (within 1e-8 rad/px of the window's analytic derivative), ``grad b`` from the same
    filter. What is left is of second order in ``sigma^2 omega`` and in the window's
    smoothing of the amplitude (``grad ln |Psi|`` is that of the amplitude seen through
    the window, not of the print itself): on images of printed grids with ink blots and
    gaps, the bias of a 1.5 degree mismatch falls from 0.015 to 0.004 px
    (tests/test_coupling.py). Where the carrier matches the grid (``omega = 0``) nothing
    changes.
    """
    sigma = float(pm.sigma)
    found = _differentiator(sigma, np.dtype(np.float64))
    # central differences where the window is too narrow for a short filter
    weights = _weights(found[0] if found is not None else np.array([0.5]))
    psi = np.empty_like(pm.psi)
    dphi = np.empty_like(pm.dphi)
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(2):
            # a correction of at most 0.2 rad needs no more digits than float32's (1e-7
            # relative, 1e-8 rad), at a fraction of float64's cost
            re, im = (part.astype(np.float32) for part in (pm.psi[j].real, pm.psi[j].imag))
            wx, wy = pm.dphi[j].astype(np.float32)
            power = re * re + im * im
            # sigma^2 grad ln |Psi| = sigma^2 Re(conj(Psi) grad Psi) / |Psi|^2
            gx = (re * _derivative(re, weights, 1) + im * _derivative(im, weights, 1)) / power
            gy = (re * _derivative(re, weights, 0) + im * _derivative(im, weights, 0)) / power
            # where the grid's amplitude changes by a good fraction within the window (a
            # crack's gap, a hole's edge) the expansion is no longer one: left alone there
            q = (gx * gx + gy * gy) * (sigma / _STEEPEST) ** 2
            q *= q
            scale = sigma**2 / (1 + q * q)
            gx *= scale
            gy *= scale
            b = _saturated(wx * gx + wy * gy)
            # the measured gradient holds the bias's own: omega = dphi - grad b
            for _ in range(_PASSES - 1):
                b = _saturated((wx - _derivative(b, weights, 1)) * gx
                               + (wy - _derivative(b, weights, 0)) * gy)
            turn = np.empty(b.shape, np.complex64)
            np.cos(b, out=turn.real)
            np.negative(np.sin(b), out=turn.imag)
            np.multiply(pm.psi[j], turn.astype(pm.psi.dtype, copy=False), out=psi[j])
            np.subtract(pm.dphi[j, 0], _derivative(b, weights, 1), out=dphi[j, 0])
            np.subtract(pm.dphi[j, 1], _derivative(b, weights, 0), out=dphi[j, 1])
    return PhaseMaps(psi=psi, dphi=dphi, valid=pm.valid, lattice=pm.lattice, sigma=pm.sigma)


def _saturated(b: np.ndarray) -> np.ndarray:
    """``b`` (rad) with non-finite values 0 and values beyond ``_SATURATION`` bent
    smoothly towards it: a bias beyond a few tenths of a radian is no first-order term
    (the grid vanishes there), and its gradient stays bounded where the expansion
    fails."""
    b = np.where(np.isfinite(b), b, 0)
    return _SATURATION * np.tanh(b / _SATURATION, out=b)


def _derivative(f: np.ndarray, weights: np.ndarray, axis: int) -> np.ndarray:
    """The differentiator ``weights`` (:func:`_weights`) along ``axis`` (1: x, 0: y), the
    ends repeated; a complex ``f`` by its real and imaginary parts."""
    if np.iscomplexobj(f):
        return (_derivative(f.real, weights, axis)
                + 1j * _derivative(f.imag, weights, axis))
    return ndimage.correlate1d(f, weights.astype(f.dtype), axis=axis, mode="nearest")


def _weights(taps: np.ndarray) -> np.ndarray:
    """``sum_n taps[n-1] (f[x+n] - f[x-n])`` as the 2m + 1 weights of a correlation."""
    return np.concatenate([-taps[::-1], [0.0], taps])
