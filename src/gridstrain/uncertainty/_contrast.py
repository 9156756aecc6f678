"""The bias next to a step of the grid's contrast (a stain, a shadow, a hole's edge
appearing between two states): a systematic error the uncertainty maps do not cover
(:func:`contrast_step_bound`), bounded pixel by pixel from the measured moduli.

A step of the image's amplitude is not band-limited: its spectrum, a ``1/f`` tail,
carries the grid's conjugate, its harmonics and the mean level into the carrier's
band, and the window's phase is off next to it. The error follows the modulus's
steepness ``s = sigma |grad ln |Psi||``: about 0.046 ``s`` px for a contrast step,
0.15-0.18 ``s`` px for a stain that darkens mean level and contrast alike and up to
0.24 ``s`` px for a step of the mean level alone (pitch 5 px, sigma 5 px, contrast
drops of 0.3-0.9, mean drops of 0.3-0.5; tests/test_small_defects.py). A feature
carried by the specimen is seen at the same material point in both states with the
same bias, which cancels in ``u``: what counts is the change of the log-modulus's
gradient between the reference at ``x`` and the deformed state at ``x + u``.

A hole's edge moving with the specimen (0.3 to 3.4 px) gives a bound of 0.001 to
0.0015 px beside it, the order of the window's other errors there.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .._validation import check_positive

__all__ = ["CONTRAST_STEP_PX", "contrast_step_bound"]

#: The bound's displacement per unit of the steepness's change, px: above the
#: largest error over steepness measured (0.24 for a step of the mean level alone,
#: 0.18 for a stain, 0.063 for a contrast step), so that the bound holds wherever
#: the leak is what makes the error.
CONTRAST_STEP_PX = 0.3

# Pixels whose material points are computed at once.
_BLOCK = 1 << 20


def _log_gradient(psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``grad ln |psi|`` per px, ``(d/dx, d/dy)``; zero where the modulus is zero."""
    mod = np.abs(psi)
    tiny = np.finfo(np.float64).tiny
    lg = np.log(np.maximum(mod, tiny, out=mod) if mod.dtype == np.float64 else
                np.maximum(mod, tiny))
    gy, gx = np.gradient(lg)
    return gx, gy


def contrast_step_bound(reference_psi, deformed_psi, u, valid, *, sigma: float) -> np.ndarray:
    """A per-pixel bound on the displacement's bias next to a change of the grid's
    contrast, px (NaN where not ``valid``).

    Parameters
    ----------
    reference_psi, deformed_psi : (2, H, W) complex array_like
        The two states' windowed transforms at their carriers.
    u : (2, H, W) array_like
        Measured displacement ``(u_x, u_y)``, px, Lagrangian.
    valid : (H, W) bool array_like
    sigma : float
        Window standard deviation, px.

    Returns
    -------
    (H, W) float ndarray
        ``CONTRAST_STEP_PX`` times the largest over the carriers of
        ``sigma |grad ln|Psi_def|(x + u) - grad ln|Psi_ref|(x)|``, its largest
        value within a sigma.
    """
    sigma = check_positive(sigma, "sigma")
    ref = np.asarray(reference_psi)
    dfm = np.asarray(deformed_psi)
    v = np.asarray(valid, dtype=bool)
    if ref.shape != dfm.shape or ref.ndim != 3 or ref.shape[1:] != v.shape:
        raise ValueError(f"reference_psi and deformed_psi must be (n, H, W) with (H, W) "
                         f"valid's shape {v.shape}, got {ref.shape} and {dfm.shape}")
    H, W = v.shape
    u = np.asarray(u)
    s = np.zeros((H, W))
    # the material points' coordinates by blocks of rows: two float64 maps of the
    # image's size would be the largest arrays of the bound
    step = max(1, _BLOCK // W)
    cols = np.arange(W, dtype=np.float64)[None, :]
    for r, d in zip(ref, dfm, strict=True):
        gr = _log_gradient(r)
        gd = _log_gradient(d)
        for r0 in range(0, H, step):
            b = slice(r0, min(H, r0 + step))
            vb = v[b]
            rows = np.arange(b.start, b.stop, dtype=np.float64)[:, None]
            # one (2, h, W) array for both maps (a list is made into one at each call)
            at = np.empty((2, *vb.shape))
            np.add(rows, np.where(vb, u[1, b], 0.0), out=at[0])
            np.add(cols, np.where(vb, u[0, b], 0.0), out=at[1])
            dx, dy = (ndimage.map_coordinates(g, at, order=1, mode="nearest") - q[b]
                      for g, q in zip(gd, gr, strict=True))
            np.maximum(s[b], np.hypot(dx, dy), out=s[b])
    # the steepness ripples within a period where the leak does not (the grid's
    # harmonics in the modulus): its largest value within a sigma bounds the leak,
    # over the valid pixels only (an invalid one is not followed by u, and a hole's
    # collapsing modulus would spread into the valid band around it)
    s[~v] = 0.0
    size = 2 * int(np.ceil(sigma)) + 1
    s = ndimage.maximum_filter(s, size=size, mode="nearest")
    return np.where(v, CONTRAST_STEP_PX * sigma * s, np.nan)
