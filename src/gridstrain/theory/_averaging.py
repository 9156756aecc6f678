"""The paper's closed forms of averaging a vibrated stack: the line profiles' Fourier
coefficients and their contrast after averaging (eq. 14), the mean image's bias (Prop.
2.1) and the phase offset the vibrations leave (eqs. 28-31). Described in
:mod:`gridstrain.theory`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import fft as sfft

from .._validation import (
    as_float_array,
    as_image,
    as_shifts,
    check_choice,
    check_finite,
    check_fraction,
    check_frequency,
    check_int,
    check_nonnegative,
    check_positive,
    check_shape,
    check_type,
)
from ..models import line_profile
from ..phase import Lattice

# Samples per period used to compute a profile's Fourier coefficients (at least this
# many, and at least 16 per retained harmonic): the profiles of gridstrain.models.synthetic
# are analytic, so the aliasing error of the FFT falls geometrically with this number
# and is below 1e-15 for all of them at 1024.
_MIN_PROFILE_SAMPLES = 1024
# Largest number of harmonics worth asking for: beyond it the coefficients of any
# profile a camera can resolve are rounding noise.
_MAX_HARMONICS = 4096
# The discrete window sums run over |n| <= this many sigmas (plus one sample): the
# neglected tail of g^2 weighs exp(-12^2) relative to its peak.
_WINDOW_SUM_SIGMAS = 12.0


# --------------------------------------------------------------------------- checks

def _check_cov(cov) -> np.ndarray:
    """A 2x2 symmetric positive semi-definite covariance of (alpha, beta), px^2."""
    c = as_float_array(cov, "cov", dtype=np.float64)
    if c.shape != (2, 2):
        raise ValueError(f"cov must be the 2x2 covariance [[Var alpha, Cov], [Cov, Var beta]] "
                         f"in px^2, got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("cov must be finite")
    scale = float(np.max(np.abs(c)))
    if abs(c[0, 1] - c[1, 0]) > 1e-12 * scale:
        raise ValueError(f"cov must be symmetric, got Cov(alpha, beta) = {c[0, 1]!r} and "
                         f"{c[1, 0]!r}")
    c = 0.5 * (c + c.T)
    if c[0, 0] < 0 or c[1, 1] < 0 or np.linalg.eigvalsh(c)[0] < -1e-12 * scale:
        raise ValueError(f"cov must be positive semi-definite (a covariance), got "
                         f"eigenvalues {np.linalg.eigvalsh(c).tolist()}")
    return c


def _check_stds(value, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A non-negative std broadcast to ``shape`` (scalar, per wave vector, or full)."""
    a = as_float_array(value, name, dtype=np.float64)
    if a.ndim == 1 and len(shape) == 2 and a.shape == (shape[0],):
        a = a[:, None]  # one value per wave vector, for both derivative directions
    try:
        a = np.broadcast_to(a, shape)
    except ValueError:
        raise ValueError(f"{name} must be a scalar or have shape {shape} (or (2,) per wave "
                         f"vector), got shape {np.shape(value)}") from None
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name} must be finite and non-negative, got {np.asarray(value)!r}")
    return a


# ------------------------------------------------------------------- line profiles

def profile_coefficients(profile="sin3", *, n_harmonics: int = 16) -> np.ndarray:
    """Fourier coefficients ``d_k`` of a 2 pi-periodic line profile.

    ``l(t) = sum_k d_k exp(i k t)`` (paper §2.1, below eq. 12).

    Parameters
    ----------
    profile : str or callable
        A name in :data:`gridstrain.models.synthetic.PROFILES` or a vectorised callable
        ``l(t)`` of the phase ``t`` (rad), 2 pi-periodic, returning real values
        (dimensionless; eq. 1 wants zero mean and a peak-to-peak of 1).
    n_harmonics : int
        Largest harmonic ``n`` returned.

    Returns
    -------
    (2 n + 1,) complex ndarray
        ``d_k`` for ``k = -n, ..., n`` (``d[n + k]``), dimensionless. For a real
        profile ``d_-k = conj(d_k)``.

    Notes
    -----
    Computed by the FFT of at least 1024 samples per period (16 per harmonic for
    large ``n``), so the result is exact to rounding for band-limited profiles and
    aliasing-limited otherwise. For ``l = sin^3 / 2``, ``d_+-1 = -+3i/16`` and
    ``d_+-3 = +-i/16``.

    Examples
    --------
    >>> d = profile_coefficients("sin3", n_harmonics=3)
    >>> bool(np.isclose(d[3 + 1], -3j / 16))
    True
    """
    n = check_int(n_harmonics, "n_harmonics")
    if n > _MAX_HARMONICS:
        raise ValueError(f"n_harmonics must be at most {_MAX_HARMONICS}, got {n_harmonics!r}")
    ell = line_profile(profile)
    N = max(_MIN_PROFILE_SAMPLES, 1 << (16 * n - 1).bit_length())
    t = 2 * np.pi * np.arange(N) / N
    values = np.asarray(ell(t))
    if values.shape != t.shape or not np.isrealobj(values):
        raise ValueError(f"profile must return a real array of the shape of its input "
                         f"{t.shape}, got {values.dtype} of shape {values.shape}")
    if not np.all(np.isfinite(values)):
        raise ValueError("profile must return finite values")
    spec = sfft.fft(values.astype(np.float64)) / N
    return spec[np.arange(-n, n + 1) % N]


