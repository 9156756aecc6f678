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

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from . import _stats
from ._validation import (
    as_float_array,
    as_image,
    check_finite,
    check_int,
    check_positive,
    check_same_shape,
    check_type,
)
from .theory import window_energy
from .wft import PhaseMaps

__all__ = ["NoiseFloor", "Uncertainty", "aliasing_bias", "displacement_strain_std",
           "metrology", "noise_floor", "noise_variance_map", "predict_uncertainty",
           "smoothing_bias"]

#: Full width at half maximum of a Gaussian over its standard deviation.
_FWHM = 2.0 * math.sqrt(2.0 * math.log(2.0))
#: Attenuation of a sine displacement that defines the spatial resolution: its period
#: is the one the window damps by 10 % (Grédiac, Blaysat & Sur 2017; DIC Challenge 2.0).
_ATTENUATION = 0.1
#: Spatial resolution over sigma. The maps are the true fields convolved with the
#: window ``g`` (eqs. 24-25), whose transfer for a sine of period ``d`` is
#: ``exp(-2 pi^2 sigma^2 / d^2)``; setting it to ``1 - 0.1`` gives
#: ``d = pi sigma sqrt(2 / ln(1 / 0.9))`` = 13.69 sigma.
_D_PER_SIGMA = math.pi * math.sqrt(2.0 / -math.log(1.0 - _ATTENUATION))
#: Width over which the window's response to a step rises from 10 % to 90 %, over
#: sigma: the step is smoothed into an error function, 2 x 1.2816 sigma.
_STEP_10_90 = 2.0 * 1.2815515655446004


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
    local = ndimage.gaussian_filter(img, sigma / math.sqrt(2), mode="nearest", truncate=5.0)
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
    return _displacement_strain_std(_phase_variance(reference, variance_ref), deformed,
                                    variance_def=variance_def, valid=valid)


def _phase_variance(maps: PhaseMaps, variance) -> np.ndarray:
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


def _displacement_strain_std(var_ref_phase: np.ndarray, deformed: PhaseMaps, *,
                             variance_def, valid) -> tuple[np.ndarray, np.ndarray]:
    """:func:`displacement_strain_std` with the reference's phase variance given
    (:func:`_phase_variance`)."""
    g2, dg2 = window_energy(deformed.sigma)
    shape = deformed.shape
    var_phase = var_ref_phase.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        vg = np.asarray(variance_def, dtype=np.float64) * (g2 / 2)
        for j in range(2):
            m2 = np.abs(deformed.psi[j]).astype(np.float64, copy=False)
            m2 *= m2
            var_phase[j] += vg / m2
        M2 = (np.linalg.inv(deformed.lattice.K) / (2 * np.pi)) ** 2
        # where Psi = 0 (no signal) the variance is inf, and 0 x inf NaN: invalid pixels
        var_u = np.tensordot(M2, var_phase, axes=1)  # (2, H, W), eq. (34)
    del var_phase
    # eq. (35): m = x and m = y alike; the strains' variances formed in their output
    strain_std = np.empty((3, *shape))
    np.multiply(var_u, dg2 / g2, out=strain_std[:2])
    np.add(strain_std[0], strain_std[1], out=strain_std[2])
    strain_std[2] *= 0.25
    np.sqrt(strain_std, out=strain_std)
    u_std = np.sqrt(var_u, out=var_u)
    nan = ~np.asarray(valid, dtype=bool)
    u_std[:, nan] = np.nan
    strain_std[:, nan] = np.nan
    return u_std, strain_std


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
        where one was (:meth:`gridstrain.noise.NoiseModel.as_dict`).
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
        return _D_PER_SIGMA * self.sigma

    @property
    def window_fwhm(self) -> float:
        """Full width at half maximum of the Gaussian window, ``2.355 sigma``, px."""
        return _FWHM * self.sigma

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
    d = _D_PER_SIGMA * sigma
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
            "window_fwhm_px": _FWHM * sigma, "step_width_px": _STEP_10_90 * sigma,
            "definitions": dict(_DEFINITIONS),
            "units": {"ux": "px", "uy": "px", "exx": "1", "eyy": "1", "exy": "1",
                      "efficiency_u": "px^2", "efficiency_strain": "px^2"},
            "states": states}


