"""The noise of the windowed Fourier transform's maps (Prop. 2.3, eqs. 34-35): the window's
energy, the phase and phase-derivative noise of a grid image, that of method C's compensated
average, and what it becomes in the displacement and the strain.
"""

from __future__ import annotations

import math

import numpy as np

from .._validation import (
    check_frequency,
    check_int,
    check_nonnegative,
    check_positive,
    check_range,
    check_type,
)
from ..phase import Lattice
from ._averaging import _WINDOW_SUM_SIGMAS, _check_stds, profile_coefficients


def window_energy(sigma: float, *, continuous: bool = False) -> tuple[float, float]:
    """Energies ``sum g^2`` and ``sum (dg/dx)^2`` of the 2-D window of :func:`wft`.

    Parameters
    ----------
    sigma : float
        Standard deviation of the Gaussian window, px.
    continuous : bool
        False: the exact sums over the sampled window of
        :func:`gridstrain.phase.wft`, centred on a pixel and normalised to unit sum,
        and over its sampled analytic derivative along one axis (normalised by the
        same sum). True: the continuous limits ``1 / (4 pi sigma^2)`` and
        ``1 / (8 pi sigma^4)``.

    Returns
    -------
    sum_g2 : float
        px^-2.
    sum_dg2 : float
        px^-4.

    Notes
    -----
    By Poisson summation the sampled sums differ from the continuous ones by
    aliases of relative weight about ``exp(-pi^2 sigma^2)``: measured, 2e-4 (and
    2e-3 for the derivative) at ``sigma = 1``, 2e-8 at ``sigma = 1.5`` and
    rounding only from ``sigma = 2``; the window of :func:`wft` is never
    narrower than a pitch, itself above 2 px.
    """
    s = check_positive(sigma, "sigma")
    if continuous:
        return 1 / (4 * math.pi * s**2), 1 / (8 * math.pi * s**4)
    half = math.ceil(_WINDOW_SUM_SIGMAS * s) + 1
    n = np.arange(-half, half + 1, dtype=np.float64)
    G = np.exp(-(n**2) / (2 * s**2))
    norm = G.sum()
    g = G / norm
    # the sampled derivative of the continuous Gaussian, divided by the same sum as
    # the window (the derivative transfer function of gridstrain.wft)
    dg = -n / s**2 * g
    g2 = float(np.sum(g**2))
    return g2 * g2, float(np.sum(dg**2)) * g2


def wft_noise_std(noise_variance: float, modulus: float, sigma: float) -> tuple[float, float]:
    """Phase and phase-derivative noise of the windowed Fourier transform.

    Small-noise theory for additive white noise on the image (paper §2.2, eqs.
    24-25); these are the levels the phase and derivative RMSEs of paper
    Fig. 12 converge to in ``1 / sqrt(T)``.

    Parameters
    ----------
    noise_variance : float
        Variance ``v`` of the white noise on the image, grey levels^2 (for a stack
        of ``T`` frames, :func:`effective_noise_variance`).
    modulus : float
        Fringe modulus ``|Psi|``, grey levels (:func:`grid_modulus` for eq. 1).
    sigma : float
        Standard deviation of the Gaussian window, px.

    Returns
    -------
    phase_std : float
        rad.
    derivative_std : float
        rad/px, along either axis.

    Notes
    -----
    The noise part of ``Psi``, ``sum_xi n(xi) g(xi - x) exp(-2 i pi k.xi)``, has
    ``E|n_Psi|^2 = v sum g^2`` and is circular (its pseudo-variance is ``v`` times
    the window's transfer at ``2k``, ``exp(-8 pi^2 sigma^2 |k|^2)``: 1e-34 at
    ``sigma = p``). The phase noise is its component in quadrature with ``Psi``,
    so ``Std(phi) = sqrt(v sum g^2 / 2) / |Psi|``; likewise the derivative, from
    the window's derivative, ``Std(dphi) = sqrt(v sum g'^2 / 2) / |Psi|``. First
    order in ``Std(phi)``; the sums are those of :func:`window_energy`. With the
    continuous sums: ``Std(phi) = sqrt(v / (8 pi)) / (sigma |Psi|)`` and
    ``Std(dphi) = sqrt(v / (16 pi)) / (sigma^2 |Psi|)``. Against the real
    :func:`gridstrain.phase.wft` (paper grid, pitch 5, ``sigma = 5``, white noise
    of std 30 grey levels, 600 images of 128 x 128, interior pixels; sampling
    error 0.3 %) the measured stds differ from these by -0.02 % (phase),
    -0.1 % (``d phi_1 / dx``) and -0.2 % (``d phi_1 / dy``).
    """
    v = check_nonnegative(noise_variance, "noise_variance")
    mod = check_positive(modulus, "modulus")
    g2, dg2 = window_energy(sigma)
    return math.sqrt(v * g2 / 2) / mod, math.sqrt(v * dg2 / 2) / mod