def _harmonics(d: np.ndarray) -> np.ndarray:
    n = (d.size - 1) // 2
    return np.arange(-n, n + 1)


def _check_coefficients(d) -> np.ndarray:
    c = np.asarray(d)
    if c.ndim != 1 or c.size % 2 != 1 or not np.issubdtype(c.dtype, np.number):
        raise ValueError(f"d must be a 1-D array of 2n+1 coefficients d_-n..d_n, got shape "
                         f"{c.shape} and dtype {c.dtype}")
    c = c.astype(complex)
    if not np.all(np.isfinite(c)):
        raise ValueError("d must be finite")
    return c


def averaged_profile_coefficients(d, frequency: float, mean: float,
                                  mean_square: float) -> np.ndarray:
    """Fourier coefficients of the line profile of an averaged grid (Prop. 2.2).

    Parameters
    ----------
    d : (2 n + 1,) array_like
        ``d_k`` of the reference profile, ``k = -n..n`` (see
        :func:`profile_coefficients`).
    frequency : float
        Carrier frequency ``f`` of the family of lines, cycles/px.
    mean : float
        ``mean_t(alpha_t)``, the sample mean of the shifts across the lines, px.
    mean_square : float
        ``mean_t(alpha_t^2)``, their sample mean square (not centred), px^2.

    Returns
    -------
    (2 n + 1,) complex ndarray
        ``(1 + i 2 pi f k mean - 1/2 (2 pi f)^2 k^2 mean_square) d_k``, eq. (14).

    Notes
    -----
    This is the second-order Taylor expansion (eq. 3) of the exact coefficient
    ``mean_t(exp(i 2 pi f k alpha_t)) d_k``; the difference is at most
    ``mean_t(|2 pi f k alpha_t|^3) / 6 * |d_k|``, so the expansion degrades on
    high harmonics first. For Gaussian shifts of ``Std(alpha) = 0.15`` px at
    ``f = 1/5`` (the paper's case 1) this bound is 0.2 % of ``|d_1|`` but 5 % of
    ``|d_3|``; for many frames eq. (14) multiplies ``d_3`` by 0.840 where the exact
    factor is ``exp(-1/2 (3 * 2 pi f)^2 Var(alpha)) = 0.852``.
    """
    c = _check_coefficients(d)
    f = check_frequency(frequency)
    m1 = check_finite(mean, "mean")
    m2 = check_nonnegative(mean_square, "mean_square")
    w = 2 * np.pi * f * _harmonics(c)
    return (1 + 1j * w * m1 - 0.5 * w**2 * m2) * c  # eq. (14)


def contrast_factor(frequency: float, variance: float) -> float:
    """Large-T factor on the fundamental's modulus, ``1 - 1/2 (2 pi f)^2 Var(alpha)``.

    Parameters
    ----------
    frequency : float
        Carrier frequency ``f``, cycles/px.
    variance : float
        ``Var(alpha)``, variance of the shifts along the wave vector, px^2.

    Returns
    -------
    float
        Dimensionless; ``|d_1|`` of the averaged grid over ``|d_1|`` (paper §2.2,
        eq. 14 with ``mean(alpha) = 0``, ``mean(alpha^2) = Var(alpha)``). The
        window's modulus ``|Psi|``, hence the phase noise, scales with it.

    Notes
    -----
    Second order. For Gaussian shifts the exact large-T factor is
    ``exp(-1/2 (2 pi f)^2 Var(alpha))``; at ``f = 1/5`` and ``Std(alpha) =
    0.15`` px the two are 0.9822 and 0.9824.
    """
    f = check_frequency(frequency)
    var = check_nonnegative(variance, "variance")
    return 1.0 - 0.5 * (2 * np.pi * f) ** 2 * var


