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
    rdtype = pm.dphi.dtype
    found = _differentiator(sigma, np.dtype(np.float64))
    taps = found[0] if found is not None else np.array([0.5])  # central differences
    psi = np.array(pm.psi, dtype=np.complex128)
    dphi = np.array(pm.dphi, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(2):
            lnx, lny = (((_derivative(psi[j], taps, axis) / psi[j]).real) for axis in (1, 0))
            # where the grid's amplitude changes by a good fraction within the window (a
            # crack's gap, a hole's edge) the expansion is no longer one: left alone there
            taper = 1 / (1 + (sigma * np.hypot(lnx, lny) / _STEEPEST) ** 8)
            b = 0.0
            for _ in range(_PASSES):
                # the measured gradient holds the bias's own: omega = dphi - grad b
                wx = dphi[j, 0] - _derivative(b, taps, 1) if _ else dphi[j, 0]
                wy = dphi[j, 1] - _derivative(b, taps, 0) if _ else dphi[j, 1]
                b = sigma**2 * (wx * lnx + wy * lny)
                # a bias beyond a few tenths of a radian is no first-order term: the grid
                # vanishes there (a crack's gap, a hole's edge); saturated smoothly, so that
                # its gradient stays bounded where the expansion fails
                b = _SATURATION * np.tanh(np.where(np.isfinite(b), b * taper, 0.0)
                                          / _SATURATION)
            psi[j] *= np.exp(-1j * b)
            dphi[j, 0] -= _derivative(b, taps, 1)
            dphi[j, 1] -= _derivative(b, taps, 0)
    return PhaseMaps(psi=psi.astype(pm.psi.dtype, copy=False),
                     dphi=dphi.astype(rdtype, copy=False), valid=np.array(pm.valid),
                     lattice=pm.lattice, sigma=pm.sigma)


def _derivative(f: np.ndarray, taps: np.ndarray, axis: int) -> np.ndarray:
    """``sum_n taps[n-1] (f[x+n] - f[x-n])`` along ``axis``, the ends repeated."""
    m = taps.size
    pad = [(0, 0), (0, 0)]
    pad[axis] = (m, m)
    g = np.pad(f, pad, mode="edge")
    n = f.shape[axis]
    out = np.zeros_like(f)
    for i, a in enumerate(taps, start=1):
        hi = np.take(g, np.arange(m + i, m + i + n), axis=axis)
        lo = np.take(g, np.arange(m - i, m - i + n), axis=axis)
        out += a * (hi - lo)
    return out
