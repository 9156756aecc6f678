"""Synthetic grid images: the paper's model (eq. 1), deformed by a known field.

Coordinates follow :mod:`gridstrain.conventions`. These generators are the ground
truth of the test-suite and of ``gridstrain demo``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .._validation import (
    check_choice,
    check_fraction,
    check_int,
    check_nonnegative,
    check_positive,
    check_shape,
)
from ..phase import Lattice

__all__ = [
    "PROFILES",
    "add_noise",
    "deformed_positions",
    "grid_image",
    "line_profile",
]

Field = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _sin3(t):
    return 0.5 * np.sin(t) ** 3


def _sin(t):
    return 0.5 * np.sin(t)


def _square(t):
    # soft-edged square wave of peak-to-peak 1: sharp lines whose harmonics decay
    # fast enough for the pixel integration to keep aliasing small
    return 0.5 * np.tanh(3.0 * np.sin(t)) / np.tanh(3.0)


#: Line profiles ``l``: 2 pi-periodic, zero mean, peak-to-peak 1 (paper eq. 1).
PROFILES: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "sin3": _sin3,
    "sin": _sin,
    "square": _square,
}


def line_profile(profile) -> Callable[[np.ndarray], np.ndarray]:
    """Return the line profile callable for a name in :data:`PROFILES` or a callable."""
    if callable(profile):
        return profile
    check_choice(profile, "profile", tuple(PROFILES))
    return PROFILES[profile]


def deformed_positions(x: np.ndarray, y: np.ndarray, displacement: Field | None, *,
                       tol: float = 1e-12, max_iter: int = 100):
    """Reference positions ``X`` of the material points seen at ``x``.

    Solves ``x = X + u(X)`` by fixed point, ``X <- x - u(X)``, which converges for any
    displacement whose gradient is below 1 (every deformation a grid survives).

    Parameters
    ----------
    x, y : ndarray
        Current (deformed-image) coordinates, px.
    displacement : callable or None
        ``(X, Y) -> (u_x, u_y)`` in px, the Lagrangian displacement field.

    Returns
    -------
    X, Y : ndarray
    """
    if displacement is None:
        return x, y
    X, Y = x.copy(), y.copy()
    for _ in range(max_iter):
        ux, uy = displacement(X, Y)
        Xn, Yn = x - ux, y - uy
        step = max(float(np.max(np.abs(Xn - X))), float(np.max(np.abs(Yn - Y))))
        X, Y = Xn, Yn
        if step < tol:
            return X, Y
    raise ValueError("displacement: x = X + u(X) did not converge; is |grad u| below 1?")


def grid_image(shape, lattice: Lattice, *, amplitude: float = 1.0, contrast: float = 0.9,
               profile="sin3", kind: str = "grid", phases: Field | None = None,
               displacement: Field | None = None, reflectance=None,
               oversample: int = 1, dtype=np.float64) -> np.ndarray:
    """Noise-free grid or checkerboard image, optionally deformed.

    Parameters
    ----------
    shape : (int, int)
        ``(H, W)``.
    lattice : Lattice
        Wave vectors of the pattern in the reference configuration.
    amplitude : float
        ``A`` of eq. (1), the mean grey level.
    contrast : float
        ``gamma`` of eq. (1), in [0, 1].
    profile : str or callable
        Line profile ``l`` (default ``"sin3"``, the paper's ``sin^3`` halved to a
        peak-to-peak of 1).
    kind : {"grid", "checkerboard"}
        ``"grid"``: eq. (1), ``A/2 (2 + gamma l(t1) + gamma l(t2))``.
        ``"checkerboard"``: ``A (1 + gamma l((t1 + t2)/2) l((t1 - t2)/2) * 2)``,
        whose fundamental wave vectors are ``k1`` and ``k2`` (they run along the
        diagonals of its squares).
    phases : callable, optional
        ``(X, Y) -> (phi1, phi2)``, phase modulations of the reference grid (its
        manufacturing defects), rad.
    displacement : callable, optional
        ``(X, Y) -> (u_x, u_y)``, Lagrangian displacement in px; the image is that
        of the deformed specimen (``x = X + u(X)`` is solved for ``X``).
    reflectance : callable, optional
        ``(X, Y) -> factor`` multiplying the grey level, attached to the specimen
        (printing or illumination defects that move with it).
    oversample : int
        Each pixel is the mean over ``oversample^2`` points of its area, a model of
        the sensor's pixel integration.
    dtype : dtype
        Output dtype (float).

    Returns
    -------
    (H, W) ndarray
    """
    H, W = check_shape(shape)
    check_positive(amplitude, "amplitude")
    check_fraction(contrast, "contrast")
    check_choice(kind, "kind", ("grid", "checkerboard"))
    oversample = check_int(oversample, "oversample")
    ell = line_profile(profile)
    offsets = (np.arange(oversample) + 0.5) / oversample - 0.5
    out = np.zeros((H, W), dtype=np.float64)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    for oy in offsets:
        for ox in offsets:
            X, Y = deformed_positions(xx + ox, yy + oy, displacement)
            t1 = 2 * np.pi * (lattice.k1[0] * X + lattice.k1[1] * Y)
            t2 = 2 * np.pi * (lattice.k2[0] * X + lattice.k2[1] * Y)
            if phases is not None:
                p1, p2 = phases(X, Y)
                t1 = t1 + p1
                t2 = t2 + p2
            if kind == "grid":
                s = amplitude / 2 * (2 + contrast * ell(t1) + contrast * ell(t2))
            else:
                s = amplitude * (1 + 2 * contrast * ell((t1 + t2) / 2) * ell((t1 - t2) / 2))
            if reflectance is not None:
                s = s * reflectance(X, Y)
            out += s
    out /= oversample**2
    return out.astype(dtype)


def add_noise(image, *, K: float = 0.28, L: float = 5.0, rng=None, bits: int | None = 12,
              clip: bool = False) -> np.ndarray:
    """Poisson-Gaussian sensor noise, ``Var = K l + L``, then quantisation.

    Parameters
    ----------
    image : (H, W) array_like
        Noise-free expected grey levels ``l`` (not modified).
    K : float
        Gain, grey levels per electron: the Poisson part has variance ``K l``.
    L : float
        Variance of the signal-independent (read) noise, grey levels squared.
        The defaults are those of a 12-bit Sensicam QE class camera
        (``../shared/paper/README.md``).
    rng : numpy.random.Generator or int, optional
        Random generator or seed.
    bits : int or None
        Round to integer grey levels (``None``: no rounding). Values are clipped to
        ``[0, 2**bits - 1]`` only if ``clip`` is True.
    clip : bool
        Saturate at the sensor's range. Off by default: with the paper's
        ``A = 2^12`` eq. (1) exceeds 4095 on about half of the pixels, and clipping
        them leaves an error that averaging never removes; rounding alone keeps the
        model of eq. (2) exact in expectation.

    Returns
    -------
    (H, W) float64 ndarray
    """
    rng = np.random.default_rng(rng)
    K = check_positive(K, "K")
    check_nonnegative(L, "L")  # checked, not converted: the draws stay those of a given seed
    lam = np.asarray(image, dtype=np.float64)
    if np.any(lam < 0):
        raise ValueError("image must be non-negative grey levels to add Poisson noise")
    electrons = rng.poisson(lam / K)
    out = K * electrons + rng.normal(0.0, np.sqrt(L), size=lam.shape) if L > 0 else (
        K * electrons.astype(np.float64))
    if bits is not None:
        out = np.round(out)
        if clip:
            out = np.clip(out, 0, 2**bits - 1)
    return out
