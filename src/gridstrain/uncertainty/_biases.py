"""Systematic errors the uncertainty maps do not cover: the harmonics of sharp lines aliasing
onto the carrier (:func:`aliasing_bias`) and the window's smoothing of strain gradients
(:func:`smoothing_bias`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from .._validation import (
    as_image,
    check_positive,
)
from ..phase._validity import filled_box
from ._maps import _ATTENUATION

__all__ = ["aliasing_bias", "smoothing_bias"]

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


def nearest_filled(a: np.ndarray, valid: np.ndarray, nearest=None) -> np.ndarray:
    """``a`` with its invalid pixels set to the nearest valid pixel's value
    (``nearest``: :func:`nearest_index` of ``valid``, when known)."""
    if valid.all() or not valid.any():
        return np.where(valid, a, 0.0)
    return a[nearest_index(valid) if nearest is None else nearest]


def nearest_index(valid: np.ndarray) -> tuple:
    """The index of each pixel's nearest valid pixel (rows, columns), arrays that
    broadcast to ``valid``'s shape.

    Where the valid pixels fill a rectangle (a frame's band of margin, no mask) the
    nearest one is the pixel clamped into it, its unique closest point: no distance
    transform is needed."""
    box = filled_box(valid)
    if box is not None:
        (H, W), (r0, r1, c0, c1) = valid.shape, box
        return (np.clip(np.arange(H), r0, r1 - 1)[:, None],
                np.clip(np.arange(W), c0, c1 - 1)[None, :])
    return tuple(ndimage.distance_transform_edt(~valid, return_distances=False,
                                                return_indices=True))


def local_departure(e: np.ndarray, valid: np.ndarray, sigma: float, nearest=None) -> np.ndarray:
    """``e`` less its median over 8 sigma around, taken on a grid of step ``sigma``
    (a ridge 2 to 3 sigmas wide holds 3 of the 9 columns of the median's window,
    which keeps it out of its background at a sigma^2-th of the full median's
    cost); invalid pixels take their nearest valid neighbour's value
    (``nearest``: :func:`nearest_index` of ``valid``, when known)."""
    f = nearest_filled(np.asarray(e, dtype=np.float64), valid, nearest)
    step = max(1, int(sigma))
    coarse = f[::step, ::step]
    size = max(3, round(8.0 * sigma / step) | 1)
    bg = ndimage.median_filter(coarse, size=size, mode="nearest")
    zoom = (f.shape[0] / bg.shape[0], f.shape[1] / bg.shape[1])
    full = ndimage.zoom(bg, zoom, order=1, mode="nearest", grid_mode=True)
    return f - full[:f.shape[0], :f.shape[1]]