def compensated_noise_std(noise_variance: float, modulus: float, sigma: float, T: int, *,
                          frequency: float, vibration_variance: float = 0.0,
                          shift_error_variance: float = 0.0,
                          centred: bool = True) -> tuple[float, float, float]:
    """Small-noise errors of method C (vibration-compensated averaging).

    Parameters
    ----------
    noise_variance : float
        Sensor noise variance of one frame, grey levels^2 (e.g.
        :func:`effective_noise_variance` with ``T = 1``).
    modulus : float
        ``|Psi|`` of the vibration-free grid, grey levels (:func:`grid_modulus`).
    sigma : float
        Window standard deviation, px.
    T : int
        Number of frames.
    frequency : float
        ``|k|`` of the wave vector, cycles/px.
    vibration_variance : float
        ``Var(alpha)`` of the vibrations along ``k``, px^2.
    shift_error_variance : float
        Variance of the shift estimates' errors along ``k``, px^2 (about
        ``(5e-4)^2`` for :func:`gridstrain.stacks.vibration.frame_shifts` on a 256 x 256
        frame of the paper's grid, falling as the inverse of the frame's area).
    centred : bool
        True: the shifts were measured from the frames and centred (what
        :func:`gridstrain.stacks.method_c` does by default), so the weights carry
        no information on the stack's mean position ``a_bar``. False: absolute
        shifts, known from elsewhere (synthetic data), with errors
        ``shift_error_variance``.

    Returns
    -------
    phase_std : float
        Std of the phase about that of the grid at the reference position (the
        mean position if ``centred``, ``s`` otherwise), rad: sensor noise of an
        average of ``T`` frames at the contrast factor below, and for absolute
        shifts the mean of their errors, ``2 pi f sqrt(Var(e) / T)``.
    derivative_std : float
        Std of the phase derivatives, rad/px (the offsets are uniform).
    offset_std : float
        Std of the spatially uniform phase offset relative to ``s``, rad: the mean
        position ``2 pi f sqrt(Var(alpha) / T)`` if ``centred`` (exactly the offset
        of method B, :func:`phase_offset_std` with ``method="B"``), else the mean
        error ``2 pi f sqrt(Var(e) / T)``, already in ``phase_std``, and 0 is
        returned. Combine with ``phase_std`` in quadrature for the RMSE against
        ``s``.

    Notes
    -----
    Frame ``t`` weighted by ``exp(-i theta_t)``, ``theta_t = 2 pi k . (a_t -
    c + e_t)`` (``c`` = ``a_bar + e_bar`` when centred, 0 otherwise), adds its
    carrier ``d_1 exp(i 2 pi k . a_t)`` as ``d_1 exp(i 2 pi k . c) exp(-i 2 pi k .
    e_t)``. The mean over frames is the analogue of eq. (14) with ``alpha_t``
    replaced by ``-e_t``: modulus factor ``1 - 1/2 (2 pi f)^2 Var(e)``
    (Prop. 2.2), offset ``arg mean_t exp(-2 i pi k . e_t)`` (eq. 28) whose first
    order is ``-2 pi k . e_bar``, zero for centred shifts, leaving the third-order
    term ``m3 / 6``, ``m3`` the sample third central moment of ``2 pi k . e_t``,
    of variance ``(2 pi f)^6 Var(e)^3 (T - 1)(T - 2) / (6 T^3)`` for Gaussian
    errors (zero for one or two frames; Prop. 2.4's analogue). The noise
    ``(1/T) sum_t exp(-i theta_t) n_t`` has the variance ``v / T`` of method A's
    (Prop. 2.3) and is circular, so eqs. (24)-(25) apply with the full modulus.
    The shift estimates' errors are global (one number per frame) and add no
    spatial noise; their correlation with the local noise of a window is of the
    order of the window's share of the frame's area. First order in the sensor
    noise, as :func:`wft_noise_std`.
    """
    v = check_nonnegative(noise_variance, "noise_variance")
    n = check_int(T, "T")
    f = check_frequency(frequency)
    var_a = check_nonnegative(vibration_variance, "vibration_variance")
    var_e = check_nonnegative(shift_error_variance, "shift_error_variance")
    w = 2 * np.pi * f
    contrast = 1.0 - 0.5 * w**2 * var_e  # eq. (14) with alpha_t -> -e_t
    if contrast <= 0:
        raise ValueError(f"shift_error_variance must be below 2 / (2 pi f)^2 = "
                         f"{2 / w**2:.4g} px^2, got {shift_error_variance!r}")
    mod = check_positive(modulus, "modulus") * contrast
    p_std, d_std = wft_noise_std(v / n, mod, sigma)  # Prop. 2.3 and eqs. (24)-(25)
    if centred:
        # Var(m3) = 6 s^6 (T-1)(T-2) / T^3 for a Gaussian sample, divided by 6^2
        third = math.sqrt(w**6 * var_e**3 * (n - 1) * (n - 2) / (6 * n**3))
        return math.hypot(p_std, third), d_std, float(w * math.sqrt(var_a / n))
    return math.hypot(p_std, w * math.sqrt(var_e / n)), d_std, 0.0