# --------------------------------------------------------------------------- systematics

# The smoothing bias's bound over its second-order estimate: Gaussian features 1.5 to
# 3 sigma wide have actual peak errors 1.25 to 2.5 times the estimate (smoothing_bias).
_SMOOTHING_FACTOR = 3.0
# The surroundings a feature's departure is taken from, in sigmas: a feature up to 3
# sigma wide (std) stands out of the median over them.
_BACKGROUND_SIGMAS = 20.0

# Harmonic orders of the line profile considered for aliasing.
_ALIAS_ORDERS = range(2, 16)
# Harmonics above this spatial frequency, cycles/px, are taken as cut by the lens:
# the diffraction cut-off 1 / (lambda N) of an f/5.6 lens in green light (0.55 um)
# on 5-um pixels is 1.6 cycles/px (sharper optics or larger pixels pass more).
_OPTICS_CUTOFF = 1.6


def _dtft(img: np.ndarray, w: np.ndarray, k) -> complex:
    H, W = img.shape
    ex = np.exp(-2j * np.pi * k[0] * np.arange(W))
    ey = np.exp(-2j * np.pi * k[1] * np.arange(H))
    return complex(ey @ (img * w) @ ex)


def aliasing_bias(image, lattice, *, sigma: float, mask=None) -> dict:
    """Phase and displacement error from the lines' harmonics aliasing onto the carrier.

    Parameters
    ----------
    image : (H, W) array_like
        The (mean) reference image, grey levels.
    lattice : Lattice
    sigma : float
        Window standard deviation, px.
    mask : (H, W) bool array_like, optional
        Pixels of the specimen.

    Returns
    -------
    dict
        ``phase_rad`` (2,): estimated bound of the phase error per wave vector;
        ``u_px``: the largest displacement error, ``phase p / 2 pi``;
        ``strain_per_strain``: strain error per unit of measured strain;
        ``sharpness`` (2,): the lines' harmonics relative to sharp lines (1);
        ``observable``: whether the sharpness was measured (harmonics that do not
        alias onto a carrier exist) or assumed (1);
        ``method``.

    Notes
    -----
    Sampling folds the ``n``-th harmonic ``n k`` of the line profile to
    ``n k`` modulo 1 cycle/px; when it lands within the window's bandwidth of a
    carrier ``+-k`` the transform at ``k`` mixes it in, with the phase ``n phi``
    instead of ``phi``: a phase error of amplitude ``(a_n / a_1) exp(-2 pi^2
    sigma^2 Delta^2)`` rad, ``Delta`` the distance of the alias to the carrier.
    At pitch 4 the 3rd, 5th, 7th... harmonics land exactly on ``-k``, ``+k``...
    The bound sums these terms for sharp lines (a square profile, ``a_n / a_1
    = 1/n`` for odd ``n``, times the pixel's integration ``sinc(n k)/sinc(k)``
    along each axis; harmonics above 1.6 cycles/px left out, the diffraction cut-off
    of an f/5.6 lens on 5-um pixels), scaled by the profile's sharpness: measured as the median
    ratio of the odd harmonics that alias elsewhere (seen in the image's spectrum)
    to their sharp-line value, or 1 when none can be seen (integer pitches such as 4,
    where every alias lands on a carrier, zero or the Nyquist frequency). The
    strain error follows from the phase ``(n + 1) phi`` of the error term: about
    ``(n + 1)`` times the phase error per unit strain, an estimate of its order
    (0.7 to 1.4 times the measured error). A checkerboard (recognised by its cross
    harmonic ``2 k1 + k2``) has harmonics ``n k1 + m k2``, ``n + m`` odd, of
    amplitudes ``1 / |n^2 - m^2|``, and its own estimate. Figures on noise-free
    images stretched by 1e-3 (``tests/test_noise_sources.py``): sharp lines at
    pitch 4, 0.026 px and 4.7e-4 measured, estimates 0.096 px and 6.8e-4; at
    pitch 6, 0.048 px measured, 0.058 px estimated; sharp checkerboards at pitch
    4 and 6, 0.013 and 0.0014 px measured, 0.057 and 0.015 px estimated; a sine
    at pitch 5.3, below 1e-4 px.
    """
    img = as_image(image, allow_uniform=True).astype(np.float64)
    sigma = check_positive(sigma, "sigma")
    w = _aliasing_window(img.shape, lattice, mask)
    ref = img - float(np.sum(img * w) / np.sum(w))
    ks = [np.array(lattice.k1), np.array(lattice.k2)]
    carriers = [s * k for k in ks for s in (1, -1)]
    bw = 1.0 / (2 * math.pi * sigma)  # the window's frequency std
    checker = _checkerboard_bound(ref, w, lattice, sigma, carriers, bw)
    if checker is not None:
        return checker
    phase, strain, sharp, seen = zip(*(_line_family_bound(ref, w, k, sigma, carriers, bw)
                                       for k in ks), strict=True)
    p = lattice.pitches
    u = max(phase[j] * p[j] / (2 * math.pi) for j in range(2))
    return {"phase_rad": [float(x) for x in phase], "u_px": float(u),
            "strain_per_strain": float(max(strain)), "sharpness": [float(x) for x in sharp],
            "observable": all(seen), "pattern": "lines",
            "method": "harmonics n k folded by the sampling onto the carrier, weighted by "
                      "the window's transfer; sharp-line amplitudes 1/n times the pixel "
                      "integration, scaled by the measured sharpness"}


