"""The transform up to the specimen's edges: the grid continued beyond them by its own
demodulated maps, then transformed whole (:func:`transform_to_edges`).

Near an edge the Gaussian window is cut: the mean grey level and the conjugate carrier
leak into ``Psi`` and the phase is biased by up to 1e-2 rad at the edge
(:mod:`gridstrain.phase.window`, ``DEFAULT_MARGIN``). Here the pixels beyond the edge
(outside the mask, and a band beyond the frame) are filled, before the window, with
the grid that the specimen's own maps predict there: at each outside pixel ``q``, from
the nearest *trusted* pixel ``t`` (at least ``depth`` px inside the edge), the phase
continued by its second-order Taylor expansion and the modulus and the mean grey level
held constant,

    phi_j(q) = phi_j(t) + grad phi_j(t) . d + 1/2 d^T Hess phi_j(t) d,   d = q - t,
    v(q) = a(t) + sum_j 2 |Psi_j(t)| cos(2 pi k_j . q + phi_j(q)),

then the extended image is transformed without a mask. The maps that the continuation
is drawn from are those of the previous transform: a few passes reach the fixed point,
where the continuation is that of the extended transform's own maps.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from .._stats import median
from .._validation import as_image, check_mask, check_type
from ._maps import PhaseMaps, finite_derivatives
from ._transform import _wft
from ._validity import _region
from .lattice import Lattice
from .window import Window

__all__ = ["EDGE_DEPTH", "EDGE_PASSES", "edge_pixels", "transform_to_edges"]

#: Depth, in window standard deviations, of the trusted pixels the continuation starts
#: from. Closer to the edge their maps are themselves the continuation's (the window
#: straddles it); deeper, the Taylor expansion reaches farther (its error grows as the
#: cube of the distance for a quadratic strain).
EDGE_DEPTH = 2.0
#: Passes of continuation and transform: the first starts from the masked transform,
#: whose maps at ``EDGE_DEPTH`` sigmas are biased by ~1e-2 rad; each pass divides the
#: error by the weight of the window beyond the edge seen from the trusted pixels
#: (about 6: 16 % of a Gaussian lies beyond one sigma).
EDGE_PASSES = 8


def edge_pixels(mask, window: Window) -> np.ndarray:
    """The pixels of ``mask`` within the window's band (``margin * sigma`` px) of its
    edges or of the frame's border: those that only :func:`transform_to_edges`
    measures.

    Parameters
    ----------
    mask : (H, W) bool array_like
        The specimen (:mod:`gridstrain.conventions`, Masks).
    window : Window

    Returns
    -------
    (H, W) bool ndarray
    """
    check_type(window, "window", Window)
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise ValueError(f"mask must be a 2-D boolean array, got shape {m.shape}")
    interior = _region(m, bool(m.all()), window.band)[0]
    return m & ~interior


def transform_to_edges(image, lattice: Lattice, window: Window, *, mask=None,
                       passes: int = EDGE_PASSES, depth: float = EDGE_DEPTH) -> PhaseMaps:
    """The windowed Fourier transform of ``image`` valid up to the edges of ``mask``
    and of the frame, the grid continued beyond them by its own maps.

    Parameters
    ----------
    image : (H, W) array_like
        Grid image, grey levels (float64 computation; float32 kept float32).
    lattice : Lattice
    window : Window
        ``sigma``, ``margin`` (the band beyond the edges that is filled, px =
        ``margin * sigma``) and ``min_modulus``.
    mask : (H, W) bool array_like, optional
        True on the specimen; its pixels must show the grid up to its edges (a mask
        one or two pixels inside the specimen's edge is safe, one reaching beyond it
        mixes the background into the continuation).
    passes : int
        Continuations and transforms (default :data:`EDGE_PASSES`).
    depth : float
        Depth of the trusted pixels, sigmas (default :data:`EDGE_DEPTH`).

    Returns
    -------
    PhaseMaps
        ``(H, W)`` maps; ``valid`` where ``mask`` is and both moduli reach
        ``min_modulus`` times their median over the mask, up to the edges.

    Notes
    -----
    The continuation is exact for a phase quadratic over the window's reach beyond
    the edge (``4 sigma``), that is for a strain linear in space, and for an
    amplitude of the grid constant along the normal to the edge; the image's
    harmonics (a square profile, a checkerboard's cross terms) are not continued:
    a grid with strong harmonics keeps part of the cut window's bias.

    For a strain quadratic in ``x`` normal to the edge, ``eps(x) = eps'' x^2 / 2``,
    the phase's cubic term ``2 pi eps'' d^3 / (6 p)`` is missed beyond the trusted
    pixels; the window at the edge weighs it with its part outside the specimen, and
    the strain at an edge pixel is biased by about ``-c eps'' sigma^2`` with ``c``
    of order one (:func:`edge_bias_quadratic` gives it for a straight edge).

    The noise: fewer of the window's pixels are measured and the continuation
    repeats the trusted pixels' noise, amplified by the Taylor expansion's
    derivatives; the strain std at an edge pixel is a few times the interior's
    (:func:`edge_noise_gain`).
    """
    check_type(lattice, "lattice", Lattice)
    check_type(window, "window", Window)
    img = as_image(image)
    m = check_mask(mask, img.shape)
    if isinstance(passes, bool) or not isinstance(passes, int) or passes < 1:
        raise ValueError(f"passes must be an integer >= 1, got {passes!r}")
    sigma = window.sigma
    H, W = img.shape
    P = math.ceil(window.band) + 1
    big = np.zeros((H + 2 * P, W + 2 * P), dtype=img.dtype)
    big[P:P + H, P:P + W] = img
    spec = np.zeros(big.shape, dtype=bool)
    spec[P:P + H, P:P + W] = m
    # the first maps: the masked transform, biased near the edges
    pm = _wft(big, lattice, sigma=sigma, mask=spec, margin=window.margin,
              min_modulus=window.min_modulus, derivatives="exact", checked=True)
    trusted = ndimage.distance_transform_edt(np.pad(spec, 1))[1:-1, 1:-1] > depth * sigma
    if not trusted.any():
        raise ValueError(f"mask: no pixel lies {depth:g} sigmas ({depth * sigma:.3g} px) "
                         "inside the specimen's edges to continue the grid from")
    outside = ~spec
    # the nearest trusted pixel of every pixel, and the offset to it
    _, (ti, tj) = ndimage.distance_transform_edt(~trusted, return_indices=True)
    qi, qj = np.nonzero(outside)
    si, sj = ti[qi, qj], tj[qi, qj]
    dy = (qi - si).astype(np.float64)
    dx = (qj - sj).astype(np.float64)
    # the transform of the padded frame has its carrier at the padded coordinates
    X, Y = qj.astype(np.float64), qi.astype(np.float64)
    K = np.array(lattice.K, dtype=np.float64)
    fill = big.astype(np.float64)
    for k in range(passes):
        # the mean grey level under the window: over the specimen at first, then over
        # the whole continued image (a cut window would let the carriers leak into it)
        mean = (_local_mean(big, spec, sigma) if k == 0 else
                ndimage.gaussian_filter(fill, sigma, mode="constant"))
        values = mean[si, sj]
        for j in range(2):
            psi = pm.psi[j]
            g = pm.dphi[j].astype(np.float64)
            phi = np.angle(psi[si, sj]) + g[0][si, sj] * dx + g[1][si, sj] * dy
            carrier = 2 * math.pi * (K[j, 0] * X + K[j, 1] * Y)
            values += 2 * np.abs(psi[si, sj]) * np.cos(carrier + phi)
        fill[qi, qj] = values
        pm = _wft(fill.astype(img.dtype), lattice, sigma=sigma, mask=None,
                  margin=window.margin, min_modulus=window.min_modulus,
                  derivatives="exact", checked=True)
    inner = (slice(P, P + H), slice(P, P + W))
    # Psi at the frame's own coordinates (conventions: the absolute carrier)
    shift = np.exp(2j * math.pi * P * (K[:, 0] + K[:, 1])).astype(pm.psi.dtype)
    psi = pm.psi[(slice(None), *inner)] * shift[:, None, None]
    dphi = np.ascontiguousarray(pm.dphi[(slice(None), slice(None), *inner)])
    valid = m.copy()
    if valid.any():
        for j in range(2):
            mod = np.abs(psi[j])
            valid &= mod >= window.min_modulus * median(mod[m])
    return finite_derivatives(PhaseMaps(psi=psi, dphi=dphi, valid=valid, lattice=lattice,
                                        sigma=sigma))


def _local_mean(image: np.ndarray, mask: np.ndarray, sigma: float) -> np.ndarray:
    """The mean grey level of the specimen under the window: the Gaussian average of
    ``image`` over ``mask`` (normalised by the window's weight on it)."""
    w = ndimage.gaussian_filter(mask.astype(np.float64), sigma, mode="constant")
    s = ndimage.gaussian_filter(np.where(mask, image, 0.0).astype(np.float64), sigma,
                                mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(w > 0, s / np.where(w > 0, w, 1.0), 0.0)
