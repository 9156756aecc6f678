"""Sensor noise: the Poisson-Gaussian model, its estimation from a static stack, and
the generalised Anscombe transform.

The noise of a linear camera is Poisson-Gaussian: a pixel of expected grey level
``l`` has variance ``Var = K l + L`` (paper §2.1, Prop. 2.3), ``K`` the gain in grey
levels per electron and ``L`` the signal-independent variance (read noise, dark
current, quantisation ``step^2 / 12``, minus ``K`` times any black-level offset).
Coordinates follow :mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg, special

from .._progress import Progress, null_progress
from .._validation import (
    as_float_array,
    as_shifts,
    check_finite,
    check_int,
    check_positive,
    check_type,
)
from ..phase import Lattice, detect_lattice
from ..stacks import MOTION_TERMS, motion_regressors, nested_motion_fits, pick_motion_fit
from ..stacks.vibration import CarrierProbe, as_frame, numbered_frames, streaming_shift

__all__ = ["NOISE_RESULT_KIND", "NoiseModel", "anscombe", "estimate_noise", "inverse_anscombe"]

#: ``result_kind`` attribute of the files ``gridstrain noise`` writes, by which
#: ``gridstrain measure --noise`` recognises them.
NOISE_RESULT_KIND = "gridstrain noise model"

# Tail probabilities beyond which a pixel's residual variance is rejected as an
# outlier (chi-square test against the current model). Contamination is nearly
# always excess variance (hot pixels, dust, flicker, unmodelled motion), so the
# upper cut is tight: at 1e-3, with T = 50 and 40 degrees of freedom, a pixel with
# three times the model's variance is rejected 97 % of the time (twice: 62 %; at
# T = 200, 99.98 %), an honest pixel one time in a thousand. Stuck pixels sit near
# zero, far below the loose lower cut. The bias the truncation puts on the kept
# variances is removed exactly (see _bin_stats).
_OUTLIER_LOW = 1e-5
_OUTLIER_HIGH = 1e-3
# A pixel is kept only if its highest fitted level (over the frames) stays this many
# noise standard deviations below saturation: its samples then reach the clip with
# probability below 3e-7 each, so clipping changes its variance by less than 1e-5.
# The test uses the fitted values, which for Gaussian noise are independent of the
# residuals; a test on the pixel's own sample spread or maximum would keep the
# pixels that happened to draw a low variance and bias K low and L high (measured:
# about -0.3 % and +2 grey levels^2 with 4 % of the pixels clipping).
_SATURATION_SIGMAS = 5.0
# Fewer pixels than this per intensity bin make the bin mean too noisy to be
# weighted by its theoretical variance (and the outlier test too coarse).
_MIN_PER_BIN = 20
# Frames are buffered up to this many bytes (and at most 16 frames) so that the
# accumulation is one matrix product per buffer instead of one pass per regressor.
_BUFFER_BYTES = 64 * 2**20
# Two-sided 95 % normal quantile, for the confidence intervals.
_Z95 = 1.959963984540054  # the 97.5 % quantile of the normal distribution
_Q75 = 0.6744897501960817  # the 75 % quantile of the normal distribution: MAD / std


def _chi2_ppf(p, dof):
    """Quantile ``p`` of the chi-square law with ``dof`` degrees of freedom (as
    ``scipy.stats.chi2.ppf``, from scipy.special: scipy.stats takes longer to
    import than a pair takes to measure)."""
    return 2.0 * special.gammaincinv(0.5 * dof, p)


def anscombe(image, *, K: float, L: float) -> np.ndarray:
    """Generalised Anscombe transform: Poisson-Gaussian noise to unit variance.

    Parameters
    ----------
    image : array_like
        Grey levels (any shape), in the units of ``K`` and ``L``. Not modified.
    K : float
        Slope of the noise model ``Var = K l + L``, grey levels.
    L : float
        Intercept of the noise model, grey levels squared (may be negative when the
        black level is offset).

    Returns
    -------
    ndarray
        ``f(z) = (2 / K) sqrt(max(K z + 3 K^2 / 8 + L, 0))``, dimensionless, same
        shape; float32 input gives float32, anything else float64.

    Notes
    -----
    With ``z = K p + o + n``, ``p`` Poisson of mean ``lambda``, ``n`` normal of
    variance ``s^2`` and ``o`` a black-level offset, the transform is
    ``2 sqrt(zt + 3/8 + st^2)`` of the normalised ``zt = (z - o) / K`` and
    ``st = s / K`` [1]_: the offset only enters through ``L = s^2 - K o``, so the
    two parameters of ``Var = K l + L`` are all it needs. Its derivative is
    ``1 / sqrt(K z + 3 K^2/8 + L)``, hence ``Var f(z) ~ (K l + L) / (K l + L +
    3 K^2 / 8)``: unity to better than ``3 K / (8 l)`` (1e-4 for the paper's camera
    at ``l = 1000``). The paper applies it before the windowed Fourier transform so
    that the phase noise follows the homoscedastic law (§2.2, ref. [10]).

    gridstrain does not stabilise images before the transform, and offers no
    option to: its uncertainty maps (:mod:`gridstrain.uncertainty`) take the
    signal-dependent noise into account pixel by pixel, and on pixel data the
    square root is harmful. It distorts the line profile, and the harmonics it
    creates alias onto the carrier: on noise-free grids of 12-bit levels a rigid
    translation of 0.3 px comes out 7e-3 px short at pitch 5 (the 4th and 6th
    harmonics land on -k and +k), and at pitch 5.3 the strain of a rigid motion
    reaches 6e-4 (``tests/test_uncertainty.py``). Use the transform for noise
    analysis and denoising, not ahead of a phase measurement.

    References
    ----------
    .. [1] F. Murtagh, J.-L. Starck, A. Bijaoui, "Image restoration with noise
       suppression using a multiresolution support", Astron. Astrophys. Suppl. Ser.
       112 (1995) 179-189.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> z = 0.28 * rng.poisson(2000 / 0.28, 100_000) + rng.normal(0, 5 ** 0.5, 100_000)
    >>> round(float(anscombe(z, K=0.28, L=5.0).std()), 2)
    1.0
    """
    K, L = check_positive(K, "K"), check_finite(L, "L")
    z = as_float_array(image, "image")
    arg = z * z.dtype.type(K) + z.dtype.type(0.375 * K * K + L)
    return z.dtype.type(2.0 / K) * np.sqrt(np.maximum(arg, 0))


def inverse_anscombe(image, *, K: float, L: float) -> np.ndarray:
    """Closed-form unbiased inverse of :func:`anscombe` (grey levels from ``E f``).

    Parameters
    ----------
    image : array_like
        Values ``D`` in the transformed domain, typically the expectation of
        ``anscombe(z)`` after denoising or averaging. Not modified.
    K, L : float
        The noise model used by the forward transform.

    Returns
    -------
    ndarray
        Grey levels, same shape; float32 stays float32, anything else float64.

    Notes
    -----
    The algebraic inverse ``((K D / 2)^2 - 3 K^2 / 8 - L) / K`` is biased because
    ``E sqrt`` is not ``sqrt E``. The exact unbiased inverse maps
    ``E f(z) | lambda`` back to ``lambda``; for the Poisson case its closed-form
    approximation is [2]_

    ``I(D) = D^2/4 + sqrt(3/2)/(4 D) - 11/(8 D^2) + 5 sqrt(3/2)/(8 D^3) - 1/8``

    and, in the normalised variables of :func:`anscombe`, the Poisson-Gaussian
    inverse is ``I(D) - st^2`` [3]_, which in grey levels reads
    ``l = K I(D) - L / K``. The ``D^2/4 - 1/8 - st^2`` part is the asymptotically
    unbiased inverse; the ``1/D`` terms fix the Poisson bias at low counts.
    Validity, measured against exact expectations (Poisson sums and Gauss-Hermite
    quadrature, ``tests/test_noise.py``): the error is below 0.04 electrons
    (``0.04 K`` grey levels) for a mean of half an electron or more and any
    ``st``, where the algebraic inverse is off by 0.25 electrons; above a few
    electrons it falls as ``0.3 / D`` electrons (1.5e-3 at 1e4 electrons), a
    relative error below 1e-5 for the thousands of electrons of a grid image.
    ``D`` must be positive; the formula diverges as ``D -> 0``, a level below the
    range of the forward transform when ``L >= 0``.

    References
    ----------
    .. [2] M. Makitalo, A. Foi, "A closed-form approximation of the exact unbiased
       inverse of the Anscombe variance-stabilizing transformation", IEEE Trans.
       Image Process. 20 (2011) 2697-2698. doi:10.1109/TIP.2011.2121085
    .. [3] M. Makitalo, A. Foi, "Optimal inversion of the generalized Anscombe
       transformation for Poisson-Gaussian noise", IEEE Trans. Image Process. 22
       (2013) 91-103. doi:10.1109/TIP.2012.2202675
    """
    K, L = check_positive(K, "K"), check_finite(L, "L")
    D = as_float_array(image, "image")
    if np.any(~(D > 0)):
        raise ValueError("image must hold positive values (the range of anscombe), got "
                         f"a minimum of {np.nanmin(D) if D.size else 'nothing'!r} or NaN")
    r = math.sqrt(1.5)
    Dd = D.astype(np.float64)
    inv = (0.25 * Dd**2 + 0.25 * r / Dd - 1.375 / Dd**2 + 0.625 * r / Dd**3 - 0.125)
    return (K * inv - L / K).astype(D.dtype)


@dataclass(frozen=True, eq=False)
class NoiseModel:
    """Poisson-Gaussian noise model ``Var = K l + L`` of a camera.

    ``K`` and ``L`` are in the units of the stored images; ``scale`` is the factor
    by which the sensor's grey levels were multiplied when stored (16 for 12-bit
    data written in 16-bit files), so ``K_sensor = K / scale`` and
    ``L_sensor = L / scale^2``.

    Attributes
    ----------
    K : float
        Slope, stored grey levels (the gain per electron).
    L : float
        Intercept, stored grey levels squared. Includes the quantisation variance
        ``step^2 / 12`` (``1/12`` sensor grey level^2 for integer levels).
    K_ci, L_ci : (float, float) or None
        95 % confidence intervals of ``K`` and ``L``, stored units.
    scale : float
        Stored grey levels per sensor grey level.
    n_frames : int or None
        Frames used to estimate the model (``None`` for a model given by hand).
    n_pixels : int or None
        Pixels that entered the final fit.
    dof : int or None
        Degrees of freedom of each pixel's residual variance (``T`` minus the
        number of regressors).
    reduced_chi2 : float or None
        Weighted residual of the fit over the intensity bins per degree of
        freedom: about 1 when the linear model and the noise law hold.
    levels, variances, variance_errors : (B,) float64 ndarray or None
        Per intensity bin: mean grey level, mean residual variance and its
        standard error (stored units), for plotting the fit.
    method : str
        ``"stack"`` (:func:`estimate_noise`), ``"single image"``
        (:func:`estimate_noise_image`) or ``"given"`` (a camera model typed in).
    filter_gain : float or None
        Single-image method: the fraction ``sum h^2`` of white-noise power its
        grid-removal filter passes (divided out of the variances).
    bit_depth : int or None
        Significant bits of the images the model was estimated on, when known.
    motion_terms : tuple of str or None
        Stack method: the regressors of the frames' rigid motion fitted out of each
        pixel's series (the shifts ``x``, ``y``, the carriers' harmonics
        ``cos(theta1)``..., or the monomials ``a^i b^j`` of a polynomial model).
    """

    K: float
    L: float
    K_ci: tuple[float, float] | None = None
    L_ci: tuple[float, float] | None = None
    scale: float = 1.0
    n_frames: int | None = None
    n_pixels: int | None = None
    dof: int | None = None
    reduced_chi2: float | None = None
    levels: np.ndarray | None = None
    variances: np.ndarray | None = None
    variance_errors: np.ndarray | None = None
    method: str = "stack"
    filter_gain: float | None = None
    bit_depth: int | None = None
    motion_terms: tuple[str, ...] | None = None

    def __post_init__(self):
        for name in ("K", "L"):
            object.__setattr__(self, name, check_finite(getattr(self, name), name))
        object.__setattr__(self, "scale", check_positive(self.scale, "scale"))
        if self.motion_terms is not None:
            object.__setattr__(self, "motion_terms", tuple(str(t) for t in self.motion_terms))
        for name in ("levels", "variances", "variance_errors"):
            arr = getattr(self, name)
            if arr is not None:
                arr = np.array(arr, dtype=np.float64)
                arr.flags.writeable = False
                object.__setattr__(self, name, arr)

    def as_dict(self) -> dict:
        """Plain-Python description (floats, lists, None), stored units and sensor units."""
        def pair(c):
            return None if c is None else [float(c[0]), float(c[1])]

        return {"method": self.method, "K": self.K, "L": self.L, "K_ci": pair(self.K_ci),
                "L_ci": pair(self.L_ci), "scale": self.scale, "bit_depth": self.bit_depth,
                "K_sensor": self.K_sensor, "L_sensor": self.L_sensor,
                "K_sensor_ci": pair(self.K_sensor_ci), "L_sensor_ci": pair(self.L_sensor_ci),
                "n_frames": self.n_frames, "n_pixels": self.n_pixels,
                "reduced_chi2": self.reduced_chi2, "filter_gain": self.filter_gain,
                "motion_terms": None if self.motion_terms is None else list(self.motion_terms),
                "units": "K: stored grey levels, L: stored grey levels^2 (sensor: / scale, "
                         "/ scale^2)"}

    def variance(self, level):
        """Noise variance ``K level + L`` at grey level(s) ``level``, stored units^2."""
        return self.K * np.asarray(level, dtype=np.float64) + self.L

    @property
    def K_sensor(self) -> float:
        """``K`` in sensor grey levels (``K / scale``)."""
        return self.K / self.scale

    @property
    def L_sensor(self) -> float:
        """``L`` in sensor grey levels squared (``L / scale^2``)."""
        return self.L / self.scale**2

    @property
    def K_sensor_ci(self) -> tuple[float, float] | None:
        """95 % confidence interval of ``K_sensor``."""
        return None if self.K_ci is None else tuple(v / self.scale for v in self.K_ci)

    @property
    def L_sensor_ci(self) -> tuple[float, float] | None:
        """95 % confidence interval of ``L_sensor``."""
        return None if self.L_ci is None else tuple(v / self.scale**2 for v in self.L_ci)

    def __repr__(self) -> str:
        def ci(c):
            return "" if c is None else f" [{c[0]:.4g}, {c[1]:.4g}]"

        head = f"NoiseModel(K={self.K:.5g}{ci(self.K_ci)}, L={self.L:.5g}{ci(self.L_ci)}"
        if self.scale != 1:
            head += (f"; sensor units (scale {self.scale:g}): K={self.K_sensor:.5g}, "
                     f"L={self.L_sensor:.5g}")
        if self.n_frames is not None:
            head += f"; T={self.n_frames}, {self.n_pixels} px"
        return head + ")"


def _regressors(shift: np.ndarray, degree: int) -> np.ndarray:
    """Monomials ``a^i b^j``, ``i + j <= degree``, by total degree: ``1, a, b, a^2,
    ab, b^2, ...`` (degree 2 is the Taylor model of eq. 3)."""
    a, b = float(shift[0]), float(shift[1])
    return np.array([a ** (n - j) * b**j for n in range(degree + 1) for j in range(n + 1)])


def _n_regressors(degree: int) -> int:
    return (degree + 1) * (degree + 2) // 2


def estimate_noise(frames, lattice: Lattice | None = None, *, shifts=None,
                   saturation: float | None = None, scale: float = 1,
                   degree: int | None = None,
                   n_bins: int = 64, progress: Progress | None = None) -> NoiseModel:
    """Estimate the Poisson-Gaussian noise ``Var = K l + L`` from a static grid stack.

    Parameters
    ----------
    frames : (T, H, W) array_like or iterable of (H, W) array_like
        Images of a static grid, affected by rigid vibrations (paper eq. 2),
        grey levels as stored. An iterable is read once, frame by frame.
    lattice : Lattice, optional
        The grid's wave vectors, used to measure the per-frame shifts. Default:
        detected on the first frame. Not needed if ``shifts`` is given or
        ``degree == 0``.
    shifts : (T, 2) array_like, optional
        Per-frame translations ``(alpha_t, beta_t)`` in px, any common origin.
        Default: measured on the fly from the carrier phase (see
        :func:`gridstrain.stacks.vibration.frame_shifts`).
    saturation : float, optional
        Stored grey level at which the sensor clips (e.g. 4095, or 65520 for
        12-bit data stored x16). Pixels that reach it in any frame, or whose
        highest fitted level comes within 5 noise standard deviations of it, are
        left out (see Notes).
    scale : float
        Stored grey levels per sensor grey level (1, or 16 for 12-bit data
        stored x16); only used to report ``K`` and ``L`` in sensor units.
    degree : {None, 0, 1, 2, 3, 4}
        The model of the frames' rigid motion regressed out of each pixel's time
        series (see Notes). None, the default: the shifts and the cosine and sine
        of the carriers' harmonics of order 1 to 3 of each frame's phase advance,
        by groups, as many as the frames allow and the image's residual needs
        (``T >= 6``). An integer: the polynomial of that degree in the shifts,
        3 the second-order Taylor model of eq. (3) plus the cubic terms, 2 eq. (3)
        alone, 1 the first-order model of the paper's ref. [22], 0 no motion at
        all (plain temporal variance: only for a truly static set-up); ``T`` must
        exceed its number of regressors, ``(degree + 1)(degree + 2) / 2``, by 3.
    n_bins : int
        Number of intensity bins (equal pixel counts) used in the fit.
    progress : callable, optional
        ``progress(fraction, message)``, called once per frame.

    Returns
    -------
    NoiseModel
        ``K`` and ``L`` in stored units, with 95 % confidence intervals.

    Raises
    ------
    ValueError
        If there are too few frames (``T`` must exceed the number of regressors
        by 3), the shifts do not match the frames, the design is singular (no
        vibrations to regress on: use ``degree=0``), or too few pixels remain.

    Notes
    -----
    Each pixel's time series is ``v(x, t) = s(x + a_t) + n(x, t)`` (eq. 2); by
    eq. (3) the vibration part is, to second order, a quadratic polynomial in
    ``a_t = (alpha_t, beta_t)`` whose coefficients are ``s``, its gradient and its
    Hessian at the pixel. The design matrix ``X`` (rows ``[1, a, b, a^2, ab, b^2,
    ...]``) is common to all pixels, so the least-squares fit of every pixel is one
    projection: while streaming, only ``X^T d`` (one value per regressor and
    pixel), ``sum d^2`` and the running maximum are accumulated, in float64, with
    ``d`` the frame minus the first frame (removing the large mean before squaring;
    the intercept absorbs it). A constant offset of the shifts does not change the
    space of polynomials, so shifts relative to the first frame, measured on the
    fly, serve, and ``shifts`` may have any origin. Memory: ``(p + 3) H W``
    float64 values (``p`` regressors) plus a buffer of at most 64 MB that turns
    the accumulation into one matrix product per 16 frames; about 30 ms per
    1024 x 1024 frame on two cores, plus 2 s for the fit.

    Why the harmonics by default. A pixel of a periodic grid sees ``s(x + a_t)``,
    a periodic function of the carrier phases ``theta_t = 2 pi K a_t``: a sum of
    harmonics ``exp(i (m theta_1 + n theta_2))``, fitted at any amplitude of the
    vibration, where a polynomial in the shifts is a Taylor series that fails
    once ``2 pi a / p`` nears 1. What is not periodic (lighting, stains) varies
    slowly and moves with ``a_t`` to first order: the shifts. These are the
    regressors of the std maps' temporal variance
    (:mod:`gridstrain.stacks.accumulate`), chosen the same way: a group of
    harmonics is fitted only if it lowers the image's mean residual variance by
    more than 1 %, and the groups that leave fewer than 3 degrees of freedom are
    not tried. On the paper's grid (pitch 5, ``K = 0.28``, ``L = 5``, T = 50,
    160 x 160) vibrating by 0.3 px the cubic polynomial states ``K`` 12 % low and
    ``L`` at 122 grey levels^2; at 0.5 px it finds no signal-dependent noise at
    all; the harmonics keep ``K`` within 3 % and ``L`` within its statistical
    error from 0 to 0.5 px (``tests/test_noise.py``).

    The polynomial models: the third-order Taylor term of a sharp grid is not
    negligible. On the paper's synthetic grid (``sin^3`` lines, pitch 5, 12 bits,
    ``K = 0.28``, ``L = 5``, T = 50, 30 stacks of 256 x 256), degree 2 biases ``L``
    by +2.8 grey levels^2 in vibration case 2 (``(0.1, 0.05)`` px) and by +27 in
    case 1 (``(0.15, 0.1)`` px); degree 3 leaves no bias detectable at that
    precision (below 0.6 in ``L``, 0.1 % in ``K``) for both, at the cost of 4
    degrees of freedom. Use 4 for stronger vibrations or square-edged lines.

    The residual ``RSS / (T - p)`` (``p`` regressors) estimates the noise variance.
    Since the noise variance of frame ``t`` follows the level the pixel sees,
    ``V_t = K m_t + L``, and ``E[RSS] = sum_t (1 - h_tt) V_t`` (``h_tt`` the
    leverages), the level paired with it is the leverage-weighted mean of the
    fitted values, ``sum_t (1 - h_tt) m_t / (T - p)``; then
    ``E[RSS / (T - p)] = K l + L`` exactly. (The plain temporal mean biases ``K``
    by about 0.5 % in case 1, where the frames with extreme shifts have both high
    leverage and levels changed by the Hessian term.)

    Pixels are then grouped in ``n_bins`` bins of equal counts by level; the bin
    means of the residual variances are fitted by weighted least squares with
    the weights of Gaussian noise, ``Var(s^2) = 2 sigma^4 / dof`` with ``sigma^2``
    from the current model, iterated until the estimates settle. Each iteration
    drops pixels whose ratio to the model lies beyond the chi-square quantiles
    ``1e-5`` and ``1 - 1e-3`` (hot pixels, dust, model failures), and divides the
    kept pixels' mean by its exact truncated chi-square value, so the cut costs
    no bias; it starts from per-bin medians corrected by the chi-square median,
    so an outlier never steers the fit. One per cent of pixels with three times
    the noise variance moves ``K`` by under 0.3 %. The
    confidence intervals come from the covariance of the weighted fit, whose
    weights are known from theory rather than estimated (a bootstrap over bins
    would re-estimate what the chi-square law already gives), inflated by the
    square root of the reduced chi-square when it exceeds 1 (misfit the theory
    does not cover). Over 30 simulated stacks of 256 x 256 x 50 the 95 % intervals
    held the true ``L`` 29 times, and over 40 of 128 x 128 x 30, ``K`` 39 and ``L``
    38 times.

    Saturation: a pixel is kept only if no frame reached ``saturation`` and its
    highest fitted value over the frames, plus 5 times the noise standard
    deviation of the brightest tenth of the pixels, stays below it. The test
    uses the fitted values, which for Gaussian noise are independent of the
    residuals; selecting on a pixel's own spread or maximum alone keeps the
    pixels that happened to draw a low variance, and biased ``K`` by -0.3 % and
    ``L`` by +2 grey levels^2 with 4 % of the pixels clipping.

    Precision: ``L`` is an extrapolation to zero level from the levels the grid
    spans, so it is much less precise than ``K``. For a 256 x 256 frame with
    ``A = 2000``, ``gamma = 0.9``, pitch 5 and T = 50, the standard errors are
    0.5 % on ``K`` and 2.7 grey levels^2 on ``L`` (half of ``L``); they fall as
    ``1 / sqrt(H W (T - p))``, so ``L`` to 20 % takes about 1024 x 1024 x 200
    frames (measured: ``K`` +0.06 %, ``L`` -6 %, standard error 0.29). A wider
    range of levels helps ``L`` the most: with the lighting falling to 10 %
    across a 256 x 256 x 50 field, ``L`` comes within 0.4 grey levels^2.
    ``L`` includes the quantisation variance (``1/12`` for integer levels).
    Saturated pixels must be excluded with ``saturation``: clipping lowers their
    variance and drags the fit.
    """
    lattice = check_type(lattice, "lattice", Lattice, allow_none=True)
    if degree is not None and (isinstance(degree, bool) or degree not in (0, 1, 2, 3, 4)):
        raise ValueError(f"degree must be None, 0, 1, 2, 3 or 4, got {degree!r}")
    n_bins = check_int(n_bins, "n_bins", minimum=3)
    scale = check_positive(scale, "scale")
    saturation = check_positive(saturation, "saturation", allow_none=True)
    n_total = len(frames) if hasattr(frames, "__len__") else None
    if shifts is not None:
        shifts = as_shifts(shifts)
        # Centred, the monomials are far from collinear (the fit itself does not
        # depend on the origin, but its conditioning does).
        shifts = shifts - shifts.mean(axis=0)
        if n_total is not None and n_total != shifts.shape[0]:
            raise ValueError(f"shifts has {shifts.shape[0]} rows but frames hold "
                             f"{n_total} frames")
    progress = null_progress if progress is None else progress
    p = _n_regressors(degree) if degree is not None else 1 + _motion_columns(n_total)
    acc = _accumulate_stack(frames, lattice, shifts, degree, p, progress)
    T = acc["T"]
    if shifts is not None and shifts.shape[0] != T:
        raise ValueError(f"shifts has {shifts.shape[0]} rows but frames hold {T} frames")
    shape = acc["v0"].shape
    terms = None
    if degree is None:
        if T < _MIN_HARMONIC_FRAMES:
            raise ValueError(f"frames must hold at least {_MIN_HARMONIC_FRAMES} frames to "
                             f"regress the vibrations out (the mean, the 2 shifts and 3 "
                             f"degrees of freedom), got {T}")
        rss, level_d, fit_max, dof, terms = _project_motion(
            acc["X"], acc["B"], acc["S2"], want_max=saturation is not None)
        rss, level_d = rss.reshape(shape), level_d.reshape(shape)
    else:
        dof = T - p
        if dof < 3:
            raise ValueError(f"frames must hold at least {p + 3} frames for degree {degree} "
                             f"({p} regressors), got {T}")
        rss, level_d, fit_max = _project(acc["X"], acc["B"].reshape(p, *shape),
                                         acc["S2"].reshape(shape), degree,
                                         want_max=saturation is not None)
        terms = tuple(_monomial_names(degree))
    var = (rss / dof).ravel()
    level = (acc["v0"] + level_d).ravel()
    ok = np.isfinite(var) & (var > 0)
    if saturation is not None:
        ok &= _unsaturated(acc["v0"].ravel() + fit_max, acc["vmax"].ravel(), level, var, ok,
                           saturation)
    progress(0.95, "noise: fitting Var = K l + L")
    fit = _fit_variance(level[ok], var[ok], dof, n_bins)
    progress(1.0, "noise: done")
    return NoiseModel(K=fit["K"], L=fit["L"], K_ci=fit["K_ci"], L_ci=fit["L_ci"],
                      scale=scale, n_frames=T, n_pixels=fit["n_pixels"], dof=dof,
                      reduced_chi2=fit["reduced_chi2"], levels=fit["levels"],
                      variances=fit["variances"], variance_errors=fit["errors"],
                      motion_terms=terms)


# The harmonic motion model needs the mean, the two shifts and 3 degrees of freedom.
_MIN_HARMONIC_FRAMES = 6


def _motion_columns(n_total: int | None) -> int:
    """The motion regressors (:data:`gridstrain.stacks.MOTION_TERMS`, whole groups)
    accumulated for a stack of ``n_total`` frames: those that can leave 3 degrees of
    freedom after the mean; all of them when the length is not known."""
    k = 0
    for grp in MOTION_TERMS:
        if n_total is not None and n_total - 1 - (k + len(grp)) < 3:
            break
        k += len(grp)
    return k


def _monomial_names(degree: int) -> list[str]:
    """The names of :func:`_regressors`' monomials after the constant: ``a``, ``b``,
    ``a^2``, ``a b``..."""
    def mono(i, j):
        f = [("a" if i == 1 else f"a^{i}") if i else "", ("b" if j == 1 else f"b^{j}")
             if j else ""]
        return " ".join(x for x in f if x)

    return [mono(n - j, j) for n in range(1, degree + 1) for j in range(n + 1)]


def _project_motion(X, Bsum, S2, *, want_max=False):
    """Residual sums of squares of the harmonic motion model and its effective levels.

    ``X`` (T, 1 + m): the constant then the motion regressors of each frame
    (:func:`gridstrain.stacks.motion_regressors`); ``Bsum`` (1 + m, n) the sums
    ``X^T d`` and ``S2`` (n,) ``sum d^2``, ``d`` the frames minus the first. The
    nested fits (:func:`gridstrain.stacks.nested_motion_fits`) leave 3 degrees of
    freedom at least; the one kept is chosen on the image's mean residual variance
    (:func:`gridstrain.stacks.pick_motion_fit`). Returns ``(rss, level, fit_max,
    dof, terms)``: per pixel the residual sum of squares, the leverage-weighted
    mean of the fitted values minus the first frame (as :func:`_project`), the
    highest fitted value minus the first frame if ``want_max``; the residual's
    degrees of freedom and the names of the regressors kept.
    """
    T = X.shape[0]
    g = X[:, 1:]
    gbar = g.mean(axis=0)
    Borth, cols, stops = nested_motion_fits(g, gbar, min_dof=3)
    Sd = Bsum[0]
    svv = S2 - Sd * Sd / T
    # z = B^T sum_t (g_t - gbar) d_t, on the kept columns (centred sums)
    z = Borth.T @ (Bsum[1:][cols] - gbar[cols, None] * Sd) if cols else np.zeros((0, Sd.size))
    z2 = np.concatenate([[0.0], np.cumsum(np.einsum("ij,ij->i", z, z))])
    means = (svv.sum() - z2[stops]) / np.array([T - 1 - k for k in stops])
    k = stops[pick_motion_fit(means, stops, cols)]
    dof = T - 1 - k
    zk = z[:k]
    rss = np.maximum(svv - np.einsum("ij,ij->j", zk, zk), 0.0)
    # the fitted values m_t = mean + Q_t z, Q = (g - gbar)[:, cols] B orthonormal; the
    # leverages h_t = 1 / T + |Q_t|^2; level as in _project: sum (1 - h_t) m_t / dof
    Q = (g[:, cols[:k]] - gbar[cols[:k]]) @ Borth[:k, :k]
    h = 1.0 / T + np.einsum("ti,ti->t", Q, Q)
    level = Sd / T + ((1.0 - h) @ Q) @ zk / dof
    fit_max = None
    if want_max:
        n = Sd.size
        fit_max = np.empty(n)
        step = max(1, (1 << 22) // T)
        for i in range(0, n, step):
            fit_max[i:i + step] = (Sd[i:i + step] / T + Q @ zk[:, i:i + step]).max(axis=0)
    names = [n for grp in MOTION_TERMS for n in grp]
    return rss, level, fit_max, dof, tuple(names[c] for c in cols[:k])


def _accumulate_stack(frames, lattice, shifts, degree, p, progress) -> dict:
    """Stream the frames once into the sums the per-pixel regression needs.

    Returns a dict with ``T`` (frames read), ``X`` ((T, p) design matrix of the
    shifts' monomials), ``B`` ((p, H W) ``X^T d``), ``S2`` ((H W,) ``sum d^2``), with
    ``d`` the frames minus the first frame ``v0`` ((H, W)), and ``vmax`` ((H, W)
    the highest value each pixel reached). Shifts come from ``shifts`` (centred),
    are zero for ``degree == 0``, or are measured on the fly from the carrier
    phase (lattice detected on the first frame if None).
    """
    n_total = len(frames) if hasattr(frames, "__len__") else None
    shape = v0 = B = S2 = vmax = shift_fn = None
    lat = lattice
    rows = []
    T = 0
    buf = None  # frames minus the first, flushed into B by one matrix product
    nbuf = 0
    for t, frame in numbered_frames(frames):
        arr = as_frame(frame, shape, t)
        if shape is None:
            shape = arr.shape
            v0 = arr.copy()
            B = np.zeros((p, arr.size))
            S2 = np.zeros(arr.size)
            vmax = arr.copy()
            buf = np.empty((max(1, min(16, _BUFFER_BYTES // (8 * arr.size))), arr.size))
            if degree != 0 and (shifts is None or degree is None) and lat is None:
                lat = detect_lattice(arr)
            if degree != 0 and shifts is None:
                shift_fn = streaming_shift(CarrierProbe(lat, shape), lat)
        if degree == 0:
            a = np.zeros(2)
        elif shifts is not None:
            if t >= shifts.shape[0]:
                raise ValueError(f"shifts has {shifts.shape[0]} rows but frames hold more")
            a = shifts[t]
        else:
            a = shift_fn(arr)
        if degree is None:
            # the carrier phase advances of the shift, eq. (2): theta = 2 pi K a
            theta = (2 * np.pi) * (lat.K @ a)
            rows.append(np.concatenate([[1.0], motion_regressors(theta, a)[0, :p - 1]]))
        else:
            rows.append(_regressors(a, degree))
        np.subtract(arr.ravel(), v0.ravel(), out=buf[nbuf])
        np.maximum(vmax, arr, out=vmax)
        nbuf += 1
        T += 1
        if nbuf == buf.shape[0]:
            _flush(B, S2, np.array(rows[T - nbuf:]), buf[:nbuf])
            nbuf = 0
        frac = 0.9 * T / n_total if n_total else 0.0
        progress(frac, f"noise: frame {T}" + (f"/{n_total}" if n_total else ""))
    if nbuf:
        _flush(B, S2, np.array(rows[T - nbuf:]), buf[:nbuf])
    if T == 0:
        raise ValueError("frames must hold at least one frame, got none")
    return {"T": T, "X": np.array(rows), "B": B, "S2": S2, "v0": v0, "vmax": vmax}


def _unsaturated(top, vmax, level, var, ok, saturation) -> np.ndarray:
    """(n,) bool: pixels that never clipped and whose highest fitted level ``top``
    stays 5 noise standard deviations below ``saturation`` (see estimate_noise)."""
    ok = ok & (vmax < saturation)  # clipped pixels, whatever the model says
    # noise scale near saturation: a median over the brightest tenth of the
    # unclipped pixels, a global figure that no single pixel's draw can move
    bright = ok & (level >= np.quantile(level[ok], 0.9)) if ok.any() else ok
    sigma_hi = math.sqrt(float(np.median(var[bright]))) if bright.any() else 0.0
    return ok & (top + _SATURATION_SIGMAS * sigma_hi < saturation)


def _flush(B, S2, X, D):
    """Accumulate ``X^T D`` into ``B`` and ``sum D^2`` into ``S2`` (in place)."""
    B += X.T @ D  # (p, n) BLAS product over a few frames at once
    S2 += np.einsum("ti,ti->i", D, D)


def _project(X, B, S2, degree, *, want_max=False):
    """Residual sum of squares and effective level of every pixel's regression.

    Parameters
    ----------
    X : (T, p) design matrix. B : (p, H, W) accumulated ``X^T d``. S2 : (H, W)
    accumulated ``sum d^2``, with ``d`` the frames minus the first frame.

    Returns
    -------
    rss : (H, W) ``sum d^2 - b^T G^-1 b``.
    level : (H, W) ``sum_t (1 - h_tt) m_t / (T - p)`` minus the first frame, with
        ``m_t`` the fitted values and ``h_tt`` the leverages.
    fit_max : (H * W,) ``max_t m_t`` minus the first frame, if ``want_max``.
    """
    T, p = X.shape
    G = X.T @ X
    # Scale the columns to unit diagonal so the conditioning test measures the
    # design itself, not the units of the shifts.
    d = np.sqrt(np.diag(G))
    if not np.all(d > 0) or np.linalg.cond(G / np.outer(d, d)) > 1e10:
        raise ValueError(
            f"the shifts do not vary enough to fit a degree-{degree} vibration model "
            "(singular design): the stack looks static, use degree=0, or pass shifts")
    C = linalg.cholesky(G / np.outer(d, d), lower=True)
    Z = linalg.solve_triangular(C, B.reshape(p, -1) / d[:, None], lower=True)
    rss = S2.ravel() - np.einsum("ij,ij->j", Z, Z)
    # The noise variance changes from frame to frame with the grey level the pixel
    # sees, V_t = K m_t + L, and E[RSS] = sum_t (1 - h_tt) V_t: the level that makes
    # E[RSS / (T - p)] = K l + L exact is the leverage-weighted mean of the fitted
    # values, not their plain mean (the two differ by up to 1 % of K under strong
    # vibrations, where extreme frames have both high leverage and curved levels).
    Xs = linalg.solve_triangular(C, (X / d).T, lower=True)  # (p, T)
    h = np.einsum("it,it->t", Xs, Xs)
    u = ((1.0 - h)[:, None] * X).sum(axis=0)
    q = linalg.solve_triangular(C, u / d, lower=True)
    level = (q @ Z) / (T - p)
    fit_max = None
    if want_max:
        # fitted values m_t = Xs^T Z, by chunks of pixels to bound the (T, n) block
        n = Z.shape[1]
        fit_max = np.empty(n)
        step = max(1, (1 << 22) // T)
        for i in range(0, n, step):
            fit_max[i:i + step] = (Xs.T @ Z[:, i:i + step]).max(axis=0)
    return (np.maximum(rss, 0).reshape(S2.shape), level.reshape(S2.shape), fit_max)


def _truncation_moments(dof, lo, hi):
    """Mean and second moment of ``X = chi2_dof / dof`` given ``lo <= X <= hi``.

    ``x f_nu(x) = nu f_{nu+2}(x)`` for the chi-square density, so
    ``E[X; a <= X <= b] = F_{nu+2}`` over the same range, and
    ``E[X^2; ...] = (nu + 2) / nu F_{nu+4}``.
    """
    def mass(nu):
        return special.chdtr(nu, hi * dof) - special.chdtr(nu, lo * dof)

    p = mass(dof)
    return mass(dof + 2) / p, (dof + 2) / dof * mass(dof + 4) / p


def _bin_stats(level, var, model_var, idx, nb, dof, m1, m2):
    """Per-bin mean level, mean variance and its standard error, truncation removed.

    A kept pixel's residual variance is ``V chi2_dof / dof`` truncated to the
    outlier cuts, with mean ``m1 V`` and second moment ``m2 V^2``: the bin mean is
    divided by ``m1`` and its variance is ``sum (m2 - m1^2) V_i^2 / n^2 / m1^2``
    (``2 V^2 / dof`` without truncation, Gaussian noise).
    """
    n = np.bincount(idx, minlength=nb).astype(np.float64)
    good = n > 0
    lb = np.bincount(idx, weights=level, minlength=nb)[good] / n[good]
    sb = np.bincount(idx, weights=var, minlength=nb)[good] / n[good] / m1
    vv = np.bincount(idx, weights=model_var**2, minlength=nb)[good]
    err = np.sqrt((m2 - m1 * m1) * vv) / n[good] / m1
    return lb, sb, err


def _wls(x, y, err):
    A = np.column_stack([x, np.ones_like(x)]) / err[:, None]
    coef, *_ = np.linalg.lstsq(A, y / err, rcond=None)
    cov = np.linalg.inv(A.T @ A)
    chi2 = float(np.sum((A @ coef - y / err) ** 2))
    return coef, cov, chi2


def _settled(K, L, K_new, L_new, level, tol) -> bool:
    """Whether an iteration of the weighted fit moved (K, L) by less than ``tol``."""
    return abs(K_new - K) <= tol * abs(K_new) and abs(L_new - L) <= tol * (
        abs(L_new) + abs(K_new) * level)


def _intervals(cov, chi2, n_bins):
    """Reduced chi-square and the 95 % half-widths of (K, L), inflated by the
    square root of the reduced chi-square when it exceeds 1 (misfit the weights
    do not cover)."""
    red = chi2 / max(n_bins - 2, 1)
    infl = math.sqrt(max(1.0, red))
    return red, tuple(math.sqrt(cov[i, i]) * infl * _Z95 for i in range(2))


def _fit_variance(level, var, dof, n_bins):
    n = level.size
    nb = min(n_bins, n // _MIN_PER_BIN)
    if nb < 3:
        raise ValueError(f"too few usable pixels to fit the noise model ({n}); need at "
                         f"least {3 * _MIN_PER_BIN} unsaturated pixels")
    edges = np.unique(np.quantile(level, np.linspace(0, 1, nb + 1)))
    if edges.size < 4:
        raise ValueError("the pixels span too narrow a range of grey levels to fit "
                         "Var = K l + L (fewer than 3 distinct intensity bins)")
    nb = edges.size - 1
    idx = np.clip(np.searchsorted(edges, level, side="right") - 1, 0, nb - 1)

    # Robust start: per-bin medians, corrected by the median of chi2_dof / dof.
    med_corr = float(_chi2_ppf(0.5, dof)) / dof
    counts = np.bincount(idx, minlength=nb)
    order = np.argsort(idx, kind="stable")
    splits = np.cumsum(counts)[:-1]
    med_v = np.array([np.median(g) for g in np.split(var[order], splits) if g.size])
    med_l = np.array([np.median(g) for g in np.split(level[order], splits) if g.size])
    K, L = np.polyfit(med_l, med_v / med_corr, 1)
    lo, hi = _chi2_ppf(np.array([_OUTLIER_LOW, 1 - _OUTLIER_HIGH]), dof) / dof
    m1, m2 = _truncation_moments(dof, lo, hi)

    floor = 1e-6 * float(np.median(var))
    for _ in range(50):
        model = np.maximum(K * level + L, floor)
        r = var / model
        keep = (r >= lo) & (r <= hi)
        lb, sb, err = _bin_stats(level[keep], var[keep], model[keep], idx[keep], nb, dof,
                                  m1, m2)
        if lb.size < 3:
            raise ValueError("too few intensity bins left after rejecting outliers")
        (K_new, L_new), cov, chi2 = _wls(lb, sb, err)
        done = _settled(K, L, K_new, L_new, float(np.mean(level)), 1e-10)
        K, L = float(K_new), float(L_new)
        if done:
            break
    if not K > 0:
        raise ValueError(f"no signal-dependent noise found (fitted K = {K:.3g}); the "
                         "frames may be processed or the stack not static")
    red, (sK, sL) = _intervals(cov, chi2, lb.size)
    return {"K": K, "L": L, "K_ci": (K - sK, K + sK), "L_ci": (L - sL, L + sL),
            "n_pixels": int(np.count_nonzero(keep)), "reduced_chi2": red,
            "levels": lb, "variances": sb, "errors": err}