def exact_contrast_factor(frequency: float, alphas) -> float:
    """Exact factor on the fundamental's modulus for given shifts, ``|mean exp(2i pi f alpha_t)|``.

    Parameters
    ----------
    frequency : float
        Carrier frequency ``f``, cycles/px.
    alphas : (T,) array_like
        Shifts across the lines, px.

    Returns
    -------
    float
        Dimensionless, in [0, 1].
    """
    f = check_frequency(frequency)
    a = as_shifts(alphas, "alphas", ndim=1)
    return float(abs(np.mean(np.exp(2j * np.pi * f * a))))


# -------------------------------------------------------------- Prop. 2.1: image bias

def mean_image_bias(image, cov, *, exact: bool = False) -> np.ndarray:
    """Bias of the expected averaged image, ``E(v_bar) - s`` (Prop. 2.1).

    Parameters
    ----------
    image : (H, W) array_like
        The vibration-free image ``s``, grey levels. Not modified.
    cov : (2, 2) array_like
        Covariance ``[[Var alpha, Cov], [Cov, Var beta]]`` of the shifts, px^2
        (``x`` first, :mod:`gridstrain.conventions`).
    exact : bool
        False: Prop. 2.1, ``1/2 div(cov grad s)`` (eq. 6), second order in the
        shifts. True: the exact expectation for Gaussian shifts, the convolution
        of ``s`` with the Gaussian of covariance ``cov``, minus ``s``.

    Returns
    -------
    (H, W) ndarray
        Grey levels; float32 for float32 input, float64 otherwise.

    Notes
    -----
    The derivatives are spectral (FFT), so the image is taken as periodic and
    band-limited: exact for an image holding a whole number of periods with no
    content above the Nyquist frequency. An eq. (1) grid generally is not: the
    ``sin^3`` grid of pitch 5 px has its third harmonic at 0.6 cycles/px, which
    the sampled image shows aliased at 0.4 cycles/px, and a shift moves it by
    ``2 pi 0.6 alpha``, not ``-2 pi 0.4 alpha``. Use :func:`grid_mean_image_bias`
    for such images. At the Nyquist frequency the mixed derivative is ambiguous;
    the real part taken here sets it to zero.
    """
    img = as_image(image, allow_uniform=True)
    c = _check_cov(cov)
    exact = bool(exact)
    H, W = img.shape
    nu_y = sfft.fftfreq(H)[:, None]
    nu_x = sfft.fftfreq(W)[None, :]
    # the quadratic form nu^T C nu of eqs. (5)-(6) in the Fourier domain
    q = c[0, 0] * nu_x**2 + 2 * c[0, 1] * nu_x * nu_y + c[1, 1] * nu_y**2
    mult = np.expm1(-2 * np.pi**2 * q) if exact else -2 * np.pi**2 * q
    spec = sfft.fft2(img)
    out = sfft.ifft2(spec * mult.astype(img.dtype)).real
    return out.astype(img.dtype, copy=False)


def _family_terms(lattice: Lattice, cov: np.ndarray, d: np.ndarray, exact: bool):
    """Per wave vector, the multipliers of d_k in the bias of an eq. (1) grid."""
    k = _harmonics(d)
    out = []
    for kj in (lattice.k1, lattice.k2):
        kv = np.asarray(kj)
        # (2 pi)^2 k_j^T C k_j: variance of the phase shift 2 pi k_j . a_t, rad^2
        q = (2 * np.pi) ** 2 * float(kv @ cov @ kv)
        # eqs. (10)-(12): 1/2 tr(C H_s) on l(t_j) multiplies d_k by -1/2 k^2 q
        mult = np.expm1(-0.5 * k**2 * q) if exact else -0.5 * k**2 * q
        out.append(mult * d)
    return out


def _grid_terms(lattice, cov, amplitude, contrast, profile, n_harmonics, exact):
    """Checked eq. (1) grid parameters and each family's bias coefficients."""
    lattice = check_type(lattice, "lattice", Lattice)
    c = _check_cov(cov)
    A = check_positive(amplitude, "amplitude")
    gamma = check_fraction(contrast, "contrast")
    d = profile_coefficients(profile, n_harmonics=n_harmonics)
    return lattice, A, gamma, d, _family_terms(lattice, c, d, bool(exact))


