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
from numpy.lib.stride_tricks import sliding_window_view
from scipy import fft as sfft
from scipy import linalg, ndimage, special

from ._progress import Progress, null_progress
from ._stats import median, row_medians
from ._validation import (
    as_float_array,
    as_image,
    as_shifts,
    check_finite,
    check_int,
    check_mask,
    check_positive,
    check_type,
)
from ._wft import _spectrum_block
from .lattice import Lattice, detect_lattice
from .vibration import _as_frame, _CarrierProbe, _iter_frames, _streaming_shift
from .wft import transfer_function

__all__ = ["NOISE_RESULT_KIND", "NoiseModel", "anscombe", "estimate_noise", "estimate_noise_image",
           "inverse_anscombe"]

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

    def __post_init__(self):
        for name in ("K", "L"):
            object.__setattr__(self, name, check_finite(getattr(self, name), name))
        object.__setattr__(self, "scale", check_positive(self.scale, "scale"))
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
                   saturation: float | None = None, scale: float = 1, degree: int = 3,
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
        :func:`gridstrain.vibration.frame_shifts`).
    saturation : float, optional
        Stored grey level at which the sensor clips (e.g. 4095, or 65520 for
        12-bit data stored x16). Pixels that reach it in any frame, or whose
        highest fitted level comes within 5 noise standard deviations of it, are
        left out (see Notes).
    scale : float
        Stored grey levels per sensor grey level (1, or 16 for 12-bit data
        stored x16); only used to report ``K`` and ``L`` in sensor units.
    degree : {0, 1, 2, 3, 4}
        Degree of the polynomial in the shifts regressed out of each pixel's
        time series (see Notes). 3, the default, is the second-order Taylor model
        of eq. (3) plus the cubic terms; 2 is eq. (3) alone; 1 is the first-order
        model of the paper's ref. [22]; 0 ignores the vibrations (plain temporal
        variance: only for a truly static set-up). ``T`` must exceed the number
        of regressors, ``(degree + 1)(degree + 2) / 2``, by at least 3.
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

    Why degree 3 by default: the third-order Taylor term of a sharp grid is not
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
    if isinstance(degree, bool) or degree not in (0, 1, 2, 3, 4):
        raise ValueError(f"degree must be 0, 1, 2, 3 or 4, got {degree!r}")
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
    p = _n_regressors(degree)
    acc = _accumulate_stack(frames, lattice, shifts, degree, n_total, progress)
    T = acc["T"]
    if shifts is not None and shifts.shape[0] != T:
        raise ValueError(f"shifts has {shifts.shape[0]} rows but frames hold {T} frames")
    dof = T - p
    if dof < 3:
        raise ValueError(f"frames must hold at least {p + 3} frames for degree {degree} "
                         f"({p} regressors), got {T}")

    shape = acc["v0"].shape
    rss, level_d, fit_max = _project(acc["X"], acc["B"].reshape(p, *shape),
                                     acc["S2"].reshape(shape), degree,
                                     want_max=saturation is not None)
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
                      variances=fit["variances"], variance_errors=fit["errors"])