def grid_modulus(amplitude: float, contrast: float, *, profile="sin3") -> float:
    """Fringe modulus ``|Psi| = A/2 gamma |d_1|`` of an eq. (1) grid.

    Parameters
    ----------
    amplitude : float
        ``A``, mean grey level.
    contrast : float
        ``gamma``, in [0, 1].
    profile : str or callable
        Line profile (see :func:`profile_coefficients`).

    Returns
    -------
    float
        Grey levels: the modulus :func:`gridstrain.phase.wft` measures on the
        noise-free, vibration-free grid (``A/2 * 0.9 * 3/16 = 0.084 A`` for the
        paper's grid). An averaged stack multiplies it by :func:`contrast_factor`.
    """
    A = check_positive(amplitude, "amplitude")
    gamma = check_range(contrast, "contrast", 0.0, 1.0, include_low=False)
    d = profile_coefficients(profile, n_harmonics=1)
    return float(A / 2 * gamma * abs(d[2]))


def effective_noise_variance(K: float, L: float, mean_level: float, *, T: int = 1) -> float:
    """Noise variance of an average of ``T`` frames, ``(K mean + L) / T`` (Prop. 2.3).

    Parameters
    ----------
    K : float
        Gain of the Poisson-Gaussian model ``Var = K l + L``, grey levels.
    L : float
        Signal-independent variance, grey levels^2.
    mean_level : float
        Mean grey level ``l`` of the image (``A`` for eq. 1), grey levels.
    T : int
        Number of frames averaged.

    Returns
    -------
    float
        Grey levels^2.

    Notes
    -----
    Eq. (19) with the heteroscedastic variance ``K s + L`` replaced by its mean:
    the windowed Fourier transform sums the noise over a window holding several
    periods, so ``E|n_Psi|^2 = sum g^2 (K s + L)`` is ``(K mean + L) sum g^2``
    up to the window's transfer at ``k`` (5e-5 at ``sigma = p``). The noise is
    then circular only if the profile has no second harmonic (true of ``sin``
    and ``sin^3``); otherwise the phase noise depends weakly on the phase.
    Vibrations change the mean by second-order terms of zero spatial mean
    (eq. 20). Eq. (20) as printed has ``L / T^2``; the correct term is ``L / T``.
    """
    k = check_nonnegative(K, "K")
    ell = check_nonnegative(L, "L")
    m = check_nonnegative(mean_level, "mean_level")
    n = check_int(T, "T")
    return (k * m + ell) / n  # eq. (19)