def grid_mean_image_bias(shape, lattice: Lattice, cov, *, amplitude: float = 1.0,
                         contrast: float = 0.9, profile="sin3", exact: bool = False,
                         n_harmonics: int = 16, dtype=np.float64) -> np.ndarray:
    """Prop. 2.1 evaluated analytically for the eq. (1) grid of :func:`grid_image`.

    Parameters
    ----------
    shape : (int, int)
        ``(H, W)``.
    lattice : Lattice
        Wave vectors of the grid (any two, not only the paper's axis-aligned pair).
    cov : (2, 2) array_like
        Covariance of the shifts ``(alpha, beta)``, px^2, ``x`` first.
    amplitude, contrast, profile
        ``A``, ``gamma`` and ``l`` of eq. (1), as in
        :func:`gridstrain.models.synthetic.grid_image` (``kind="grid"``, no phase
        modulation, point sampling).
    exact : bool
        False: Prop. 2.1 (second order). True: the exact expectation for Gaussian
        shifts, in which the harmonic ``k`` of family ``j`` is multiplied by
        ``exp(-1/2 k^2 (2 pi)^2 k_j^T C k_j) - 1``.
    n_harmonics : int
        Harmonics of the profile kept (see :func:`profile_coefficients`).
    dtype : dtype
        Output dtype.

    Returns
    -------
    (H, W) ndarray
        ``E(v_bar) - s``, grey levels.

    Notes
    -----
    With ``t_j = 2 pi k_j . x`` the Hessian of eq. (1) is
    ``A gamma / 2 sum_j (2 pi)^2 k_j k_j^T l''(t_j)`` (eqs. 10-12 for any lattice),
    so ``1/2 tr(C H_s) = A gamma / 4 sum_j (2 pi)^2 (k_j^T C k_j) l''(t_j)`` with
    ``l'' = -sum_k k^2 d_k exp(i k t)``. Evaluated from the harmonics of the
    continuous profile, it is right where the spectral :func:`mean_image_bias` of
    a sampled image is wrong: for harmonics above the Nyquist frequency. Phase
    modulations are left out; eqs. (8)-(12) neglect their gradients anyway.
    """
    H, W = check_shape(shape)
    lattice, A, gamma, d, terms = _grid_terms(lattice, cov, amplitude, contrast, profile,
                                              n_harmonics, exact)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    k = _harmonics(d)
    out = np.zeros((H, W))
    for kj, b in zip((lattice.k1, lattice.k2), terms, strict=True):
        t = 2 * np.pi * (kj[0] * xx + kj[1] * yy)
        # the series is real (b_-k = conj b_k): sum the k > 0 half twice
        for m, bm in zip(k, b, strict=True):
            if m > 0 and abs(bm) > 0:
                out += 2 * (bm * np.exp(1j * m * t)).real
    return (A / 2 * gamma * out).astype(dtype)


def mean_image_bias_rms(lattice: Lattice, cov, *, amplitude: float = 1.0,
                        contrast: float = 0.9, profile="sin3", exact: bool = False,
                        shape=None, n_harmonics: int = 16) -> float:
    """RMS over the image of the bias of Prop. 2.1 for an eq. (1) grid.

    The RMSE between an averaged stack and the vibration-free grid (paper
    Fig. 5c) levels off at this value as the number of frames grows.

    Parameters
    ----------
    lattice, cov, amplitude, contrast, profile, exact, n_harmonics
        As in :func:`grid_mean_image_bias`.
    shape : (int, int), optional
        If given, the RMS of :func:`grid_mean_image_bias` over this image (pixel
        sampling included). Default: the limit over many periods,
        ``A gamma / 2 * sqrt(sum_j sum_k |b_jk|^2)`` with ``b_jk`` the bias
        multipliers of :func:`grid_mean_image_bias` times ``d_k``: distinct
        harmonics are orthogonal and the two families are not parallel.

    Returns
    -------
    float
        Grey levels.

    Notes
    -----
    For the paper's synthetic data (``A = 2^12``, ``gamma = 0.9``, pitch 5,
    ``sin^3``) Prop. 2.1 gives 30.0 grey levels in case 1 (``Std = (0.15, 0.1)``
    px), 12.6 in case 2 (``(0.1, 0.05)``), 0.17 in case 3 and 0.031 in case 4;
    the exact Gaussian expectation (``exact=True``) gives 28.2 and 12.2 in cases
    1 and 2. The second-order theory overestimates the level by 7 % in case 1
    because most of ``l''`` is in the third harmonic, whose phase shift
    ``3 * 2 pi f alpha`` is then no longer small.
    """
    if shape is not None:
        b = grid_mean_image_bias(shape, lattice, cov, amplitude=amplitude,
                                 contrast=contrast, profile=profile, exact=exact,
                                 n_harmonics=n_harmonics)
        return float(np.sqrt(np.mean(b**2)))
    lattice, A, gamma, _d, terms = _grid_terms(lattice, cov, amplitude, contrast, profile,
                                               n_harmonics, exact)
    return float(A / 2 * gamma * math.sqrt(sum(float(np.sum(np.abs(b) ** 2)) for b in terms)))


