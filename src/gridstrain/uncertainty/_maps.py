"""Uncertainty maps: the predicted standard deviation of every result, per pixel.

The sensor noise is Poisson-Gaussian, ``Var = K l + L`` for a pixel of expected grey
level ``l`` (paper §2, Prop. 2.3). Through the windowed Fourier transform it becomes
phase and phase-derivative noise whose small-noise standard deviations are known in
closed form (:func:`gridstrain.theory.wft_noise_std`); this module evaluates them
pixel by pixel from the local noise variance and the local fringe modulus
``|Psi|``, then propagates them through eqs. (34)-(35) to the displacement and the
strain. Conventions: :mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .. import _stats
from .._runtime import compiled
from .._validation import (
    as_float_array,
    as_image,
    check_finite,
    check_int,
    check_positive,
    check_same_shape,
    check_type,
)
from ..phase import PhaseMaps, filled_box
from ..theory import window_energy

__all__ = ["NoiseFloor", "Uncertainty", "displacement_strain_std", "metrology", "noise_floor",
           "noise_variance_map", "predict_uncertainty"]

#: Full width at half maximum of a Gaussian over its standard deviation.
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
#: Attenuation of a sine displacement that defines the spatial resolution: its period
#: is the one the window damps by 10 % (Grédiac, Blaysat & Sur 2017; DIC Challenge 2.0).
_ATTENUATION = 0.1
#: Spatial resolution over sigma. The maps are the true fields convolved with the
#: window ``g`` (eqs. 24-25), whose transfer for a sine of period ``d`` is
#: ``exp(-2 pi^2 sigma^2 / d^2)``; setting it to ``1 - 0.1`` gives
#: ``d = pi sigma sqrt(2 / ln(1 / 0.9))`` = 13.69 sigma.
SPATIAL_RESOLUTION_PER_SIGMA = math.pi * math.sqrt(2.0 / -math.log(1.0 - _ATTENUATION))
#: Width over which the window's response to a step rises from 10 % to 90 %, over
#: sigma: the step is smoothed into an error function, 2 x 1.2816 sigma.
_STEP_10_90 = 2.0 * 1.2815515655446004


# The g^2-weighted mean (noise_weighted) runs in the compiled loop of
# gridstrain.uncertainty._kernels (numba, the "fast" extra) when installed, loaded on
# its first use: scipy's filter, the same bits, in a third of its time (its loops
# vectorised). False forces scipy's (what a machine without numba runs).
_COMPILED = True
# g^2 truncated at this many of its standard deviations
_G2_TRUNCATE = 5.0


@functools.cache
def _load_kernels():
    """The module of compiled loops (:func:`gridstrain._runtime.compiled.load`), or None."""
    return compiled.load(__package__, "._kernels")


def _kernels():
    """:func:`_load_kernels`, unless the compiled loops are switched off."""
    return _load_kernels() if _COMPILED else None


@functools.lru_cache(maxsize=8)
def _half_kernel(sd: float) -> np.ndarray:
    """scipy's Gaussian kernel of std ``sd`` truncated at ``_G2_TRUNCATE`` stds (that
    of ``ndimage.gaussian_filter1d``, normalised to a sum of 1), from its centre tap
    on: ``[w_0, w_1, ..., w_r]``, read-only."""
    r = int(_G2_TRUNCATE * sd + 0.5)
    x = np.arange(-r, r + 1)
    phi = np.exp(-0.5 / (sd * sd) * x**2)
    phi = phi / phi.sum()
    half = np.ascontiguousarray(phi[r:])
    half.flags.writeable = False
    return half


def _rows(a: np.ndarray, n: int) -> np.ndarray:
    """``a`` as ``n`` contiguous float64 (or bool) rows of its pixels, for the compiled
    loops (a view when it is one already)."""
    return np.ascontiguousarray(a).reshape(n, -1)


def noise_weighted(values, sigma: float, *, where=None) -> np.ndarray:
    """``values`` (H, W) averaged with the weight each pixel's noise has in ``Psi``:
    ``g^2``, a Gaussian of std ``sigma / sqrt 2`` (truncated at 5 of its stds, the
    borders continued by their nearest pixel); float64.

    ``scipy.ndimage.gaussian_filter(values, sigma / sqrt(2), mode="nearest",
    truncate=5.0)``, the same bits: by the compiled loop of
    :mod:`gridstrain.uncertainty._kernels` on a float64 map when numba is installed
    (0.5 against 1.6 ms at 250 x 400 px and sigma = 5 px, one core), by scipy
    otherwise.

    With ``where`` (H, W) bool, the pixels the caller reads: the mean is made over
    the rows and columns of the box that holds them (the same bits there), NaN
    elsewhere; a state's maps, whose uncertainty is read at its valid pixels alone,
    skip the margin (0.82 -> 0.62 ms at 250 x 400 px, sigma = 5 px and a margin of
    20 px, one core).
    """
    a = np.asarray(values)
    sd = sigma / math.sqrt(2)
    kern = _kernels()
    box = None if where is None else _bounding_box(np.asarray(where, dtype=bool))
    # scipy leaves an axis unfiltered for a std of 1e-15 or less
    if kern is None or a.dtype != np.float64 or a.ndim != 2 or a.size == 0 \
            or not sd > 1e-15:
        out = ndimage.gaussian_filter(a.astype(np.float64, copy=False), sd, mode="nearest",
                                      truncate=_G2_TRUNCATE)
        if box is not None:
            outside = np.ones(out.shape, dtype=bool)
            outside[box[0]:box[1], box[2]:box[3]] = False
            out[outside] = np.nan
        return out
    a = np.ascontiguousarray(a)
    if box is None:
        out = np.empty(a.shape)
        kern.gaussian_nearest(a, _half_kernel(float(sd)), np.empty(a.shape), out)
        return out
    out = np.full(a.shape, np.nan)
    if box[0] < box[1]:
        kern.gaussian_nearest_box(a, _half_kernel(float(sd)), np.empty(a.shape), out, *box)
    return out


def _bounding_box(where: np.ndarray) -> tuple[int, int, int, int]:
    """``(r0, r1, c0, c1)``: the smallest box of rows ``r0:r1`` and columns ``c0:c1``
    that holds the True pixels of ``where`` (an empty box, ``(0, 0, 0, 0)``, for none)."""
    rows = np.flatnonzero(where.any(axis=1))
    if rows.size == 0:
        return 0, 0, 0, 0
    cols = np.flatnonzero(where.any(axis=0))
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


@dataclass(frozen=True, eq=False)
class Uncertainty:
    """Predicted standard deviations of a measurement, per pixel.

    Attributes
    ----------
    u_std : (2, H, W) ndarray
        Std of ``(u_x, u_y)``, px.
    strain_std : (3, H, W) ndarray
        Std of ``(eps_xx, eps_yy, eps_xy)``, dimensionless.
    phase_std : (2, 2, H, W) ndarray
        Std of the phases, rad: ``[state, wave vector]`` with state 0 the
        reference and 1 the deformed image.
    dphi_std : (2, 2, H, W) ndarray
        Std of each phase derivative (along x or y alike), rad/px, indexed as
        ``phase_std``.
    valid : (H, W) bool ndarray
        Where the prediction applies (NaN elsewhere).
    """

    u_std: np.ndarray
    strain_std: np.ndarray
    phase_std: np.ndarray
    dphi_std: np.ndarray
    valid: np.ndarray

    def __post_init__(self):
        for name in ("u_std", "strain_std", "phase_std", "dphi_std", "valid"):
            getattr(self, name).flags.writeable = False

    def median(self) -> dict[str, float]:
        """Median over the valid pixels of each map: a one-line noise floor."""
        v = self.valid
        names = ("ux", "uy", "exx", "eyy", "exy")
        maps = (*self.u_std, *self.strain_std)
        if not v.any():
            return dict.fromkeys(names, math.nan)
        # each m[v] is a fresh gather: partially sorted in place, not copied again
        return {n: _stats.median(m[v], overwrite_input=True)
                for n, m in zip(names, maps, strict=True)}


def noise_variance_map(mean_image, *, K: float, L: float, sigma: float,
                       frames: int = 1) -> np.ndarray:
    """Variance of the noise of an averaged image, as the WFT window sees it.

    Parameters
    ----------
    mean_image : (H, W) array_like
        The (time-averaged) grid image, grey levels.
    K, L : float
        Sensor noise model ``Var = K l + L`` in the image's grey levels.
    sigma : float
        Window standard deviation, px.
    frames : int
        Number ``T`` of frames averaged (method A) or per-frame results averaged
        (method B): the variance is divided by ``T`` (Prop. 2.3, eq. 19).

    Returns
    -------
    (H, W) float64 ndarray
        ``(K lbar + L) / T`` with ``lbar`` the mean grey level weighted by ``g^2``,
        the weight each pixel's noise has in ``Psi`` (``g^2`` is a Gaussian of std
        ``sigma / sqrt 2``): the signal-dependent noise is white but not uniform,
        and this is its local level.
    """
    img = as_image(mean_image, "mean_image", allow_uniform=True).astype(np.float64)
    K = check_positive(K, "K")
    # a fitted L may come out below zero when the read noise is small (its
    # interval then holds zero): the model stands at the levels it was fitted on
    L = check_finite(L, "L")
    sigma = check_positive(sigma, "sigma")
    frames = check_int(frames, "frames")
    local = noise_weighted(img, sigma)
    return np.maximum(K * np.maximum(local, 0.0) + L, 0.0) / int(frames)


def _as_map(v, shape, name):
    """A non-negative variance, scalar or per pixel, as a finite (H, W) float64 map."""
    a = as_float_array(v, name, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(shape, float(a))
    if a.shape != tuple(shape):
        raise ValueError(f"{name} must be a scalar or an array of shape {tuple(shape)}, "
                         f"got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name} must be finite and non-negative")
    return a


def predict_uncertainty(reference: PhaseMaps, deformed: PhaseMaps, *, variance_ref,
                        variance_def, valid=None) -> Uncertainty:
    """Standard deviation maps of phases, derivatives, displacement and strain.

    Parameters
    ----------
    reference, deformed : PhaseMaps
        The two states' transforms (single images or stack averages).
    variance_ref, variance_def : float or (H, W) array_like
        Noise variance of each state's (averaged) image, grey levels^2 (see
        :func:`noise_variance_map`).
    valid : (H, W) bool array_like, optional
        Pixels to report (default: valid in both maps).

    Returns
    -------
    Uncertainty

    Notes
    -----
    At each pixel and for each wave vector ``j``:
    ``Std(phi_j) = sqrt(v sum g^2 / 2) / |Psi_j|`` and
    ``Std(dphi_j) = sqrt(v sum g'^2 / 2) / |Psi_j|`` (small-noise theory, paper §2.2;
    see :func:`gridstrain.theory.wft_noise_std`). The reference and deformed maps
    are independent, and so are ``d/dx`` and ``d/dy`` of a phase at one pixel
    (``sum g g' = 0``). With ``M = K^-1 / 2 pi``:
    ``Var(u_i) = sum_j M_ij^2 (s_ref,j^2 + s_def,j^2)`` (eq. 34) and
    ``Var(G_im) = sum_j M_ij^2 (d_ref,j^2 + d_def,j^2)`` (eq. 35), so that
    ``Std(eps_xy) = sqrt(Var G_01 + Var G_10) / 2``. The deformed state's values
    are taken at the same pixel: its modulus and noise vary on the scale of the
    specimen, not of the displacement. A spatially constant phase offset from
    vibrations (Prop. 2.4) is a rigid-body term and is not in these maps.
    """
    check_type(reference, "reference", PhaseMaps)
    check_type(deformed, "deformed", PhaseMaps)
    check_same_shape(deformed.shape, reference.shape, "deformed maps", "the reference")
    shape = reference.shape
    v_ref = _as_map(variance_ref, shape, "variance_ref")
    v_def = _as_map(variance_def, shape, "variance_def")
    if valid is None:
        valid = reference.valid & deformed.valid
    valid = np.asarray(valid, dtype=bool)
    check_same_shape(valid.shape, shape, "valid", "the maps")
    g2, dg2 = window_energy(reference.sigma)

    phase_std = np.empty((2, 2, *shape))
    dphi_std = np.empty((2, 2, *shape))
    for s, (pm, v) in enumerate(((reference, v_ref), (deformed, v_def))):
        mod = np.abs(pm.psi).astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            for j in range(2):
                phase_std[s, j] = np.sqrt(v * g2 / 2) / mod[j]
                dphi_std[s, j] = np.sqrt(v * dg2 / 2) / mod[j]
    u_std, strain_std = displacement_strain_std(reference, deformed, variance_ref=v_ref,
                                                variance_def=v_def, valid=valid)
    nan = ~valid
    for a in (phase_std, dphi_std):
        a[..., nan] = np.nan
    return Uncertainty(u_std=u_std, strain_std=strain_std, phase_std=phase_std,
                       dphi_std=dphi_std, valid=valid)


def displacement_strain_std(reference: PhaseMaps, deformed: PhaseMaps, *, variance_ref,
                            variance_def, valid) -> tuple[np.ndarray, np.ndarray]:
    """The ``u_std`` (2, H, W) and ``strain_std`` (3, H, W) of
    :func:`predict_uncertainty` alone, with a few maps of memory instead of twenty.

    The derivatives' variances are the phases' times ``dg2 / g2`` (same moduli and
    sensor variance, eqs. 23-25 of the window's energies), so that the strain's
    variance is the displacement's times that ratio: only the two phase variances
    are formed. The arguments are those of :func:`predict_uncertainty`, already
    checked (``valid`` given).
    """
    return std_from_phase_variance(phase_variance(reference, variance_ref), deformed,
                                    variance_def=variance_def, valid=valid)


def phase_variance(maps: PhaseMaps, variance) -> np.ndarray:
    """(2, H, W) variance of each wave vector's phase in ``maps``, rad^2, from the
    sensor's per-pixel ``variance`` (eq. 23): one side of
    :func:`displacement_strain_std`, made once for a reference measured against many
    states."""
    g2, _ = window_energy(maps.sigma)
    out = np.zeros((2, *maps.shape))
    with np.errstate(divide="ignore", invalid="ignore"):
        vg = np.asarray(variance, dtype=np.float64) * (g2 / 2)
        for j in range(2):
            m2 = np.abs(maps.psi[j]).astype(np.float64, copy=False)
            m2 *= m2
            out[j] += vg / m2
    return out


def std_from_phase_variance(var_ref_phase: np.ndarray, deformed: PhaseMaps, *,
                             variance_def, valid, medians: bool = False) -> tuple:
    """:func:`displacement_strain_std` with the reference's phase variance given
    (:func:`phase_variance`).

    With ``medians``, also the median of each of the five maps over the ``valid``
    pixels, ``[ux, uy, exx, eyy, exy]`` (:func:`gridstrain._stats.median`'s values):
    ``u_std`` and the normal strains' std are non-decreasing functions of one
    displacement variance each (its square root, and that of its product by
    ``dg2 / g2``), so that one selection of that variance's middle values gives both
    medians (:func:`gridstrain._stats.middle_values`). The variances are sums of
    products of non-negative numbers (or NaN where ``Psi = 0``): no square root of a
    negative one makes a NaN that the selection would not see.
    """
    g2, dg2 = window_energy(deformed.sigma)
    shape = deformed.shape
    kern = _kernels()
    variance_def = np.asarray(variance_def, dtype=np.float64)
    if kern is not None and (variance_def.shape != shape
                             or np.asarray(var_ref_phase).dtype != np.float64):
        kern = None  # a scalar variance (numpy's broadcasting), or another precision
    with np.errstate(divide="ignore", invalid="ignore"):
        if kern is not None:  # one pass, the same operations (_kernels)
            var_phase = np.empty((2, *shape))
            mod = np.abs(deformed.psi).astype(np.float64, copy=False)
            kern.phase_variance_sum(_rows(var_ref_phase, 2), _rows(variance_def, 1)[0],
                                    _rows(mod, 2), g2 / 2, var_phase.reshape(2, -1))
            del mod
        else:
            var_phase = var_ref_phase.copy()
            vg = variance_def * (g2 / 2)
            for j in range(2):
                m2 = np.abs(deformed.psi[j]).astype(np.float64, copy=False)
                m2 *= m2
                var_phase[j] += vg / m2
        M2 = (np.linalg.inv(deformed.lattice.K) / (2 * np.pi)) ** 2
        # where Psi = 0 (no signal) the variance is inf, and 0 x inf NaN: invalid pixels
        var_u = np.tensordot(M2, var_phase, axes=1)  # (2, H, W), eq. (34)
    del var_phase
    valid = np.asarray(valid, dtype=bool)
    ratio = dg2 / g2
    # the displacement variances' middle values over the valid pixels: the box they
    # fill (a view, not to be sorted in place), else their gather
    box = filled_box(valid) if medians else None

    def at_valid(a):
        """``(values, whether they may be sorted in place)``"""
        if box is None:
            return a[valid], True
        r0, r1, c0, c1 = box
        return a[r0:r1, c0:c1], False

    pairs = []
    for i in range(2 if medians else 0):
        values, own = at_valid(var_u[i])
        pairs.append(_stats.middle_values(values, overwrite_input=own))
    # eq. (35): m = x and m = y alike; the strains' variances formed in their output
    strain_std = np.empty((3, *shape))
    if kern is not None:  # one pass, the same operations (_kernels)
        # u_std in a map of its own: outputs apart from the inputs vectorise
        u_std = np.empty((2, *shape))
        kern.std_from_variance(_rows(var_u, 2), _rows(valid, 1)[0], ratio,
                               u_std.reshape(2, -1), strain_std.reshape(3, -1))
    else:
        np.multiply(var_u, ratio, out=strain_std[:2])
        np.add(strain_std[0], strain_std[1], out=strain_std[2])
        strain_std[2] *= 0.25
        np.sqrt(strain_std, out=strain_std)
        u_std = np.sqrt(var_u, out=var_u)
        nan = ~valid
        np.copyto(u_std, np.nan, where=nan)
        np.copyto(strain_std, np.nan, where=nan)
    if not medians:
        return u_std, strain_std
    n = int(np.count_nonzero(valid))

    def mid(pair, f):  # median's arithmetic on f of the middle values
        lower, upper = f(pair[0]), f(pair[1])
        return float(upper) if n % 2 else float((lower + upper) / 2)

    found = [mid(p, np.sqrt) for p in pairs]
    found += [mid(p, lambda v: np.sqrt(v * ratio)) for p in pairs]
    values, own = at_valid(strain_std[2])
    found.append(_stats.median(values, overwrite_input=own))
    return u_std, strain_std, found


@dataclass(frozen=True, eq=False)
class NoiseFloor:
    """The noise floor of displacement and strain, per state: measured or predicted.

    One type for both: :func:`gridstrain.measure_series` gives the floor of the
    maps of each loaded state it measured (``SeriesResult.noise``), and
    :func:`noise_floor` predicts that of a planned measurement (one state against
    a reference, from a camera model). Every ``*_u`` array is ``(n_states, 2)`` for
    ``(u_x, u_y)`` in px, every ``*_strain`` array ``(n_states, 3)`` for ``(e_xx,
    e_yy, e_xy)`` (dimensionless); NaN where the estimate is unavailable. The
    values are one standard deviation at a pixel.

    Attributes
    ----------
    sigma : float
        Window standard deviation, px. The spatial resolution
        (:attr:`spatial_resolution`, 13.69 sigma) and the window's FWHM
        (:attr:`window_fwhm`, 2.355 sigma) follow from it.
    sensor_variance : (n_series,) tuple of float
        Per-frame image noise variance of each series (reference first), raw
        grey levels^2, NaN for a single frame.
    variance_method : (n_series,) tuple of str
        How each variance was obtained.
    modulus : (n_series, 2) ndarray
        Median ``|Psi|`` of each series' phase maps over their valid pixels, raw
        grey levels.
    theory_u, theory_strain : ndarray
        Windowed-Fourier noise theory (eqs. 23-25, 34-35) with those variances,
        reference and state together.
    split_u, split_strain : ndarray
        Measured: the reference split into halves, scaled to each state's frame
        counts (NaN for a prediction).
    vibration_u : ndarray
        Standard deviation of the constant vibration offset of the displacement
        (reference and state together), px (NaN for a prediction).
    model : dict, optional
        Where the image noise came from: ``source`` ("stack", "single image",
        "given" or a mix per series), and the camera model ``Var = K l + L`` used
        where one was (:meth:`gridstrain.uncertainty.NoiseModel.as_dict`).
    frames : (n_series,) tuple of int, optional
        Frames averaged in each series (reference first).
    theory_phase : (n_states, 2) ndarray, optional
        Per wave vector, the std of one state's phase, rad (given by
        :func:`noise_floor`; None otherwise).
    theory_dphi : (n_states, 2) ndarray, optional
        Per wave vector, the std of one state's phase derivative along x, rad/px
        (as ``theory_phase``).
    """

    sigma: float
    sensor_variance: tuple[float, ...]
    variance_method: tuple[str, ...]
    modulus: np.ndarray
    theory_u: np.ndarray
    theory_strain: np.ndarray
    split_u: np.ndarray
    split_strain: np.ndarray
    vibration_u: np.ndarray
    model: dict | None = None
    frames: tuple[int, ...] | None = None
    theory_phase: np.ndarray | None = None
    theory_dphi: np.ndarray | None = None

    def __post_init__(self):
        for name in ("modulus", "theory_u", "theory_strain", "split_u", "split_strain",
                     "vibration_u", "theory_phase", "theory_dphi"):
            a = getattr(self, name)
            if a is not None:
                a.flags.writeable = False

    @property
    def spatial_resolution(self) -> float:
        """The period of a sine displacement the window damps by 10 %, px
        (``13.69 sigma``; :func:`metrology`)."""
        return SPATIAL_RESOLUTION_PER_SIGMA * self.sigma

    @property
    def window_fwhm(self) -> float:
        """Full width at half maximum of the Gaussian window, ``2.355 sigma``, px."""
        return FWHM_PER_SIGMA * self.sigma

    def as_dict(self) -> dict:
        """Plain-Python summary (lists, floats, NaN as None), for JSON and HDF5."""
        def clean(a):
            return [None if not math.isfinite(v) else float(v)
                    for v in np.asarray(a, dtype=float).ravel()]

        out = {"sigma_px": self.sigma, "spatial_resolution_px": self.spatial_resolution,
               "window_fwhm_px": self.window_fwhm,
               "resolution_definition": _DEFINITIONS["spatial_resolution"],
               "sensor_variance": clean(self.sensor_variance),
               "variance_method": list(self.variance_method),
               "modulus": [clean(m) for m in self.modulus]}
        for name in ("theory_u", "theory_strain", "split_u", "split_strain", "vibration_u",
                     "theory_phase", "theory_dphi"):
            a = getattr(self, name)
            if a is not None:
                out[name] = [clean(row) for row in a]
        if self.frames is not None:
            out["frames"] = list(self.frames)
        out["model"] = self.model
        return out


def noise_floor(maps: PhaseMaps, mean_image, *, K: float, L: float,
                frames: int = 1) -> NoiseFloor:
    """Predicted noise floor of a measurement between two states like ``maps``.

    Parameters
    ----------
    maps : PhaseMaps
        Transform of a representative (averaged) image of the specimen.
    mean_image : (H, W) array_like
        That image, grey levels.
    K, L : float
        Sensor noise ``Var = K l + L``, in the image's grey levels.
    frames : int
        ``T``, frames averaged per state (reference and deformed alike).

    Returns
    -------
    NoiseFloor
        For one state (``n_states = 1``) against a reference, both of ``T``
        independent frames with the same noise: the medians over the valid pixels
        of the maps of :func:`predict_uncertainty` (``theory_*``), the image's
        per-frame variance at its median grey level (``sensor_variance``), the
        median moduli; ``split_*`` and ``vibration_u`` are NaN (nothing measured).
    """
    check_type(maps, "maps", PhaseMaps)
    var = noise_variance_map(mean_image, K=K, L=L, sigma=maps.sigma, frames=frames)
    unc = predict_uncertainty(maps, maps, variance_ref=var, variance_def=var)
    v = unc.valid
    if not v.any():
        raise ValueError("maps have no valid pixel: no noise floor can be predicted")
    img = np.asarray(mean_image, dtype=np.float64)

    def med(a):
        return _stats.median(a[v], overwrite_input=True)

    level = med(img)
    modulus = [med(np.abs(p)) for p in maps.psi]
    how = f"camera model Var = K l + L at the median grey level {level:.6g}"
    return NoiseFloor(
        sigma=maps.sigma,
        sensor_variance=(float(K * level + L),) * 2, variance_method=(how, how),
        modulus=np.array([modulus, modulus]),
        theory_u=np.array([[med(a) for a in unc.u_std]]),
        theory_strain=np.array([[med(a) for a in unc.strain_std]]),
        split_u=np.full((1, 2), np.nan), split_strain=np.full((1, 3), np.nan),
        vibration_u=np.full((1, 2), np.nan),
        model={"source": "given", "K": float(K), "L": float(L)},
        frames=(int(frames),) * 2,
        theory_phase=np.array([[med(a) for a in unc.phase_std[0]]]),
        theory_dphi=np.array([[med(a) for a in unc.dphi_std[0]]]))


# --------------------------------------------------------------------------- metrology


_DEFINITIONS = {
    "resolution": "one standard deviation of the noise at a pixel (median of the predicted "
                  "std map)",
    "spatial_resolution": "d, the period of a sine displacement the Gaussian window damps "
                          "by 10 %: pi sigma sqrt(2 / ln(1 / 0.9)) = 13.69 sigma (Grediac, "
                          "Blaysat & Sur 2017; DIC Challenge 2.0)",
    "window_fwhm": "FWHM of the Gaussian window, 2 sqrt(2 ln 2) sigma = 2.355 sigma",
    "step_width": "distance over which a step rises from 10 % to 90 %, 2.563 sigma",
    "efficiency": "metrological efficiency indicator: displacement resolution x d (px^2); "
                  "strain resolution x d^2 (px^2); d the spatial resolution; independent "
                  "of sigma; lower is better",
}


def metrology(resolutions, sigma: float) -> dict:
    """Metrological figures of each map: resolution, spatial resolution, efficiency.

    Parameters
    ----------
    resolutions : sequence of dict
        Per state, the resolution (one standard deviation of the noise at a pixel)
        of each map: ``{"ux": px, "uy": px, "exx": 1, "eyy": 1, "exy": 1}``.
    sigma : float
        Window standard deviation, px.

    Returns
    -------
    dict
        ``sigma_px``, ``spatial_resolution_px`` (``d``, the period of a sine
        displacement damped by 10 %, ``13.69 sigma``), ``window_fwhm_px`` (``2.355
        sigma``), ``step_width_px`` (10-90 % rise of the response to a step,
        ``2.563 sigma``), ``definitions`` and ``units``, and ``states``: per state
        and map, ``resolution`` and ``efficiency``.

    Notes
    -----
    The maps are the true fields convolved with the window ``g`` (eqs. 24-25); a
    sine displacement of period ``d`` comes out multiplied by the window's transfer
    function ``exp(-2 pi^2 sigma^2 / d^2)``. The grid-method literature and the DIC
    Challenge 2.0 take as spatial resolution the period damped by 10 % (Grédiac,
    Blaysat & Sur, "A critical comparison of some metrological parameters
    characterizing local digital image correlation and grid method", Exp. Mech. 57
    (2017) 871-903, doi:10.1007/s11340-017-0279-x; Reu et al., "DIC Challenge 2.0",
    Exp. Mech. 62 (2022) 639-654, doi:10.1007/s11340-021-00806-6), so that

        ``d = pi sigma sqrt(2 / ln(1 / 0.9)) = 13.69 sigma``.

    The same papers couple resolution and spatial resolution in one *metrological
    efficiency indicator*, constant for a given camera and grid whatever the window
    (lower is better):

    - displacement: ``alpha_u = sigma_u d``, px^2;
    - strain: ``alpha_e = sigma_e d^2``, px^2.

    With the windowed Fourier transform the displacement noise falls as ``1 /
    sigma`` and the strain noise as ``1 / sigma^2`` (eqs. 34-35 with
    :func:`gridstrain.theory.wft_noise_std`), so both are independent of
    ``sigma``. The window's FWHM (``2.355 sigma``) is given beside ``d`` under its
    own name; figures computed on it are 5.8 (u) and 34 (strain) times smaller.
    """
    sigma = check_positive(sigma, "sigma")
    d = SPATIAL_RESOLUTION_PER_SIGMA * sigma
    states = []
    for res in resolutions:
        entry = {}
        for name, r in res.items():
            power = 1 if name in ("ux", "uy") else 2
            ok = r is not None and math.isfinite(r)
            entry[name] = {"resolution": float(r) if ok else None,
                           "efficiency": float(r) * d**power if ok else None}
        states.append(entry)
    return {"sigma_px": sigma, "spatial_resolution_px": d,
            "window_fwhm_px": FWHM_PER_SIGMA * sigma, "step_width_px": _STEP_10_90 * sigma,
            "definitions": dict(_DEFINITIONS),
            "units": {"ux": "px", "uy": "px", "exx": "1", "eyy": "1", "exy": "1",
                      "efficiency_u": "px^2", "efficiency_strain": "px^2"},
            "states": states}