def displacement_noise_std(phase_std_ref, phase_std_def, lattice: Lattice) -> np.ndarray:
    """Std of the displacement from independent phase noise (eq. 34).

    Parameters
    ----------
    phase_std_ref, phase_std_def : float or (2,) array_like
        Phase noise std of the reference and deformed images, rad, one value or one
        per wave vector.
    lattice : Lattice
        Wave vectors, cycles/px.

    Returns
    -------
    (2,) ndarray
        Std of ``(u_x, u_y)``, px, for ``u = -(1/2 pi) K^-1 (phi_def - phi_ref)``
        (:mod:`gridstrain.conventions`), all four phase maps independent. For the
        axis-aligned grid ``Std(u_x) = p / (2 pi) sqrt(s_ref^2 + s_def^2)``.
    """
    lattice = check_type(lattice, "lattice", Lattice)
    r = _check_stds(phase_std_ref, "phase_std_ref", (2,))
    d = _check_stds(phase_std_def, "phase_std_def", (2,))
    M = np.linalg.inv(lattice.K) / (2 * np.pi)
    return np.sqrt((M**2) @ (r**2 + d**2))


def strain_noise_std(deriv_std_ref, deriv_std_def, lattice: Lattice) -> np.ndarray:
    """Std of the strain from independent phase-derivative noise (eq. 35).

    Parameters
    ----------
    deriv_std_ref, deriv_std_def : float, (2,) or (2, 2) array_like
        Phase-derivative noise std of the reference and deformed images, rad/px:
        one value, one per wave vector (both directions), or ``[j, m]`` for
        ``d phi_j / d x_m``.
    lattice : Lattice
        Wave vectors, cycles/px.

    Returns
    -------
    (3,) ndarray
        Std of ``(eps_xx, eps_yy, eps_xy)`` (tensor shear), dimensionless, for
        ``G = -(1/2 pi) K^-1 (D_def - D_ref)`` with ``D[j, m] = d phi_j / d x_m``
        and ``eps`` its symmetric part (:mod:`gridstrain.conventions`), all
        derivative maps independent (at one pixel ``d/dx`` and ``d/dy`` of a
        phase are uncorrelated since ``sum g g' = 0``). For the axis-aligned grid
        ``Std(eps_xx) = p / (2 pi) sqrt(s_ref^2 + s_def^2)`` and
        ``Std(eps_xy)`` is that divided by ``sqrt(2)``.
    """
    lattice = check_type(lattice, "lattice", Lattice)
    r = _check_stds(deriv_std_ref, "deriv_std_ref", (2, 2))
    d = _check_stds(deriv_std_def, "deriv_std_def", (2, 2))
    V = r**2 + d**2  # Var of Delta D[j, m]
    M = np.linalg.inv(lattice.K) / (2 * np.pi)  # G[i, m] = -sum_j M[i, j] dD[j, m]
    var_G = (M**2) @ V  # [i, m]
    var_xy = 0.25 * ((M[0] ** 2) @ V[:, 1] + (M[1] ** 2) @ V[:, 0])
    return np.sqrt(np.array([var_G[0, 0], var_G[1, 1], var_xy]))
