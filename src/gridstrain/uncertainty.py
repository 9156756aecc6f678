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

from ._validation import as_image, check_positive
from .theory import window_energy
from .wft import PhaseMaps

__all__ = ["NoiseFloor", "Uncertainty", "noise_floor", "noise_variance_map", "predict_uncertainty"]


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
        return {n: float(np.median(m[v])) if v.any() else math.nan for n, m in zip(names, maps,
                                                                                  strict=True)}


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
    if not math.isfinite(L) or L < 0:
        raise ValueError(f"L must be a finite non-negative variance, got {L!r}")
    sigma = check_positive(sigma, "sigma")
    if not isinstance(frames, int | np.integer) or frames < 1:
        raise ValueError(f"frames must be a positive integer, got {frames!r}")
    local = ndimage.gaussian_filter(img, sigma / math.sqrt(2), mode="nearest", truncate=5.0)
    return (K * np.maximum(local, 0.0) + L) / int(frames)


def _as_map(v, shape, name):
    a = np.asarray(v, dtype=np.float64)
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
    for name, pm in (("reference", reference), ("deformed", deformed)):
        if not isinstance(pm, PhaseMaps):
            raise TypeError(f"{name} must be PhaseMaps, got {type(pm).__name__}")
    if reference.shape != deformed.shape:
        raise ValueError(f"deformed maps must have the shape of the reference "
                         f"{reference.shape}, got {deformed.shape}")
    shape = reference.shape
    v_ref = _as_map(variance_ref, shape, "variance_ref")
    v_def = _as_map(variance_def, shape, "variance_def")
    if valid is None:
        valid = reference.valid & deformed.valid
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != shape:
        raise ValueError(f"valid must have shape {shape}, got {valid.shape}")
    g2, dg2 = window_energy(reference.sigma)

    phase_std = np.empty((2, 2, *shape))
    dphi_std = np.empty((2, 2, *shape))
    for s, (pm, v) in enumerate(((reference, v_ref), (deformed, v_def))):
        mod = np.abs(pm.psi).astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            for j in range(2):
                phase_std[s, j] = np.sqrt(v * g2 / 2) / mod[j]
                dphi_std[s, j] = np.sqrt(v * dg2 / 2) / mod[j]
    M2 = (np.linalg.inv(reference.lattice.K) / (2 * np.pi)) ** 2
    var_phase = phase_std[0] ** 2 + phase_std[1] ** 2  # (2, H, W), per wave vector
    var_deriv = dphi_std[0] ** 2 + dphi_std[1] ** 2
    u_std = np.sqrt(np.tensordot(M2, var_phase, axes=1))
    var_G = np.tensordot(M2, var_deriv, axes=1)  # same for m = x and m = y
    strain_std = np.sqrt(np.stack([var_G[0], var_G[1], 0.25 * (var_G[0] + var_G[1])]))
    nan = ~valid
    for a in (u_std, strain_std, phase_std, dphi_std):
        a[..., nan] = np.nan
    return Uncertainty(u_std=u_std, strain_std=strain_std, phase_std=phase_std,
                       dphi_std=dphi_std, valid=valid)


@dataclass(frozen=True)
class NoiseFloor:
    """Predicted noise floor of a measurement between two states of ``T`` frames.

    Attributes
    ----------
    frames : int
        ``T`` frames averaged per state.
    sigma : float
        Window standard deviation, px.
    level : float
        Median grey level of the specimen (stored units).
    modulus : (2,) tuple of float
        Median fringe modulus ``|Psi_j|`` (grey levels).
    phase_std, dphi_std : (2,) tuple of float
        Per wave vector, rad and rad/px, for one state.
    u_std : (2,) tuple of float
        ``(u_x, u_y)``, px.
    strain_std : (3,) tuple of float
        ``(eps_xx, eps_yy, eps_xy)``.
    resolution : float
        Spatial resolution, px: the full width at half maximum of the window,
        ``2 sqrt(2 ln 2) sigma`` (two features closer than this are not told apart).
    """

    frames: int
    sigma: float
    level: float
    modulus: tuple[float, float]
    phase_std: tuple[float, float]
    dphi_std: tuple[float, float]
    u_std: tuple[float, float]
    strain_std: tuple[float, float, float]
    resolution: float


def noise_floor(maps: PhaseMaps, mean_image, *, K: float, L: float,
                frames: int = 1) -> NoiseFloor:
    """Predicted std of displacement and strain between two states like ``maps``.

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
        Medians over the valid pixels of the maps of :func:`predict_uncertainty`,
        for two independent states with the same noise.
    """
    if not isinstance(maps, PhaseMaps):
        raise TypeError(f"maps must be PhaseMaps, got {type(maps).__name__}")
    var = noise_variance_map(mean_image, K=K, L=L, sigma=maps.sigma, frames=frames)
    unc = predict_uncertainty(maps, maps, variance_ref=var, variance_def=var)
    v = unc.valid
    if not v.any():
        raise ValueError("maps have no valid pixel: no noise floor can be predicted")
    img = np.asarray(mean_image, dtype=np.float64)

    def med(a):
        return float(np.median(a[v]))

    return NoiseFloor(
        frames=int(frames), sigma=maps.sigma, level=med(img),
        modulus=tuple(med(np.abs(p)) for p in maps.psi),
        phase_std=tuple(med(a) for a in unc.phase_std[0]),
        dphi_std=tuple(med(a) for a in unc.dphi_std[0]),
        u_std=tuple(med(a) for a in unc.u_std),
        strain_std=tuple(med(a) for a in unc.strain_std),
        resolution=2 * math.sqrt(2 * math.log(2)) * maps.sigma,
    )