# ------------------------------------------------------- eqs. (28)-(31): phase offset

def _offset(theta: np.ndarray, exact: bool, method: str) -> np.ndarray:
    """Phase offset from per-frame phase shifts ``theta`` (T, ...) in rad."""
    if method == "A":
        if exact:
            # argument of the averaged image's fundamental, mean_t exp(i theta_t) d_1
            return np.angle(np.mean(np.exp(1j * theta), axis=0))
        m1 = np.mean(theta, axis=0)
        m2 = np.mean(theta**2, axis=0)
        # eq. (28); arctan2 equals eq. (29)'s arctan while its denominator is
        # positive, i.e. for any RMS shift below 0.225 pitch
        return np.arctan2(m1, 1 - 0.5 * m2)
    if exact:
        # a single shifted frame turns the phase by exactly theta_t (wrapped)
        return np.mean(np.angle(np.exp(1j * theta)), axis=0)
    # §2.3: the mean of eq. (29) applied to each frame
    return np.mean(np.arctan2(theta, 1 - 0.5 * theta**2), axis=0)


def phase_offset(shifts, frequency: float, *, exact: bool = False,
                 method: str = "A") -> float:
    """Phase offset ``delta`` caused by vibrations along one wave vector (eqs. 28-30).

    Parameters
    ----------
    shifts : (T,) array_like
        ``alpha_t``, the shift of each frame along the wave vector's direction, px,
        with frame ``t`` equal to ``s(x + alpha_t)`` (paper eq. 2; the specimen is
        displaced by ``-alpha_t``).
    frequency : float
        Carrier frequency ``f = 1/p`` of the family of lines, cycles/px.
    exact : bool
        False: the paper's second-order formula. True: the exact offset.
    method : {"A", "B"}
        "A": the offset of the phase of the averaged image,
        ``delta = arctan(2 pi f mean(alpha) / (1 - 1/2 (2 pi f)^2 mean(alpha^2)))``
        (eq. 29) or, exact, ``arg mean_t exp(2 i pi f alpha_t)``.
        "B": the offset of the mean of the per-frame phases (§2.3),
        ``mean_t arctan(2 pi f alpha_t / (1 - 1/2 (2 pi f alpha_t)^2))`` or, exact,
        ``mean_t 2 pi f alpha_t`` (each wrapped to (-pi, pi]).

    Returns
    -------
    float
        ``delta``, rad, such that ``arg Psi(v_bar) = arg Psi(s) + delta`` (eq. 26):
        shifting a frame by ``+alpha`` raises the phase the windowed Fourier
        transform of :func:`gridstrain.phase.wft` measures by ``+2 pi f alpha``.
        Subtract it to correct the phase.

    Notes
    -----
    Eq. (29) is second order: it replaces ``mean exp(i theta_t)``, ``theta_t =
    2 pi f alpha_t``, by ``1 + i mean(theta) - mean(theta^2) / 2``. The leading
    error is ``mean(theta^3) / 6``, zero-mean with standard deviation
    ``sqrt(15) / 6 (2 pi f Std(alpha))^3 / sqrt(T)`` for Gaussian shifts. A Monte
    Carlo (20 000 stacks, T = 1 to 1000, f = 1/5) gives an RMS of
    ``delta_eq29 - delta_exact`` of ``0.0044 / sqrt(T)`` rad in case 1
    (``Std(alpha) = 0.15`` px, 2.3 % of ``Std(delta)``), ``0.0013 / sqrt(T)``
    at 0.1 px (1.0 %), ``1.6e-4 / sqrt(T)`` at 0.05 px (0.25 %) and
    ``1.3e-6 / sqrt(T)`` at 0.01 px: after correcting with eq. (29), case 1
    keeps a residual of 3e-4 rad at T = 200, as large as the sensor-noise floor
    of the phase there (2.8e-4 rad for the paper's grid and camera, from
    :func:`effective_noise_variance` and :func:`wft_noise_std`), as the paper
    observes.

    Examples
    --------
    >>> round(phase_offset([0.1], 0.2, exact=True), 6)  # 2 pi * 0.2 * 0.1
    0.125664
    """
    a = as_shifts(shifts, "shifts", ndim=1)
    f = check_frequency(frequency)
    check_choice(method, "method", ("A", "B"))
    return float(_offset(2 * np.pi * f * a, bool(exact), method))


