"""The synthetic data set of the founding paper's §3.2: phase maps, vibrations, frames.

Sur & Grédiac (2015) test time-averaging on grid images generated from eqs. (1)-(2):
a grid of pitch 5 px whose phase modulations ``phi1``, ``phi2`` are synthetic maps
(their Fig. 4), translated by a random vibration ``(alpha_t, beta_t)`` and corrupted
by Poisson-Gaussian sensor noise quantised to 12 bits. This module rebuilds that data
set; :mod:`gridstrain.paper.experiment` runs the paper's experiments on it. Coordinates and
signs follow :mod:`gridstrain.conventions`.

Choices the paper leaves open, made here once:

* **Phase maps** (:func:`paper_phases`). ``phi1(x, y) = a1 sin(2 pi nu(x) (y - yc))``,
  a sine along the vertical axis whose frequency ``nu(x)`` grows linearly from
  1/300 to 1/75 cycle/px across the width; ``phi2(y)`` is piecewise quadratic in
  ``y`` (four pieces on equal quarters of the height, its derivative piecewise linear
  with three jumps) and does not depend on ``x``, so ``d phi2 / dx = 0`` (the null
  ground truth of the paper's Fig. 10). *Each* map is scaled so that its largest
  derivative over the pixel grid, in either direction, is ``max_derivative``
  (0.005 rad/px by default); the largest over both maps and both directions is
  therefore the same number. On a 512 x 512 grid this gives maxima of 0.060 rad
  for ``phi1`` and 0.42 rad for ``phi2``, the paper's values. (The noise-driven
  RMSEs of the experiments do not depend on this scale.)
* **Interpolation** (:func:`clean_frame`). As in the paper, ``s(x + alpha, y + beta)``
  uses the exact carrier ``2 pi f (x + alpha)`` and the phase maps *bilinearly*
  interpolated at the shifted points (``scipy.ndimage.map_coordinates``,
  ``order=1``, ``mode="nearest"``: beyond the map the edge value is repeated, which
  touches only the outermost pixel or so, well inside the band that the windowed
  Fourier transform flags invalid).
* **Grey levels** (:func:`vibrated_frame`). The paper's ``A = 2**12`` makes eq. (1)
  reach ``A (1 + gamma / 2) = 5939`` grey levels, above a 12-bit sensor's 4095, on
  about half of the pixels; saturating them would leave an error that no averaging
  removes and that eq. (2) does not model. We keep ``A = 2**12`` and the paper's
  12-bit *quantisation step* (rounding to integer grey levels) but do not clip, so
  eq. (2) holds exactly in expectation. Pass ``clip=True``, or an ``amplitude``
  with ``amplitude * (1 + contrast / 2) <= 4095`` (e.g. 2824), for the other
  readings.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
from scipy import ndimage

from .._validation import (
    as_image,
    as_pair,
    check_fraction,
    check_int,
    check_positive,
    check_shape,
)
from ..models import add_noise, line_profile

__all__ = [
    "clean_frame",
    "draw_shifts",
    "iter_frames",
    "mean_image_bias",
    "paper_phases",
    "vibrated_frame",
    "vibration_cases",
]

#: Largest phase derivative of the paper's maps, rad/px (§3.2).
MAX_DERIVATIVE = 0.005
# Local frequency range of phi1 along y, cycles/px: one period of 300 px on the left
# edge to one of 75 px on the right. With the 0.005 rad/px normalisation the amplitude
# is 0.005 / (2 pi / 75) = 0.060 rad, the paper's maximum of phi1.
_NU1 = (1.0 / 300.0, 1.0 / 75.0)
# Derivative of phi2 on each quarter of the height, as (value at start, value at end)
# relative to its maximum: linear pieces with jumps at 1/4, 1/2, 3/4 of the height.
# Integrated over a 512-px height and scaled to 0.005 rad/px they give a maximum of
# phi2 of 0.42 rad (the paper's value).
_PHI2_PIECES = ((0.3, 1.0), (-0.6, 0.2), (0.8, -0.8), (0.1, 0.3))

# The paper's default parameters (§3.2); README notes give K and L.
_DEFAULTS = {"amplitude": 4096.0, "contrast": 0.9, "pitch": 5.0, "profile": "sin3",
             "K": 0.28, "L": 5.0}


def _phi2_profile(H: int):
    """Unscaled ``phi2`` and its derivative along ``y`` (per pixel), shape (H,)."""
    y = np.arange(H, dtype=float)
    quarter = (H - 1) / 4.0
    piece = np.minimum((y / quarter).astype(int), 3)
    phi = np.empty(H)
    der = np.empty(H)
    start_phi = 0.0
    for j, (g0, g1) in enumerate(_PHI2_PIECES):
        sel = piece == j
        t = y[sel] - j * quarter  # px from the start of the piece
        slope = (g1 - g0) / quarter
        der[sel] = g0 + slope * t
        phi[sel] = start_phi + g0 * t + 0.5 * slope * t**2
        start_phi += g0 * quarter + 0.5 * slope * quarter**2
    return phi, der


def paper_phases(shape, *, max_derivative: float = MAX_DERIVATIVE):
    """Phase modulation maps imitating the paper's Fig. 4, and their exact derivatives.

    Parameters
    ----------
    shape : (int, int)
        ``(H, W)`` of the pixel grid.
    max_derivative : float
        Largest ``|d phi / dx|`` and ``|d phi / dy|`` of each map over the pixel
        grid, rad/px (the paper's 0.005).

    Returns
    -------
    phases : (2, H, W) float64 ndarray
        ``phi1`` and ``phi2`` sampled at the pixel centres, rad.
    derivatives : (2, 2, H, W) float64 ndarray
        Their exact derivatives at the pixel centres, rad/px, laid out like
        :attr:`gridstrain.phase.PhaseMaps.dphi`: ``derivatives[j, 0] = d phi_j / dx``,
        ``derivatives[j, 1] = d phi_j / dy``.

    Notes
    -----
    ``phi1(x, y) = a1 sin(2 pi nu(x) (y - yc))`` with ``yc = (H - 1) / 2`` and
    ``nu`` linear in ``x`` from 1/300 to 1/75 cycle/px; ``phi2`` is piecewise
    quadratic in ``y`` alone, zero at ``y = 0``. See the module docstring for the
    normalisation. The maps are deterministic.

    Examples
    --------
    >>> phases, der = paper_phases((512, 512))
    >>> round(float(np.abs(der).max()), 6), round(float(phases[0].max()), 3)
    (0.005, 0.06)
    """
    H, W = check_shape(shape, "shape", minimum=8)
    max_derivative = check_positive(max_derivative, "max_derivative")
    y = np.arange(H, dtype=float)[:, None]
    x = np.arange(W, dtype=float)[None, :]
    nu0, nu1 = _NU1
    slope = (nu1 - nu0) / max(W - 1, 1)
    nu = nu0 + slope * x
    arg = 2 * math.pi * nu * (y - (H - 1) / 2.0)
    s1, c1 = np.sin(arg), np.cos(arg)
    d1x = c1 * 2 * math.pi * slope * (y - (H - 1) / 2.0)
    d1y = c1 * 2 * math.pi * nu
    a1 = max_derivative / max(float(np.abs(d1x).max()), float(np.abs(d1y).max()))
    p2, d2 = _phi2_profile(H)
    a2 = max_derivative / float(np.abs(d2).max())

    phases = np.empty((2, H, W))
    der = np.zeros((2, 2, H, W))
    phases[0] = a1 * s1
    der[0, 0] = a1 * d1x
    der[0, 1] = a1 * d1y
    phases[1] = (a2 * p2)[:, None]
    der[1, 1] = (a2 * d2)[:, None]
    return phases, der


def vibration_cases() -> dict[int, tuple[float, float]]:
    """The paper's four vibration laws: case -> ``(sigma_alpha, sigma_beta)``, px.

    Case 1 is strong vibration, case 3 the typical residual vibration of the
    paper's real experiment (§3.2; case 3 read as (0.01, 0.01), see the paper notes).
    """
    return {1: (0.15, 0.1), 2: (0.1, 0.05), 3: (0.01, 0.01), 4: (0.001, 0.005)}


def _stds(case) -> tuple[float, float]:
    if isinstance(case, int | np.integer) and not isinstance(case, bool):
        cases = vibration_cases()
        if int(case) not in cases:
            raise ValueError(f"case must be one of {sorted(cases)}, got {case!r}")
        return cases[int(case)]
    try:
        sa, sb = as_pair(case, "case")
    except TypeError:
        raise TypeError(f"case must be 1, 2, 3, 4 or a (sigma_alpha, sigma_beta) pair, "
                        f"got {case!r}") from None
    if sa < 0 or sb < 0:
        raise ValueError(f"case standard deviations must be finite and >= 0, got {case!r}")
    return sa, sb


def draw_shifts(T: int, case, *, rng=None) -> np.ndarray:
    """Draw ``T`` i.i.d. Gaussian vibration translations ``(alpha_t, beta_t)``.

    Parameters
    ----------
    T : int
        Number of frames.
    case : int or (float, float)
        A case of :func:`vibration_cases` or ``(sigma_alpha, sigma_beta)`` in px.
    rng : numpy.random.Generator or int, optional
        Random generator or seed.

    Returns
    -------
    (T, 2) float64 ndarray
        Shifts in px, ``(alpha, beta)`` = ``(x, y)`` components, zero-mean
        independent Gaussians. They are ``rng.standard_normal((T, 2))`` scaled
        column by column, so one seed gives proportional shifts in every case.
    """
    T = check_int(T, "T", minimum=1)
    stds = np.array(_stds(case))
    rng = np.random.default_rng(rng)
    return rng.standard_normal((T, 2)) * stds


def _params(amplitude, contrast, pitch, profile):
    amplitude = check_positive(amplitude, "amplitude")
    contrast = check_fraction(contrast, "contrast")
    pitch = check_positive(pitch, "pitch")
    if pitch <= 2:
        raise ValueError(f"pitch must be above 2 px (Nyquist), got {pitch!r}")
    return amplitude, contrast, pitch, line_profile(profile)


def _phase_pair(phases) -> np.ndarray:
    """``phases`` as a (2, H, W) float64 array, each map checked as an image."""
    p = np.asarray(phases, dtype=float)
    if p.ndim != 3 or p.shape[0] != 2:
        raise ValueError(f"phases must be a (2, H, W) array with H, W >= 8, got shape "
                         f"{p.shape}")
    for j in range(2):  # at least 8 x 8, finite; a uniform phase is a plain grid
        as_image(p[j], f"phases[{j}]", allow_uniform=True)
    return p


def clean_frame(phases, shift=(0.0, 0.0), *, amplitude: float = 4096.0,
                contrast: float = 0.9, pitch: float = 5.0, profile="sin3") -> np.ndarray:
    """Noise-free grid image translated by a vibration: ``s(x + alpha, y + beta)``.

    Parameters
    ----------
    phases : (2, H, W) array_like
        ``phi1``, ``phi2`` at the pixel centres, rad (from :func:`paper_phases`).
    shift : (float, float)
        ``(alpha, beta)``, px. ``(0, 0)`` gives the reference image ``s``, the
        ground-truth source of the experiments.
    amplitude, contrast : float
        ``A`` (mean grey level) and ``gamma`` of eq. (1).
    pitch : float
        ``p = 1/f``, px; the grid is the paper's axis-aligned one,
        ``Lattice.from_pitch(pitch)``.
    profile : str or callable
        Line profile ``l`` (see :data:`gridstrain.models.synthetic.PROFILES`); default the
        paper's ``sin^3`` scaled to a peak-to-peak of 1.

    Returns
    -------
    (H, W) float64 ndarray
        Eq. (1) at ``(x + alpha, y + beta)``, grey levels: exact carrier,
        bilinearly interpolated phases (edge values repeated beyond the map).
    """
    p = _phase_pair(phases)
    a, b = as_pair(shift, "shift")
    A, gamma, pitch, ell = _params(amplitude, contrast, pitch, profile)
    H, W = p.shape[1:]
    f = 1.0 / pitch
    x = np.arange(W, dtype=float) + a
    y = np.arange(H, dtype=float) + b
    if a == 0.0 and b == 0.0:
        p1, p2 = p[0], p[1]
    else:
        coords = np.empty((2, H, W))
        coords[0] = y[:, None]
        coords[1] = x[None, :]
        p1 = ndimage.map_coordinates(p[0], coords, order=1, mode="nearest")
        p2 = ndimage.map_coordinates(p[1], coords, order=1, mode="nearest")
    t1 = 2 * math.pi * f * x[None, :] + p1
    t2 = 2 * math.pi * f * y[:, None] + p2
    return A / 2 * (2 + gamma * ell(t1) + gamma * ell(t2))  # eq. (1)


def vibrated_frame(phases, shift, *, amplitude: float = 4096.0, contrast: float = 0.9,
                   pitch: float = 5.0, profile="sin3", K: float = 0.28, L: float = 5.0,
                   rng=None, bits: int | None = 12, clip: bool = False) -> np.ndarray:
    """One frame of the paper's stack, eq. (2): ``s(x + alpha, y + beta) + noise``.

    Parameters
    ----------
    phases : (2, H, W) array_like
        Phase maps, rad (:func:`paper_phases`).
    shift : (float, float)
        Vibration ``(alpha_t, beta_t)``, px.
    amplitude, contrast, pitch, profile
        Grid of eq. (1), see :func:`clean_frame`.
    K, L : float
        Sensor noise ``Var = K l + L`` (grey levels; the defaults are those of a
        12-bit Sensicam QE class camera).
    rng : numpy.random.Generator or int, optional
        Random generator or seed of the noise.
    bits : int or None
        Round to integer grey levels (``None``: no quantisation).
    clip : bool
        Saturate at ``2**bits - 1`` (off by default, see the module docstring).

    Returns
    -------
    (H, W) float64 ndarray
        Grey levels.
    """
    s = clean_frame(phases, shift=shift, amplitude=amplitude, contrast=contrast, pitch=pitch,
                    profile=profile)
    return add_noise(s, K=K, L=L, rng=rng, bits=bits, clip=clip)


def iter_frames(phases, shifts, *, rng=None, **params) -> Iterator[np.ndarray]:
    """Generate the frames of a vibrated stack one at a time (never the whole stack).

    Parameters
    ----------
    phases : (2, H, W) array_like
        Phase maps, rad.
    shifts : (T, 2) array_like
        Vibrations ``(alpha_t, beta_t)``, px (e.g. from :func:`draw_shifts`).
    rng : numpy.random.Generator or int, optional
        Generator or seed of the sensor noise; frame ``t`` uses the ``t``-th draws
        of this one stream, so a prefix of the stack does not depend on its length.
    **params
        Keyword options of :func:`vibrated_frame`.

    Yields
    ------
    (H, W) float64 ndarray
    """
    p = _phase_pair(phases)
    sh = np.asarray(shifts, dtype=float)
    if sh.ndim != 2 or sh.shape[1] != 2:
        raise ValueError(f"shifts must be a (T, 2) array, got shape {sh.shape}")
    rng = np.random.default_rng(rng)
    for shift in sh:
        yield vibrated_frame(p, shift, rng=rng, **params)


def mean_image_bias(phases, variance, *, covariance: float = 0.0, amplitude: float = 4096.0,
                    contrast: float = 0.9, pitch: float = 5.0, profile="sin3") -> np.ndarray:
    """Bias of the averaged image predicted by Proposition 2.1, eqs. (5) and (10)-(12).

    Parameters
    ----------
    phases : (2, H, W) array_like
        Phase maps, rad.
    variance : (float, float)
        ``(Var alpha, Var beta)``, px^2.
    covariance : float
        ``Cov(alpha, beta)``, px^2 (its term vanishes by eq. 12).
    amplitude, contrast, pitch, profile
        Grid of eq. (1), see :func:`clean_frame`.

    Returns
    -------
    (H, W) float64 ndarray
        ``E(v_bar) - s = 1/2 Var(alpha) s_xx + 1/2 Var(beta) s_yy``, grey levels,
        with the second derivatives of eqs. (10)-(11),
        ``s_xx = gamma A / 2 (2 pi f)^2 l''(2 pi f x + phi1)``.

    Notes
    -----
    ``l''`` is a central second difference of the profile with a step of 1e-3 rad
    (truncation error ~1e-7 relative, round-off ~1e-10). Eq. (5) is a second-order
    Taylor expansion: for the paper's ``sin^3`` profile its third harmonic already
    moves by ``(2 pi 3 f sigma)^2 / 2 = 0.16`` at ``sigma = 0.15`` px, where the
    exact Gaussian average is a few per cent smaller.
    """
    p = _phase_pair(phases)
    va, vb = as_pair(variance, "variance")
    if va < 0 or vb < 0:
        raise ValueError(f"variance must be finite and >= 0, got {variance!r}")
    del covariance  # eq. (12): the cross derivative is zero for the grid of eq. (1)
    A, gamma, pitch, ell = _params(amplitude, contrast, pitch, profile)
    H, W = p.shape[1:]
    w = 2 * math.pi / pitch
    t1 = w * np.arange(W, dtype=float)[None, :] + p[0]
    t2 = w * np.arange(H, dtype=float)[:, None] + p[1]
    h = 1e-3

    def second(t):
        return (ell(t + h) - 2 * ell(t) + ell(t - h)) / h**2

    scale = gamma * A / 2 * w**2
    return 0.5 * va * scale * second(t1) + 0.5 * vb * scale * second(t2)