def _aliasing_window(shape, lattice, mask) -> np.ndarray:
    """(H, W) weights of the spectral estimates: a Hann window, times the mask
    eroded by three pitches and softened over one."""
    H, W = shape
    hy, hx = np.hanning(H), np.hanning(W)
    if mask is None:
        return np.outer(hy, hx)
    # a soft edge: a hard one would spread the mean level and the fundamental
    # over the spectrum, where they would pass for harmonics
    p = float(np.mean(lattice.pitches))
    n = math.ceil(3 * p)
    m = np.asarray(mask, dtype=bool)
    box = _filled_box(m)
    if box is not None:
        # a rectangle (the whole image where nothing is masked) is eroded into a
        # rectangle, whose Gaussian is the product of the two axes' Gaussians: the
        # 2-D filters' window, to rounding, from two 1-D ones
        sides = []
        for (a, b), size in zip(box, shape, strict=True):
            side = np.zeros(size)
            side[a + n:max(a + n, b - n)] = 1.0
            sides.append(ndimage.gaussian_filter1d(side, p))
        return np.outer(hy * sides[0], hx * sides[1])
    m = ndimage.binary_erosion(m, iterations=n)
    return np.outer(hy, hx) * ndimage.gaussian_filter(m.astype(np.float64), p)


def _filled_box(m: np.ndarray):
    """``((r0, r1), (c0, c1))`` when the True pixels of ``m`` fill exactly that
    rectangle (at least one pixel), None otherwise."""
    rows = np.flatnonzero(m.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(m.any(axis=0))
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    if np.count_nonzero(m) != (r1 - r0) * (c1 - c0):
        return None
    return (r0, r1), (c0, c1)


def _line_family_bound(ref, w, k, sigma, carriers, bw):
    """Aliasing bound of one family of lines of wave vector ``k`` (see aliasing_bias).

    Returns the phase bound (rad) and the strain bound (per unit strain), both
    scaled by the sharpness; the sharpness (1 for sharp lines); and whether it was
    measured (odd harmonics seen away from every carrier) rather than assumed.
    """
    a1 = abs(_dtft(ref, w, k))
    mtf1 = abs(np.sinc(k[0]) * np.sinc(k[1]))
    bound = 0.0
    strain_b = 0.0
    ratios = []
    orders = [n for n in _ALIAS_ORDERS if n * float(np.hypot(*k)) <= _OPTICS_CUTOFF]
    folded = {m: (m * k + 0.5) % 1.0 - 0.5 for n in orders for m in (n, -n)}
    folded.update({m: m * k for m in (-1, 1)})
    for n in orders:
        f = folded[n]
        delta = min(float(np.hypot(*(f - c))) for c in carriers)
        mtf = abs(np.sinc(n * k[0]) * np.sinc(n * k[1])) / mtf1
        term = (1.0 / n if n % 2 else 0.0) * mtf
        transfer = math.exp(-2 * math.pi**2 * sigma**2 * delta**2)
        bound += term * transfer
        strain_b += (n + 1) * term * transfer
        # an odd harmonic whose alias is away from the carriers, from zero, from
        # the Nyquist lines (where it meets its own conjugate) and from every
        # other harmonic's alias can be measured
        apart = all(float(np.hypot(*((g - f + 0.5) % 1.0 - 0.5))) > 3 * bw
                    for m, g in folded.items() if m != n)
        if n % 2 and term > 0.01 and delta > 3 * bw and np.hypot(*f) > 3 * bw and \
                np.all(np.abs(np.abs(f) - 0.5) > 1.5 * bw) and apart and a1 > 0:
            ratios.append(abs(_dtft(ref, w, n * k)) / a1 / term)
    # the median: one harmonic caught by a mask edge or texture does not decide
    c = min(1.0, float(np.median(ratios))) if ratios else 1.0
    return c * bound, c * strain_b, c, bool(ratios)


def _checkerboard_bound(ref, w, lattice, sigma, carriers, bw):
    """The aliasing estimate of a checkerboard, or None when the image is a grid of
    lines (no cross harmonic ``2 k1 + k2``).

    A sharp checkerboard whose squares' diagonals run along ``k1`` and ``k2`` is
    the product of two square waves of phases ``(phi1 + phi2)/2`` and
    ``(phi1 - phi2)/2``: its harmonics are ``n k1 + m k2`` with ``n + m`` odd and
    amplitudes ``1 / |n^2 - m^2|`` relative to the fundamental. The cross
    harmonics (2, 1), (1, 2)... (a third for sharp squares, absent from a grid of
    lines or a sine checkerboard) measure the sharpness.
    """
    k1, k2 = np.array(lattice.k1), np.array(lattice.k2)

    def mtf(f):
        return abs(np.sinc(f[0]) * np.sinc(f[1]))

    def fold(f):
        return (f + 0.5) % 1.0 - 0.5

    a1 = 0.5 * (abs(_dtft(ref, w, k1)) + abs(_dtft(ref, w, k2)))
    m1 = 0.5 * (mtf(k1) + mtf(k2))
    if not a1 > 0:
        return None
    ratios = []
    for n, m in ((2, 1), (1, 2), (2, -1), (-1, 2)):
        h = n * k1 + m * k2
        f = fold(h)
        if min(float(np.hypot(*(f - c))) for c in carriers) > 3 * bw and \
                np.hypot(*f) > 3 * bw and mtf(h) > 0.05 * m1:
            ratios.append(abs(_dtft(ref, w, h)) / a1 / (mtf(h) / m1 / 3.0))
    # a grid of lines has no cross harmonic: noise and leaks give a few per cent
    if not ratios or float(np.median(ratios)) < 0.1:
        return None
    c = min(1.0, float(np.median(ratios)))
    bound = strain_b = 0.0
    order = range(-9, 10)
    for n in order:
        for m in order:
            h = n * k1 + m * k2
            if (n + m) % 2 == 0 or abs(n) + abs(m) == 1 or np.hypot(*h) > _OPTICS_CUTOFF:
                continue
            delta = min(float(np.hypot(*(fold(h) - cc))) for cc in carriers)
            term = mtf(h) / m1 / abs(n * n - m * m)
            transfer = math.exp(-2 * math.pi**2 * sigma**2 * delta**2)
            # a pair (h, -h) folds onto the pair of carriers: count each once
            bound += 0.5 * term * transfer
            strain_b += 0.5 * (abs(n) + abs(m) + 1) * term * transfer
    p = float(np.mean(lattice.pitches))
    return {"phase_rad": [c * bound] * 2, "u_px": float(c * bound * p / (2 * math.pi)),
            "strain_per_strain": float(c * strain_b), "sharpness": [c, c],
            "observable": True, "pattern": "checkerboard",
            "method": "harmonics n k1 + m k2 (n + m odd) of a checkerboard folded by the "
                      "sampling onto the carrier, weighted by the window's transfer; "
                      "sharp-square amplitudes 1/|n^2 - m^2| times the pixel integration, "
                      "scaled by the sharpness measured on the cross harmonics"}


def smoothing_bias(strain, valid, *, sigma: float) -> dict:
    """The window's smoothing of strain gradients, estimated from the measured field.

    Parameters
    ----------
    strain : (3, H, W) array_like
        Measured ``(e_xx, e_yy, e_xy)``, NaN where not valid.
    valid : (H, W) bool array_like
    sigma : float
        Window standard deviation, px.

    Returns
    -------
    dict
        Per component ``(e_xx, e_yy, e_xy)``, dimensionless:

        - ``max`` (3,): the bound on the window's bias, ``factor`` times the largest
          ``|sigma^2 / 2 lap(e)|`` over the valid pixels;
        - ``estimate_max`` and ``p95`` (3,): the largest value and the 95th
          percentile of ``|sigma^2 / 2 lap(e)|`` itself;
        - ``attenuation`` (3,): the fraction by which the window lowers the peak
          where the bound is largest, ``max / (|departure| + max)``, with the
          departure the measured strain's from its median over 20 sigma around
          (meaningful where ``max`` stands above the noise);
        - ``below_resolution`` (3,) bool: that fraction exceeds 10 %, the
          attenuation that defines the spatial resolution (:func:`metrology`);

        and ``factor``, ``definition``.

    Notes
    -----
    The maps are the true fields convolved with the Gaussian window (eqs.
    24-25); to second order, ``g * e = e + sigma^2 / 2 lap(e)``. The Laplacian is
    taken on the measured field smoothed once more by the window (normalised
    over the valid pixels, so the mask's edge adds nothing), which keeps its noise
    below the map's own noise: noise alone gives a 95th percentile of about 0.6
    times the strain noise std (the pipeline warns above twice the noise std).
    The estimate is of the bias of the smoothed field, so it understates
    narrow features: for a Gaussian strain feature of standard deviation ``w``,
    ``|sigma^2 / 2 lap(g * g * e)|`` at its peak over the actual peak error
    ``A (1 - w / sqrt(w^2 + sigma^2))`` (a band; ``A sigma^2 / (w^2 + sigma^2)``
    for a round bump) is 0.51 (band) and 0.40 (bump) at ``w = 1.5 sigma``, 0.64
    and 0.56 at ``2 sigma``, 0.80 and 0.72 at ``3 sigma``, tending to 1 for wide
    features (closed forms; 0.52, 0.41, 0.67, 0.56 measured on noise-free
    independent images). The bound ``max`` is that estimate times
    ``factor = 3``: from 1.2 to 2.5 times the actual peak error for features
    from 1.5 to 3 sigma wide, 3 times for wide ones; below about ``1.2 sigma``
    (band) or ``1.6 sigma`` (bump) it no longer bounds, and ``below_resolution``
    says so. Noise adds to the largest value: about 1.1 times the strain noise
    std on a uniform field, so a bound below ~3.5 noise std is noise.

    It is taken on every ``s``-th row and column, ``s = floor(sigma / 2.5)``, at
    ``s^2`` times less cost. The maps are band-limited by the window (transfer
    ``exp(-2 pi^2 sigma^2 f^2)``): at the Nyquist frequency of that sampling,
    ``1 / 2s``, less than ``exp(-3.125 pi^2) < 1e-13`` of them is left, so nothing
    aliases. The five-point Laplacian at a step of ``s`` px underestimates that of
    a sine of wavenumber ``k`` by ``(k s)^2 / 12``: at ``k = 1 / sigma``, where the
    estimate of a sine is largest, under 1.4 % (``s <= sigma / 2.5``), or 2 % at
    ``sigma = 2`` px, which is sampled at every pixel.
    """
    sigma = check_positive(sigma, "sigma")
    e = np.asarray(strain, dtype=np.float64)
    v = np.asarray(valid, dtype=bool)
    s = max(1, int(sigma // 2.5))
    e, v = e[:, ::s, ::s], v[::s, ::s]
    sig = sigma / s  # the window in samples of the decimated maps
    inner = ndimage.binary_erosion(v, iterations=max(1, math.ceil(2 * sig)))
    p95, mx, att = [], [], []
    wsum = ndimage.gaussian_filter(v.astype(np.float64), sig)
    np.maximum(wsum, 1e-12, out=wsum)
    ii, jj = np.nonzero(inner)
    half = round(_BACKGROUND_SIGMAS * sig / 2)
    for c in e:
        filled = np.where(v, c, 0.0)
        sm = np.divide(ndimage.gaussian_filter(filled, sig), wsum, out=filled)
        lap = ndimage.laplace(sm)
        del sm
        b = lap[inner] if inner.any() else np.array([])
        del lap
        b *= 0.5 * sig**2  # sigma^2 / 2 times the Laplacian per px^2 (samples of s px)
        np.abs(b, out=b)
        p95.append(float(np.percentile(b, 95)) if b.size else math.nan)
        mx.append(float(b.max()) if b.size else math.nan)
        if b.size:
            # the departure from the surroundings where the bound peaks
            i, j = ii[int(np.argmax(b))], jj[int(np.argmax(b))]
            box = (slice(max(0, i - half), i + half + 1), slice(max(0, j - half), j + half + 1))
            dep = float(c[i, j]) - float(np.median(c[box][v[box]]))
            peak = _SMOOTHING_FACTOR * mx[-1]
            att.append(peak / (abs(dep) + peak) if peak > 0 else 0.0)
        else:
            att.append(math.nan)

    def clean(v):
        return [x if math.isfinite(x) else None for x in v]

    bound = [_SMOOTHING_FACTOR * x for x in mx]
    return {"max": clean(bound), "estimate_max": clean(mx), "p95": clean(p95),
            "attenuation": clean(att),
            "below_resolution": [bool(math.isfinite(a) and a > _ATTENUATION) for a in att],
            "factor": _SMOOTHING_FACTOR,
            "definition": "max: a bound on the window's smoothing bias, factor x the "
                          "largest |sigma^2/2 laplacian(e)| of the measured strain smoothed "
                          "by the window, over the valid pixels 2 sigma from their edge "
                          "(tested on Gaussian features 1.5 to 3 sigma wide: 1.2 to 2.5 "
                          "times the actual peak error); estimate_max, p95: that "
                          "Laplacian term itself"}


def _nearest_filled(a: np.ndarray, valid: np.ndarray, nearest=None) -> np.ndarray:
    """``a`` with its invalid pixels set to the nearest valid pixel's value
    (``nearest``: :func:`_nearest_index` of ``valid``, when known)."""
    if valid.all() or not valid.any():
        return np.where(valid, a, 0.0)
    return a[_nearest_index(valid) if nearest is None else nearest]


def _nearest_index(valid: np.ndarray) -> tuple:
    """The index of each pixel's nearest valid pixel."""
    return tuple(ndimage.distance_transform_edt(~valid, return_distances=False,
                                                return_indices=True))


def _departure(e: np.ndarray, valid: np.ndarray, sigma: float, nearest=None) -> np.ndarray:
    """``e`` less its median over 8 sigma around, taken on a grid of step ``sigma``
    (a ridge 2 to 3 sigmas wide holds 3 of the 9 columns of the median's window,
    which keeps it out of its background at a sigma^2-th of the full median's
    cost); invalid pixels take their nearest valid neighbour's value
    (``nearest``: :func:`_nearest_index` of ``valid``, when known)."""
    f = _nearest_filled(np.asarray(e, dtype=np.float64), valid, nearest)
    step = max(1, int(sigma))
    coarse = f[::step, ::step]
    size = max(3, round(8.0 * sigma / step) | 1)
    bg = ndimage.median_filter(coarse, size=size, mode="nearest")
    zoom = (f.shape[0] / bg.shape[0], f.shape[1] / bg.shape[1])
    full = ndimage.zoom(bg, zoom, order=1, mode="nearest", grid_mode=True)
    return f - full[:f.shape[0], :f.shape[1]]