def phase_offsets(shifts_xy, lattice: Lattice, *, exact: bool = False,
                  method: str = "A") -> np.ndarray:
    """Phase offsets of both wave vectors for 2-D vibrations, any lattice.

    Parameters
    ----------
    shifts_xy : (T, 2) array_like
        ``(alpha_t, beta_t)`` per frame, px, ``x`` first; frame ``t`` is
        ``s(x + alpha_t, y + beta_t)``.
    lattice : Lattice
        The grid's wave vectors ``k_j``, cycles/px.
    exact, method
        As in :func:`phase_offset`.

    Returns
    -------
    (2,) ndarray
        ``(delta_1, delta_2)``, rad: :func:`phase_offset` with ``2 pi f alpha_t``
        replaced by the phase shift ``2 pi k_j . (alpha_t, beta_t)``.
    """
    a = as_shifts(shifts_xy, "shifts_xy", ndim=2)
    lattice = check_type(lattice, "lattice", Lattice)
    check_choice(method, "method", ("A", "B"))
    theta = 2 * np.pi * a @ lattice.K.T  # (T, 2): 2 pi k_j . a_t
    return _offset(theta, bool(exact), method)


def phase_offset_std(frequency: float, variance: float, T: int, *,
                     method: str = "A") -> float:
    """Standard deviation of the vibration phase offset over stacks (Prop. 2.4).

    Parameters
    ----------
    frequency : float
        Carrier frequency ``f``, cycles/px.
    variance : float
        ``Var(alpha)`` of the shifts along the wave vector, px^2 (for a general
        lattice, ``k^T C k / |k|^2``).
    T : int
        Number of frames averaged.
    method : {"A", "B"}
        "A": the offset of the averaged image, eq. (31),
        ``2 pi f / (1 - 1/2 (2 pi f)^2 Var(alpha)) * sqrt(Var(alpha) / T)``.
        "B": the mean of the per-frame offsets (§2.3),
        ``2 pi f sqrt(Var(alpha) / T)``.

    Returns
    -------
    float
        rad.

    Notes
    -----
    ``Var(mean(alpha)) = Var(alpha) / T`` is used in eq. (31); the paper's example
    uses ``2 Var(alpha)^2 / (T - 1)``, the variance of the sample variance (see
    the module docstring). At ``f = 1/5`` and ``Std(alpha) = 0.05`` px the result
    is ``0.063 / sqrt(T)`` rad. A Monte Carlo of 100 000 stacks of T = 25
    Gaussian shifts at ``f = 1/5`` (sampling error 0.2 %) gives, relative to the
    formula: at ``Std(alpha) = 0.05`` px, +0.2 % for eq. (29), 0.0 % for the exact
    offset, +0.2 % (B, exact) and +0.4 % (B, per-frame eq. 29); at 0.15 px (case
    1), -0.1 % for eq. (29) but -1.9 % for the exact offset (the delta method is
    first order), and +1.6 % for method B with per-frame eq. (29), whose
    ``arctan(theta / (1 - theta^2 / 2)) = theta + theta^3 / 6 + ...`` overshoots.
    The same holds at T = 200. ``tests/test_theory.py`` checks the 0.05 px case
    with 10 000 stacks.
    """
    f = check_frequency(frequency)
    var = check_nonnegative(variance, "variance")
    n = check_int(T, "T")
    check_choice(method, "method", ("A", "B"))
    w = 2 * np.pi * f
    if method == "B":
        return float(w * math.sqrt(var / n))
    den = 1 - 0.5 * w**2 * var
    if den <= 0:
        raise ValueError(f"variance must be below 2 / (2 pi f)^2 = {2 / w**2:.4g} px^2 for "
                         f"eq. (31) to hold, got {variance!r}")
    return float(w / den * math.sqrt(var / n))  # eq. (31), Var(mean alpha) = Var / T