def _accumulate_stack(frames, lattice, shifts, degree, n_total, progress) -> dict:
    """Stream the frames once into the sums the per-pixel regression needs.

    Returns a dict with ``T`` (frames read), ``X`` ((T, p) design matrix of the
    shifts' monomials), ``B`` ((p, H W) ``X^T d``), ``S2`` ((H W,) ``sum d^2``), with
    ``d`` the frames minus the first frame ``v0`` ((H, W)), and ``vmax`` ((H, W)
    the highest value each pixel reached). Shifts come from ``shifts`` (centred),
    are zero for ``degree == 0``, or are measured on the fly from the carrier
    phase (lattice detected on the first frame if None).
    """
    p = _n_regressors(degree)
    shape = v0 = B = S2 = vmax = shift_fn = None
    rows = []
    T = 0
    buf = None  # frames minus the first, flushed into B by one matrix product
    nbuf = 0
    for t, frame in _iter_frames(frames):
        arr = _as_frame(frame, shape, t)
        if shape is None:
            shape = arr.shape
            v0 = arr.copy()
            B = np.zeros((p, arr.size))
            S2 = np.zeros(arr.size)
            vmax = arr.copy()
            buf = np.empty((max(1, min(16, _BUFFER_BYTES // (8 * arr.size))), arr.size))
            if degree > 0 and shifts is None:
                lat = lattice if lattice is not None else detect_lattice(arr)
                shift_fn = _streaming_shift(_CarrierProbe(lat, shape), lat)
        if degree == 0:
            a = np.zeros(2)
        elif shifts is not None:
            if t >= shifts.shape[0]:
                raise ValueError(f"shifts has {shifts.shape[0]} rows but frames hold more")
            a = shifts[t]
        else:
            a = shift_fn(arr)
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


# --------------------------------------------------------------------------- one image

# Side of the tiles whose median periodogram measures the grid's harmonic content:
# 128 px resolve 1/128 cycle/px.
_TILE = 128
# Harmonics n k1 + m k2 with |n|, |m| up to this order are candidates for a notch
# (beyond it the pixel's integration leaves less than a grey level on a sharp
# checkerboard at pitch 5).
_MAX_ORDER = 12
# A harmonic is notched when the tile spectrum near its aliased frequency exceeds
# this many times the noise floor (the median over the bins away from every
# candidate). Over ~60 tiles the 3 x 3-smoothed median of white noise spreads by
# about 0.1 relative, so 1.3 is ~3 spreads above it; a harmonic left below it adds
# a fraction of the noise density over a few bins of the kept band, under 1 %.
_PEAK_FACTOR = 1.3
# Frequency std of each Gaussian notch, cycles/px: wide enough to cover a peak
# broadened by lighting, strain or a lattice error of 1e-4 cycle/px at order 12,
# narrow enough that hundreds of notches leave most of the band.
_NOTCH_STD = 0.012
# A notch widens by this fraction per decade of its peak above the noise floor:
# a strong harmonic carries strong skirts (a print texture or the lighting
# modulating it, the strain spreading it), which a fixed width lets through. A
# 20-px texture of 5 % contrast biased the variance by +8 % with fixed notches,
# by under 0.5 % with 0.15 (the fundamental's notch is then ~2.5 times wider).
_WIDEN = 0.15
# Residuals beyond this many robust standard deviations (within an intensity bin)
# are rejected as outliers: dust, steps, texture; the truncation's effect on the
# variance of Gaussian residuals is divided out exactly.
_CLIP = 3.5
# E[X^2 | |X| <= c] / Var for a standard normal: the truncation's effect divided out
_CLIP_KAPPA = 1 - 2 * _CLIP * math.exp(-_CLIP**2 / 2) / math.sqrt(2 * math.pi) / math.erf(
    _CLIP / math.sqrt(2))


# tiles transformed at once by _tile_spectrum: 16 tiles of 128 x 128
_TILE_BATCH_BYTES = 2**21


def _blackman_harris(n: int) -> np.ndarray:
    # 4-term Blackman-Harris: sidelobes below -92 dB, so the grid's fundamental
    # (1e8 times the noise density on a 12-bit image) does not leak over the band
    t = 2 * np.pi * np.arange(n) / n
    return 0.35875 - 0.48829 * np.cos(t) + 0.14128 * np.cos(2 * t) - 0.01168 * np.cos(3 * t)


def _tile_spectrum(img: np.ndarray, usable: np.ndarray, tile: int) -> np.ndarray:
    """(tile, tile) median periodogram over half-overlapping tiles, 3 x 3 smoothed.

    The tiles (together about 4 times the image) are transformed a batch at a
    time, each batch's periodograms written straight into the (bins, tiles) table
    whose rows the median is taken along: the memory is that table, half a tile's
    bins per tile (about twice the image in float64), whatever the image's size.
    """
    win = np.outer(_blackman_harris(tile), _blackman_harris(tile))
    step = tile // 2
    blocks = sliding_window_view(img, (tile, tile))[::step, ::step]
    good = sliding_window_view(usable, (tile, tile))[::step, ::step].all(axis=(2, 3))
    # the tiles wholly usable, or all of them when fewer than 4 are (holes
    # everywhere: the median over all tiles is still robust)
    if np.count_nonzero(good) < 4:
        good = np.ones(good.shape, dtype=bool)
    where = np.argwhere(good)
    n, wr = len(where), tile // 2 + 1
    # a real tile's periodogram is even: half of it, one row of bins per frequency
    table = np.empty((tile * wr, n))
    batch = max(1, _TILE_BATCH_BYTES // (tile * tile * 8))
    for i0 in range(0, n, batch):
        idx = where[i0:i0 + batch]
        sel = blocks[idx[:, 0], idx[:, 1]]
        sel = (sel - sel.mean(axis=(1, 2), keepdims=True)) * win
        table[:, i0:i0 + len(idx)] = (np.abs(sfft.rfft2(sel)) ** 2).reshape(len(idx), -1).T
    med = row_medians(table).reshape(tile, wr)
    spec = np.empty((tile, tile))
    spec[:, :wr] = med
    spec[:, wr:] = med[(-np.arange(tile)) % tile][:, tile - wr:0:-1]
    return ndimage.uniform_filter(spec, 3, mode="wrap")


def _harmonics(lattice: Lattice, order: int) -> np.ndarray:
    """(M, 2) aliased frequencies ``(f_y, f_x)`` of ``n k1 + m k2``, in [-1/2, 1/2)."""
    n, m = np.meshgrid(np.arange(-order, order + 1), np.arange(-order, order + 1))
    k1, k2 = np.array(lattice.k1), np.array(lattice.k2)  # (k_x, k_y)
    f = n.ravel()[:, None] * k1 + m.ravel()[:, None] * k2
    f = (f + 0.5) % 1.0 - 0.5
    return f[:, ::-1]


def _residual_filter(shape, lattice: Lattice, spec: np.ndarray, s: float):
    """Transfer (H, W) of the grid-removal filter and the notched frequencies.

    ``H(f) = prod_h (1 - exp(-|f - f_h|^2 / (2 s^2)))^2`` over the significant
    harmonics (always 0 and the fundamentals): a double zero at each, so a peak
    of width ``w`` leaks ``(w^2 / 2 s^2)^4`` of its power.
    """
    H, W = shape
    tile = spec.shape[0]
    cand = _harmonics(lattice, _MAX_ORDER)
    # noise floor: tile bins more than 3 bins from every candidate
    near = np.zeros((tile, tile), dtype=bool)
    for fy, fx in cand:
        iy, ix = round(fy * tile) % tile, round(fx * tile) % tile
        near[np.ix_(np.arange(iy - 3, iy + 4) % tile, np.arange(ix - 3, ix + 4) % tile)] = True
    far = spec[~near] if (~near).sum() >= 20 else spec.ravel()
    floor = float(np.median(far)) if (~near).sum() >= 20 else float(np.quantile(far, 0.1))
    n = np.arange(-_MAX_ORDER, _MAX_ORDER + 1)
    nn, mm = np.meshgrid(n, n)
    always = (np.abs(nn) + np.abs(mm)).ravel() <= 1
    out = np.ones((H, W))
    fy_all, fx_all = np.fft.fftfreq(H), np.fft.fftfreq(W)
    used = []
    for (fy, fx), keep in zip(cand, always, strict=True):
        iy, ix = round(fy * tile) % tile, round(fx * tile) % tile
        local = spec[np.ix_(np.arange(iy - 1, iy + 2) % tile, np.arange(ix - 1, ix + 2) % tile)]
        if not keep and local.max() <= _PEAK_FACTOR * floor:
            continue
        used.append((fy, fx))
        # strong peaks carry strong skirts (texture, lighting, strain): wider notches
        sh = s * (1.0 + _WIDEN * math.log10(max(float(local.max()) / floor, 1.0)))
        dy = (fy_all - fy + 0.5) % 1.0 - 0.5
        dx = (fx_all - fx + 0.5) % 1.0 - 0.5
        ri, ci = np.nonzero(np.abs(dy) < 8 * sh)[0], np.nonzero(np.abs(dx) < 8 * sh)[0]
        g = np.exp(-0.5 * dy[ri, None] ** 2 / sh**2) * np.exp(-0.5 * dx[None, ci] ** 2 / sh**2)
        out[np.ix_(ri, ci)] *= (1.0 - g) ** 2
    return out, np.array(used)


def _clipped_variance(r: np.ndarray) -> float:
    """Variance of zero-mean Gaussian samples ``r`` with outliers rejected."""
    c, kappa = _CLIP, _CLIP_KAPPA
    s2 = (median(np.abs(r), overwrite_input=True) / _Q75) ** 2
    for _ in range(20):
        keep = r * r <= c * c * s2
        new = float(np.mean(r[keep] ** 2)) / kappa
        if abs(new - s2) <= 1e-9 * new:
            break
        s2 = new
    return s2


def estimate_noise_image(image, lattice: Lattice | None = None, *, mask=None,
                         saturation: float | None = None, scale: float = 1,
                         n_bins: int = 32) -> NoiseModel:
    """Estimate the Poisson-Gaussian noise ``Var = K l + L`` from a single grid image.

    Parameters
    ----------
    image : (H, W) array_like
        One frame of a grid or checkerboard, grey levels as stored (at least
        160 x 160 px). Not modified.
    lattice : Lattice, optional
        The grid's wave vectors, used to find the regions without a grid (holes,
        background) whose edges are left out. Default: detected.
    mask : (H, W) bool array_like, optional
        True on the pixels that may be used; the neighbourhood of the others is
        left out too.
    saturation : float, optional
        Stored grey level at which the sensor clips; pixels near a clipped one are
        left out (as are those near a zero).
    scale : float
        Stored grey levels per sensor grey level (16 for 12-bit data stored x16);
        only used to report ``K`` and ``L`` in sensor units.
    n_bins : int
        Number of intensity bins of equal counts.

    Returns
    -------
    NoiseModel
        ``method == "single image"``, ``n_frames == 1``; ``levels`` and
        ``variances`` per bin in stored units (the variance of the image noise, the
        filter's gain divided out).

    Notes
    -----
    A grid image is a locally periodic pattern times a slowly varying lighting,
    plus noise: in the spectrum the pattern lives in narrow peaks at the harmonics
    ``n k1 + m k2`` (``|n|, |m| <= 12``, folded by the sampling) and at zero, and
    the noise, white, everywhere. Which harmonics hold more than noise is read
    from the data, the median over half-overlapping 128 x 128 tiles of
    Blackman-Harris periodograms (so a hole or an edge in a few tiles does not
    matter): a harmonic is notched when the tile spectrum near it exceeds 1.3
    times the noise floor. The filter is ``H(f) = prod (1 - G(f - f_h))^2`` over
    the notched harmonics, ``G`` a Gaussian of 0.012 cycle/px (wider on images
    under 560 px, and for strong peaks): a double zero at each harmonic, so a peak broadened by the
    lighting or the strain leaks nothing measurable, and a kernel whose reach is
    about 60 px. The residual ``r = h * image`` is what the grid does not explain.

    The filter's effect is accounted for exactly, not fitted: a pixel's residual
    has variance ``sum_y h(x - y)^2 (K l(y) + L) = G (K lambda(x) + L)`` with
    ``G = sum h^2`` (Parseval: the fraction of white-noise power the filter
    passes, computed from ``h``) and ``lambda = (h^2 * image) / G`` the local level
    with the weights ``h^2`` (linear in the image, so unbiased). The pairs
    ``(lambda, r^2 / G)`` are grouped in bins of equal counts by ``lambda``; in
    each bin the variance is a clipped mean of ``r^2`` (3.5 robust standard
    deviations, the truncation divided out), and ``K``, ``L`` come from the
    weighted fit of these bin variances, as in single-image raw-data noise
    estimation (Foi et al. 2008). Pixels within the kernel's reach of the image
    border, of a pixel outside ``mask``, of a clipped pixel, or of the border of a
    region without a grid (fundamental modulus below a quarter of its median,
    evaluated from the image's spectrum near each fundamental on a grid of a few
    pixels) are left out; the inside of a hole, uniform, is noise and is kept. Confidence
    intervals come from the fit's covariance, with each
    bin's error from the chi-square law corrected for the correlation the filter
    puts between neighbouring residuals (``sum_d rho(d)^2``, from ``h``),
    inflated by the square root of the reduced chi-square when above 1.

    ``L`` is poorly pinned by one image (its levels span a narrow range far from 0:
    +-1117 around 1301 on 12-bit images stored x16, a fifth of the draws negative,
    while ``K`` stays within 1 %): its interval says so, and a negative fit, which
    no sensor gives, is refitted with ``L = 0`` (``K`` alone, the same weights),
    its interval ``[0, L + half-width]``. The variance at the image's levels, what
    the uncertainty maps use, moves by less than the fit's own error: the refit
    keeps the weighted residual least.

    Print texture (a static reflectance pattern) is not noise. A texture smooth
    over a few pixels modulates the harmonics and the zero frequency within their
    notches, which widen with the strength of their peak (15 % per decade above
    the noise floor), and is removed with the grid; what a texture holds at the
    scale of a pixel or two passes the filter and is counted as noise: the
    estimate is biased up by the texture's power in the kept band. Measured
    (``tests/test_noise_image.py``) on the variance at the mean level: +0.2 %
    for a 5 % texture smooth over 20 px (+0.6 % at 10 %), +1.6 % over 5 px,
    +7.5 % for a 2 % texture over 3 px and +37 % for 5 %. Without texture, on
    512 x 688 12-bit images stored x16 (checkerboards rotated 20 and -12 degrees
    at pitches 5.3 and 7.1, sharp lines at pitch 4, a sine grid at 6.2; a hole,
    lighting falling to 40 %): ``K`` within 1.5 % and the variance at the mean
    level within 0.8 %, in about 0.08 s (0.2 s at 1040 x 1376 px).

    References
    ----------
    A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical
    Poissonian-Gaussian noise modeling and fitting for single-image raw-data",
    IEEE Trans. Image Process. 17 (2008) 1737-1754. doi:10.1109/TIP.2008.2001399
    """
    img = as_image(image).astype(np.float64, copy=False)  # read only, never written
    H, W = img.shape
    if min(H, W) < 160:
        raise ValueError(f"image must be at least 160 x 160 px to estimate its noise, got "
                         f"{H} x {W}")
    lattice = check_type(lattice, "lattice", Lattice, allow_none=True)
    n_bins = check_int(n_bins, "n_bins", minimum=3)
    scale = check_positive(scale, "scale")
    m = check_mask(mask, img.shape)
    saturation = check_positive(saturation, "saturation", allow_none=True)
    bad = ~m | (img <= 0)
    if saturation is not None:
        bad |= img >= saturation
    if lattice is None:
        lattice = detect_lattice(img, mask=m)
    F = sfft.rfft2(img)
    edge = _gridless_borders(F, img.shape, lattice, m)
    # the kernel of a Gaussian notch of frequency std s is a Gaussian envelope of
    # 1 / (2 pi s) px (its square, of the double notch, is narrower): beyond 4.5 of
    # them a pixel's residual no longer sees an edge, a hole or a clipped pixel
    # on small images the notches widen so that the reach stays a sixth of the side
    notch = max(_NOTCH_STD, 4.5 / (2 * math.pi * min(H, W) / 6))
    reach = math.ceil(4.5 / (2 * math.pi * notch))
    tile = min(_TILE, 1 << math.floor(math.log2(min(H, W) / 2)))
    Hf, _ = _residual_filter(img.shape, lattice, _tile_spectrum(img, ~bad & ~edge, tile), notch)
    del img  # each full-size map is dropped once used
    # correlation of neighbouring residuals: Var(mean of n r^2) = 2 V^2 R / n
    A = np.abs(Hf) ** 2
    R = float(A.size * np.sum(A * A) / np.sum(A) ** 2)
    del A
    r, lam, G = _filtered_residual(F, Hf, (H, W))
    del F, Hf
    bad |= edge
    # nothing to keep away from (no mask, no clipped pixel, no gridless region): no
    # dilation, which costs 16 ms at 1040 x 1376 for nothing
    ok = ~ndimage.binary_dilation(bad, iterations=reach) if bad.any() else \
        np.ones(bad.shape, dtype=bool)
    ok[:reach] = ok[-reach:] = False
    ok[:, :reach] = ok[:, -reach:] = False
    n_bins = min(n_bins, np.count_nonzero(ok) // 200)
    if n_bins < 8:
        raise ValueError(f"too few usable pixels ({np.count_nonzero(ok)}) to estimate the "
                         "noise from this image (borders, masked, clipped and gridless "
                         "regions are left out with a band of "
                         f"{reach} px); a larger image or a noise model from a stack "
                         "helps")
    box = [lam[ok], r[ok]]
    del lam, r
    lb, vb, nbin = _binned_variances(box, n_bins, G)
    K, L, cov, chi2, err = _fit_binned(lb, vb, nbin, R)
    red, (sK, sL) = _intervals(cov, chi2, lb.size)
    L_ci = (max(0.0, L - sL), L + sL)  # a variance is not negative
    if L < 0:
        # the read-noise variance refitted at its bound, 0: K alone, same weights
        w = 1.0 / err**2
        K = float(np.sum(w * lb * vb) / np.sum(w * lb * lb))
        L, L_ci = 0.0, (0.0, max(L + sL, 0.0))
    return NoiseModel(K=K, L=L, K_ci=(K - sK, K + sK), L_ci=L_ci, scale=scale,
                      n_frames=1, n_pixels=int(np.count_nonzero(ok)), dof=None,
                      reduced_chi2=red, levels=lb, variances=vb, variance_errors=err,
                      method="single image", filter_gain=G)


def _gridless_borders(F, shape, lattice, mask) -> np.ndarray:
    """(H, W) bool: the borders of the regions without a grid (fundamental modulus
    below a quarter of its median), steps the grid-removal filter does not remove.

    ``F`` is the real 2-D FFT (``rfft2``) of the image of ``shape``. The moduli of
    the windowed transform at the two fundamentals (window of standard deviation
    the pitch) are band-limited: they
    are evaluated on a grid of about ``sigma / 1.5`` px from the spectrum within
    ``0.68 / sigma`` of each fundamental (the window's transfer falls below 1e-4
    beyond), one small inverse FFT each instead of a windowed Fourier transform of
    the whole image. The periodic extension this assumes only changes the moduli
    within a few windows of the image border, which the estimate leaves out anyway.
    """
    H, W = shape
    sigma = lattice.pitch
    band = 0.68 / sigma  # cycles/px: exp(-2 pi^2 sigma^2 band^2) < 1e-4
    by, bx = math.ceil(band * H), math.ceil(band * W)
    h, w = sfft.next_fast_len(2 * by + 1), sfft.next_fast_len(2 * bx + 1)
    dy, dx = np.arange(-by, by + 1), np.arange(-bx, bx + 1)
    mods = []
    for kx, ky in (lattice.k1, lattice.k2):
        ny, nx = round(ky * H), round(kx * W)
        rows, cols = (ny + dy) % H, (nx + dx) % W
        gy = transfer_function((ny + dy) / H - ky, sigma)
        gx = transfer_function((nx + dx) / W - kx, sigma)
        small = np.zeros((h, w), dtype=complex)
        small[np.ix_(dy % h, dx % w)] = _spectrum_at(F, rows, cols, W) * np.outer(gy, gx)
        # |sum_d F(k + d) G(d) exp(2 i pi d.x)| at x = (i H / h, j W / w): the modulus
        mods.append(np.abs(sfft.ifft2(small)) * (h * w) / (H * W))
    # back to pixels: each pixel takes the nearest coarse sample
    iy = np.rint(np.arange(H) * h / H).astype(int) % h
    ix = np.rint(np.arange(W) * w / W).astype(int) % w
    inner = np.zeros((H, W), dtype=bool)
    e = math.ceil(3 * sigma)
    inner[e:H - e, e:W - e] = True
    sel = mask & inner
    nogrid = np.zeros((H, W), dtype=bool)
    for mod in mods:
        full = mod[np.ix_(iy, ix)]
        ref = full[sel] if sel.any() else full.ravel().copy()
        nogrid |= full < 0.25 * median(ref, overwrite_input=True)
        del full, ref
    # the modulus marks a gridless region's border to within about two pitches, and
    # the coarse grid to within half its step
    band_px = math.ceil(2 * lattice.pitch + 0.5 * max(H / h, W / w))
    return ndimage.binary_dilation(nogrid, iterations=band_px) & ndimage.binary_dilation(
        ~nogrid, iterations=band_px)


def _spectrum_at(F, rows, cols, W):
    """The full 2-D FFT at ``rows`` x ``cols`` from the real one ``F`` (``rfft2`` of a
    real image of ``W`` columns), by :func:`gridstrain._wft._spectrum_block`, which
    takes its columns in increasing order."""
    order = np.argsort(cols, kind="stable")
    out = np.empty((rows.size, cols.size), dtype=F.dtype)
    out[:, order] = _spectrum_block(F, rows, cols[order], W)
    return out


def _filtered_residual(F, Hf, shape):
    """Residual ``r = h * img`` of the grid-removal filter of transfer ``Hf``, the
    local level ``lambda = (h^2 * img) / G`` and the filter's white-noise gain
    ``G = sum h^2`` (Parseval), from ``F`` the image's real 2-D FFT (``rfft2``):
    ``Hf`` is even (the harmonics come in opposite pairs), so ``h`` is real and its
    half spectrum is enough."""
    half = Hf[:, :F.shape[1]]
    G = float(np.mean(Hf * Hf))  # Parseval: sum h^2, the white-noise power passed
    # one full-size map at a time beside F: h^2's transform, then each product in place
    h = sfft.irfft2(half, s=shape)
    np.multiply(h, h, out=h)
    spec = sfft.rfft2(h)
    del h
    lam = sfft.irfft2(np.multiply(spec, F, out=spec), s=shape)
    del spec
    lam /= G
    spec = np.multiply(F, half)
    r = sfft.irfft2(spec, s=shape)
    return r, lam, G


def _binned_variances(box: list, n_bins, G):
    """Per bin of equal counts by level ``lv``: mean level, clipped variance of the
    residuals ``rv`` divided by the filter gain ``G``, and the pixel count (bins of
    fewer than 50 pixels are dropped). ``box`` is ``[lv, rv]``, handed over: each
    is dropped once sorted by bin."""
    lv = box[0]
    # bins of about equal counts: the edges are quantiles of every 8th pixel (the
    # counts vary by about 1 %, and each bin's count weighs its variance), the two
    # outer ones the extremes of all, so that every pixel falls in a bin
    edges = np.quantile(lv[::8], np.linspace(0, 1, n_bins + 1))
    edges[0], edges[-1] = lv.min(), lv.max()
    edges = np.unique(edges)
    nb = edges.size - 1
    if nb < 3:
        raise ValueError("the image spans too narrow a range of levels to fit "
                         "Var = K l + L")
    idx = np.clip(np.searchsorted(edges, lv, side="right") - 1, 0, nb - 1).astype(np.int16)
    lb, vb, nbin = [], [], []
    # a stable sort of small integers is a radix sort
    order = np.argsort(idx, kind="stable")
    splits = np.cumsum(np.bincount(idx, minlength=nb))[:-1]
    del idx
    lv = box.pop(0)[order]
    rv = box.pop(0)[order]
    del order
    for lg, rg in zip(np.split(lv, splits), np.split(rv, splits), strict=True):
        if lg.size < 50:
            continue
        lb.append(float(lg.mean()))
        vb.append(_clipped_variance(rg) / G)
        nbin.append(lg.size)
    lb, vb, nbin = np.array(lb), np.array(vb), np.array(nbin, dtype=np.float64)
    if lb.size < 3:
        raise ValueError("too few intensity bins to fit Var = K l + L")
    return lb, vb, nbin


def _fit_binned(lb, vb, nbin, R):
    """``K``, ``L``, their covariance, the chi-square and the bin errors of the
    weighted fit of ``Var = K l + L`` to the bin variances, the weights from the
    chi-square law with the residuals' correlation factor ``R``, iterated."""
    K, L = np.polyfit(lb, vb, 1)
    for _ in range(20):
        model = np.maximum(K * lb + L, 1e-6 * float(np.median(vb)))
        err = model * np.sqrt(2 * R / nbin)
        (K_new, L_new), cov, chi2 = _wls(lb, vb, err)
        done = _settled(K, L, K_new, L_new, float(np.mean(lb)), 1e-9)
        K, L = float(K_new), float(L_new)
        if done:
            break
    if not K > 0:
        raise ValueError(f"no signal-dependent noise found in the image (fitted K = {K:.3g}); "
                         "it may be processed (denoised, compressed) or hold no grid")
    return K, L, cov, chi2, err
