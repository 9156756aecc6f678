"""The phase-modulus coupling of the windowed Fourier transform, corrected to second
order (:func:`coupling_corrected`).

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

from .._validation import check_float_dtype
from ._maps import PhaseMaps, compiled_loops
from ._transform import _differentiator

# The largest correction, rad: well above the coupling of print defects at a mismatch of
# a few degrees (0.01-0.05 rad, which tanh leaves within 0.2 % at 0.02 / 0.2), well below
# the phase's range, where the window's expansion has failed.
_SATURATION = 0.2
# The steepest amplitude corrected, as sigma |grad ln |Psi||: printed defects, dust and
# lighting stay below 0.1 (the correction then within 1e-3 of itself); a crack's gap or
# a hole's edge reach 0.3 to 2, where the neglected terms are as large as the first.
_STEEPEST = 0.25


def coupling_corrected(pm: PhaseMaps, *, dtype=None) -> PhaseMaps:
    """``pm`` with the phase-modulus coupling of its window taken out, to second order.

    For the Gaussian window, moving the carrier by ``omega / 2 pi`` (and demodulating
    back) is evaluating ``Psi`` at a complex point: ``sum_d g(d) s(x + d) exp(-i omega .
    d) = exp(-sigma^2 |omega|^2 / 2) Psi(x - i sigma^2 omega)``, ``Psi`` continued
    analytically. Taking ``omega`` the grid's local frequency mismatch, each pixel's
    window is moved onto the grid's own carrier; the phase of the Taylor series of
    ``ln Psi`` changes by ``-b``,

    ``b = sigma^2 omega . grad ln |Psi| + (sigma^4 / 2) omega . grad grad phi . omega``

    (the next term, ``-(sigma^6 / 6) (omega . grad)^3 ln |Psi|``, is left out), with
    ``grad ln |Psi| = Re(grad Psi / Psi)`` and ``grad phi = dphi`` of the transform
    itself. ``omega`` is ``dphi - grad b``: the measured gradient holds the bias's own.
    ``psi`` is multiplied by ``exp(-i b)`` and ``grad b`` is taken from ``dphi``.

    Parameters
    ----------
    pm : PhaseMaps
        Maps of one transform, demodulated at the carrier they were transformed at
        (not yet brought to another by :func:`~gridstrain.phase.demodulated_at`:
        ``omega`` is the mismatch with that carrier).
    dtype : {None, numpy.float32, numpy.float64}
        The precision of the maps returned (None: ``pm``'s). float64 from float32 maps
        widens them as they are written: the maps of a frame transformed in float32
        take their float64 precision here, without a copy of their own.

    Returns
    -------
    PhaseMaps
        The same validity, lattice and window; ``psi`` and ``dphi`` corrected, in their
        dtypes (``dtype``'s where given).

    Notes
    -----
    To first order, ``Psi ~ a exp(i phi) exp(-sigma^2 |omega|^2 / 2) (1 + i sigma^2 omega .
    grad ln a)``: a phase bias of ``sigma^2 omega . grad ln a`` where the grid's amplitude
    ``a`` (seen through the window: ``|Psi|`` is it) varies and the carrier is off the
    local frequency. The second-order term is that of a curved phase (a strain gradient):
    under a uniform amplitude the first term alone would correct it twice. What is left
    is of third order, about ``sigma^2 |omega|^2 / 3`` of the bias: against a direct
    Gaussian-window sum on a dip of the amplitude (tests/test_coupling.py), 1 % of it at
    a mismatch of 1.5 degrees, 3.5 % at 3 and 12 % at 5, where the first-order term
    alone leaves 2.5, 7 and 17 %. Print defects narrower than about a third of the
    window (an ink blot of 2 px radius at sigma = 6.4 px) also let the grid's conjugate
    component into the window, which no shift of the carrier removes.

    Where the carrier matches the grid (``omega = 0``) nothing changes. Where the
    grid's amplitude changes by a good fraction within the window (``sigma |grad ln
    |Psi||`` beyond ``_STEEPEST``: a crack's gap, a hole's edge) the series is no
    longer one and the correction is faded out; and it never exceeds
    ``_SATURATION``.

    The derivatives are the least-squares differentiator of the fast derivatives
    (within 1e-8 rad/px of the window's analytic derivative), in float32, the ends of
    the maps repeated: nine per wave vector. With numba (the ``fast`` extra) compiled
    loops (:mod:`gridstrain.phase._kernels`) take them in three passes down the rows,
    each a few rows behind the one before, so that what the passes exchange stays in
    cache; without it, ``scipy.ndimage`` correlations of whole maps. Both give the
    same maps to float32's rounding (within 2e-6 rad at sigma = 5 px,
    tests/test_coupling.py); ``benchmarks/bench_coupling.py`` times them against the
    transform.
    """
    sigma = float(pm.sigma)
    found = _differentiator(sigma, np.dtype(np.float64))
    # central differences where the window is too narrow for a short filter
    taps = found[0] if found is not None else np.array([0.5])
    real = pm.dphi.dtype if dtype is None else check_float_dtype(dtype, allow_none=False)
    psi = np.empty(pm.psi.shape, np.result_type(real, np.complex64))
    dphi = np.empty(pm.dphi.shape, real)
    kern = compiled_loops()
    if kern is not None:
        _compiled(kern, pm, sigma, taps, psi, dphi)
    else:
        _numpy(pm, sigma, _weights(taps), psi, dphi)
    return PhaseMaps(psi=psi, dphi=dphi, valid=pm.valid, lattice=pm.lattice, sigma=pm.sigma)


def _compiled(kern, pm: PhaseMaps, sigma: float, taps: np.ndarray, psi: np.ndarray,
              dphi: np.ndarray):
    """:func:`coupling_corrected` into ``psi``, ``dphi`` by the compiled loops
    (:func:`gridstrain.phase._kernels.coupling_rows`): the operations of :func:`_bias`
    in float32, row by row, with ``ln |Psi|`` taken as half the logarithm of
    ``|Psi|^2 / max |Psi|^2`` and the logarithm, tanh, cos and sin as polynomials
    that the loops vectorise (within an ulp or a few of libm's)."""
    a = taps.astype(np.float32)
    m = taps.size
    W = pm.shape[1]
    R = 2 * m + 1
    ring = np.empty((5, R, W + 2 * m), np.float32)
    rows = np.empty((3, R, W), np.float32)
    tmp = np.empty((5, W), np.float32)
    f32 = np.float32
    for j in range(2):
        src = np.ascontiguousarray(pm.psi[j])
        src = src.view(src.real.dtype)
        with np.errstate(divide="ignore"):  # no signal at all: 1 / 0, then NaN maps
            inv = 1 / np.float64(kern.max_norm(src))
        kern.coupling_rows(src, np.ascontiguousarray(pm.dphi[j]), inv,
                           a, f32(sigma**2),
                           f32((sigma / _STEEPEST) ** 2), f32(0.5 * sigma**2),
                           f32(_SATURATION), psi[j].view(dphi.dtype), dphi[j], ring, rows,
                           tmp)


def _numpy(pm: PhaseMaps, sigma: float, weights: np.ndarray, psi: np.ndarray,
           dphi: np.ndarray):
    """:func:`coupling_corrected` into ``psi``, ``dphi`` in numpy."""
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(2):
            b = _bias(pm.psi[j], pm.dphi[j], sigma, weights)
            turn = np.empty(b.shape, np.complex64)
            np.cos(b, out=turn.real)
            np.negative(np.sin(b), out=turn.imag)
            # complex64 widened in the product's buffers, exactly: no full-size copy
            np.multiply(pm.psi[j], turn, out=psi[j])
            np.subtract(pm.dphi[j, 0], _derivative(b, weights, 1), out=dphi[j, 0])
            np.subtract(pm.dphi[j, 1], _derivative(b, weights, 0), out=dphi[j, 1])


def _bias(psi: np.ndarray, dphi: np.ndarray, sigma: float, weights: np.ndarray):
    """The phase bias ``b`` of one wave vector's ``psi`` (H, W) and ``dphi`` (2, H, W), rad,
    float32 (:func:`coupling_corrected`)."""
    # float32 (1e-7 relative) at a fraction of float64's cost: ln |Psi| rounded to
    # 1e-6 where |ln| ~ 10, through sigma^2 omega and the differentiator, leaves the
    # correction within about 1e-6 rad of float64's arithmetic, far below the maps'
    # noise
    wx, wy = dphi.astype(np.float32)
    # grad ln |Psi| = Re(grad Psi / Psi): ln |Psi| is as smooth as Psi where the grid
    # shows, and one map to differentiate rather than two
    mod = np.abs(psi)
    # relative to its largest value, so that images scaled by a power of two (12-bit
    # data stored x16) give the same maps to the last bit
    lnmod = np.log((mod / mod.max()).astype(np.float32))
    gx = _derivative(lnmod, weights, 1)
    gy = _derivative(lnmod, weights, 0)
    q = (gx * gx + gy * gy) * (sigma / _STEEPEST) ** 2
    q *= q
    scale = sigma**2 / (1 + q * q)  # sigma^2, faded out where the series fails
    gx *= scale
    gy *= scale
    # first order with omega = dphi; then omega = dphi - grad b, and the second order
    b = _saturated(wx * gx + wy * gy)
    ox = wx - _derivative(b, weights, 1)
    oy = wy - _derivative(b, weights, 0)
    curv = (ox * ox * _derivative(wx, weights, 1) + 2 * ox * oy * _derivative(wx, weights, 0)
            + oy * oy * _derivative(wy, weights, 0))
    return _saturated(ox * gx + oy * gy + 0.5 * sigma**2 * scale * curv)


def _saturated(b: np.ndarray) -> np.ndarray:
    """``b`` (rad) with non-finite values 0 and values beyond ``_SATURATION`` bent
    smoothly towards it: a bias beyond a few tenths of a radian is no first-order term
    (the grid vanishes there), and its gradient stays bounded where the expansion
    fails."""
    b = np.where(np.isfinite(b), b, 0)
    return _SATURATION * np.tanh(b / _SATURATION, out=b)


def _derivative(f: np.ndarray, weights: np.ndarray, axis: int) -> np.ndarray:
    """The differentiator ``weights`` (:func:`_weights`) along ``axis`` (1: x, 0: y) of a
    real map, the ends repeated."""
    return ndimage.correlate1d(f, weights.astype(f.dtype), axis=axis, mode="nearest")


def _weights(taps: np.ndarray) -> np.ndarray:
    """``sum_n taps[n-1] (f[x+n] - f[x-n])`` as the 2m + 1 weights of a correlation."""
    return np.concatenate([-taps[::-1], [0.0], taps])
