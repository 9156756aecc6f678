"""The grid's harmonics aliasing onto the carriers: a systematic error the uncertainty
maps do not cover (:func:`aliasing_bias`), its per-pixel bound and the advice it gives.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import scipy.linalg
from scipy import ndimage

from .._validation import (
    as_image,
    check_positive,
)
from ._maps import SPATIAL_RESOLUTION_PER_SIGMA

__all__ = ["aliasing_advice", "aliasing_bias", "aliasing_bound_at"]

# Harmonics above this spatial frequency, cycles/px, are left out. No lens is taken to
# cut them: perfect optics leave the pixel's integration alone, sinc(h), and a sharp
# line's n-th harmonic 1/n of its fundamental, which still reach the carriers' band
# (at pitch 5 px the 9th and 11th, 1.8 and 2.2 cycles/px, made errors 9 times a bound
# stopped at 1.6). Counting up to 3 cycles/px moves the bound of sharp lines at pitch 4
# to 8 px by under 5 % against 4.5 cycles/px (tests/bias_cases.py).
_OPTICS_CUTOFF = 3.0

# Harmonics that cannot be measured (their folds on the carrier's) and lie above this
# frequency, cycles/px, are not counted: the diffraction cut-off 1 / (lambda N) of an
# f/5.6 lens in green light (0.55 um) on 5-um pixels.
_MODEL_CUTOFF = 1.6


def _dtfts(rw: np.ndarray, freqs) -> np.ndarray:
    """The transform of the weighted image ``rw`` at each frequency of ``freqs``
    ``(f_x, f_y)``, cycles/px, at once: two matrix products instead of one pass over
    the image per frequency."""
    H, W = rw.shape
    f = np.asarray(freqs, dtype=np.float64).reshape(-1, 2)
    if not len(f):
        return np.zeros(0, dtype=np.complex128)
    ey = np.exp(-2j * np.pi * f[:, 1:2] * np.arange(H))  # (n, H)
    ex = np.exp(-2j * np.pi * f[:, 0:1] * np.arange(W))  # (n, W)
    return np.sum((ey @ rw) * ex, axis=1)


def aliasing_bias(image, lattice, *, sigma: float, mask=None) -> dict:
    """Bound of the displacement and strain errors from the grid's harmonics aliasing onto
    the carriers, measured on the reference image.

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
        ``u_px_components`` (2,): bound of the ``(u_x, u_y)`` error, px; ``u_px`` their
        largest; ``phase_rad`` (2,): amplitude of one image's phase error per wave
        vector, rad; ``strain_per_strain``: bound of the strain error per unit of
        measured strain (the largest component); ``strain_ripple``: the strain error's
        part that does not scale with the strain (dimensionless); ``harmonics``: one
        record per harmonic counted (``order`` ``(n, m)``, ``carrier`` 1 or 2,
        ``relative_amplitude`` to the carrier's, ``fold_distance`` cycles/px,
        ``transfer`` of the window, ``measured``); ``observable``: every harmonic
        counted was measured (otherwise the sharp-print model stands in, see Notes);
        ``sigma`` the window's, px; ``pattern`` ("measured", or the model's "lines" or
        "checkerboard"), ``sharpness`` (the model's scale for odd and even
        harmonics, 1 when measured),
        ``method``.

    Notes
    -----
    The reference image holds the harmonics ``h = n k1 + m k2`` of its lattice, every
    ``(n, m)``: even and odd orders, and the cross terms that a grid's ink crossings
    or a checkerboard make. Sampling folds ``h`` to ``h`` modulo 1 cycle/px; one that
    lands at ``Delta`` from a carrier ``k_j`` passes the window with the transfer
    ``exp(-2 pi^2 sigma^2 Delta^2)`` and adds to the carrier's phase a term of
    amplitude ``r_h = |c_h| / |c_j|`` times that transfer, whose phase moves as
    ``2 pi (h - k_j) . u``: ``n`` times faster than the carrier's. The error is
    periodic in the displacement, not a constant: the reference's and the deformed
    image's terms add with phases that differ by ``2 pi (h - k_j) . u``, so the
    displacement error is bounded by twice one image's amplitude,
    ``|K^-1| 2 A / 2 pi`` per component (``A = sum_h r_h T_h``, ``K`` the matrix of
    the wave vectors), and the strain error by ``|K^-1| sum_h r_h T_h (|h - k_j| e +
    2 |Delta_h|)``; both times 1.25, for a print whose harmonics' share varies line by
    line about the image's average that is measured.

    The amplitudes are measured, not modelled: the harmonics whose folds lie within
    the window's band of a carrier are fitted jointly with the carrier (each amplitude,
    the carrier's and every harmonic's, allowed to vary linearly across the image, and
    again with the carrier's quadratically, the smaller of the two shares kept: each
    fit leaks the carrier's envelope into the folds nearest it in its own way; a
    harmonic's share is its largest ratio to the carrier's at 3 x 3 points over the
    window's region: a print whose line width drifts across the specimen changes that
    share from place to place, and an even harmonic of lines half a pitch wide changes
    sign where the width crosses half the pitch) by weighted least squares, a Hann
    window times the mask, on the image divided by its lighting (a polynomial of
    degree 6 fitted to it, :func:`_lighting`: a varying lighting would widen the
    carrier's peak over the bins where the folds lie). The power that noise and print
    defects put at every frequency, measured where no harmonic folds, is taken out in
    quadrature (a local amplitude whose power is under 9 times that noise's is taken
    as noise), and no amplitude
    exceeds the mean level times the pixel's integration at its frequency (a
    reflectance is not negative). A lattice turned or stretched away from a whole
    number of pixels puts the folds a few frequency bins apart from the carrier and
    from one another, where they are told apart. A harmonic whose
    fold cannot be told from its neighbours' (an integer pitch along the pixel axes:
    it lands exactly on the carrier, where no window removes it and no single image
    sees it) is not measurable; then the sharp-print model stands in for it (lines of
    amplitudes ``1/|n| 1/|m|``, checkerboards ``1/|n^2 - m^2|``, times the pixel's
    integration), scaled by the largest ratio of what is seen to that model: on the
    measured harmonics, and on one family's harmonics where they fold away from the
    carriers (each fold against the largest model amplitude folding there), or 1
    when nothing is seen; ``observable`` is False. No correction is applied: a harmonic on
    the carrier cannot be removed, and one off it is damped by the window already;
    the bound is stated and warned about where it exceeds the noise.

    Harmonics up to 3 cycles/px are counted: perfect optics leave the pixel's
    integration, ``sinc(h)``, as the only cut. On noise-free prints of sharp lines
    (``tests/bias_cases.py``: pitch 4 to 8 px, perfect optics or a Gaussian blur of
    0.5 and 1 px, line width drifting by 0 or +-20 % across the frame, vignetting 0 or
    50 %) the bound holds in 120 of 120 cases, 1.2 to 7.1 times the largest error
    where it exceeds 1e-3 px (median 2.3), and stays under 0.0075 px where the errors
    are 1e-5 px (blurred prints: no warning at ordinary noise levels;
    ``tests/test_bounds.py``; errors under 1e-4 px aside). Harmonics that cannot be
    measured are counted up to 1.6 cycles/px only.

    Figures (``tests/test_aliasing.py``): one harmonic of a direct sum, its amplitude
    to 2 % and the measured error 0.8 times the bound; photographs of printed lines
    0.2 to 0.5 pitch wide at pitches 4 to 7 px turned by 0.6 degree (noise-free,
    stretched by 2 % and -0.6 %), largest errors 0.01 to 0.13 px, bounds 1.6 to 22
    times them; a photographed sine grid, under half the noise std.
    """
    img = as_image(image, allow_uniform=True).astype(np.float64)
    sigma = check_positive(sigma, "sigma")
    box = _central(img.shape)
    img = img[box]
    w = _aliasing_window(img.shape, lattice,
                         None if mask is None else np.asarray(mask, dtype=bool)[box])
    img = img / _lighting(img, w)
    mean = float(np.sum(img * w) / np.sum(w))
    ref = img - mean
    ks = [np.array(lattice.k1, dtype=np.float64), np.array(lattice.k2, dtype=np.float64)]
    floor = _floor(ref, w, lattice)
    records = []
    for j, k in enumerate(ks):
        records.extend(_measured_harmonics(ref, w, lattice, j, k, sigma, mean, floor))
    if any(not r["measured"] and r["relative_amplitude"] * r["transfer"] > _NEGLIGIBLE
           for r in records):
        return _model_bound(ref, w, lattice, sigma, records)
    return _bound(records, lattice, sigma, observable=True, pattern="measured",
                  sharpness=[1.0, 1.0],
                  method="every harmonic n k1 + m k2 folded within the window's band of a "
                         "carrier, its amplitude fitted on the reference image, weighted "
                         "by the window's transfer; twice one image's error (reference "
                         "and deformed)")


# The degree of the polynomial in (x, y) that stands for the lighting: dividing by
# it divides the carrier too, and what the polynomial misses of the vignetting (the
# cos^4 law, 50 % at the corners) is left on the carrier's envelope, a curvature the
# fit reads as harmonics folded near it: degree 4 left bounds of 0.005 to 0.015 px
# on blurred prints whose errors are 1e-5 px, degree 6 0.001 to 0.008 (degree 8 no
# less; tests/bias_cases.py).
_LIGHT_DEGREE = 6


def _lighting(img, w) -> np.ndarray:
    """The lighting over the image: a polynomial of degree ``_LIGHT_DEGREE`` in the
    pixel's coordinates fitted to ``img`` by least squares with the weights ``w``, 1
    where it is not positive (outside the weights).

    A local mean (a Gaussian over two pitches, normalised) damps the carriers in the
    image's interior but not where the image's border cuts it: there its window's cut
    leaves about 2 % of the carrier (``g(0) / 2 pi k``), a ripple along the border
    that spreads the carrier's spectrum over the bins where the nearest folds lie
    (0.07 % of the carrier read as harmonics on a pure sine grid, bounds of 0.01 to
    0.05 px where the errors were 1e-5 px). A polynomial has no carrier to leak: the
    Hann-weighted projection of a carrier on it is the window's transform far from
    zero. Lighting gradients and vignetting (the cos^4 law) over a few hundred pixels
    are smooth polynomials; what is sharper (a stain, a hole) is the reflectance's
    modulation of the carrier, measured on the ring around it (:func:`_ring_floor`).
    """
    H, W = img.shape
    y = (np.arange(H) - (H - 1) / 2) / H
    x = (np.arange(W) - (W - 1) / 2) / W
    terms = [(a, b) for a in range(_LIGHT_DEGREE + 1) for b in range(_LIGHT_DEGREE + 1 - a)]
    sw = np.sqrt(w).ravel()
    A = np.stack([np.outer(y**b, x**a).ravel() * sw for a, b in terms], axis=1)
    coef = np.linalg.lstsq(A, img.ravel() * sw, rcond=None)[0]
    light = sum(c * np.outer(y**b, x**a) for c, (a, b) in zip(coef, terms, strict=True))
    return np.where((w > 0) & (light > 0), light, 1.0)


# The smallest share of the carrier's amplitude, after the window, that counts.
_NEGLIGIBLE = 1e-4

# Largest side of the region the harmonics are measured on, px: a central crop
# resolves the folds (1 / 256 cycle/px) at a bounded cost.
_MEASURE_SIDE = 256

# A harmonic is measured when its fit's variance is at most this many times what it
# would be alone: beyond, its fold overlaps another's or the carrier's. Up to it the
# noise taken out is the inflated one: a pair of folds two bins either side of the
# carrier is, over the Hann window, much like the carrier's quadratic envelope
# (inflations of 5 to 8 at the 192-px side), yet told apart from it.
_INFLATION = 10.0
# ... and in the fit whose carrier's envelope is linear (its columns the fewer).
_INFLATION_LINEAR = 2.0

# Folds closer than this, in bins of the spectrum, are not told apart (the Hann
# window's main lobe is 2 bins wide each side).
_APART = 1.5

# The powers of (x, y) that multiply a harmonic in the fit, and the carrier (its
# first _CARRIER_TERMS): the carrier's own envelope is quadratic, since the share of
# the light in the fundamental of lines whose width drifts linearly across the
# specimen, (1 - f) sin(pi f) / pi with f the line's fraction of the pitch, is not
# linear in it; a linear envelope leaves the curvature to the harmonics folded a few
# bins from the carrier, read as harmonics of 0.5 % of it where the lens leaves none
# (blurred prints of half-pitch lines drifting by +-20 %: bounds of 0.03 to 0.045 px
# over errors of 1e-5 px).
_POWERS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))
_HARMONIC_TERMS = 3
_LINEAR_TERMS = 3
_CARRIER_TERMS = len(_POWERS)

# The amplitudes fitted are the image's averages; a print whose lines' widths vary
# (a printer's banding, 6 % std) changes a harmonic's share line by line: the
# largest local error of noise-free lines 0.2 pitch wide at pitch 4 px
# (tests/world_camera.py) is 1.2 times the bound from the averages.
_LOCAL = 1.25


def _central(shape) -> tuple:
    """The slices of the central ``_MEASURE_SIDE`` square of an image of ``shape``."""
    H, W = shape
    r0, c0 = max(0, (H - _MEASURE_SIDE) // 2), max(0, (W - _MEASURE_SIDE) // 2)
    return slice(r0, r0 + _MEASURE_SIDE), slice(c0, c0 + _MEASURE_SIDE)


def _fold(f):
    return (f + 0.5) % 1.0 - 0.5


def _transfer(delta, sigma):
    """The Gaussian window's transfer at ``delta`` cycles/px."""
    return math.exp(-2 * math.pi**2 * sigma**2 * delta**2)


def _harmonics_near(lattice, k, sigma, radius_extra=0.0):
    """``[(n, m, h, fold, Delta)]``: the lattice's harmonics (below the optics'
    cut-off) whose fold lies within the window's band of ``k`` (transfer above
    ``_NEGLIGIBLE``), or ``radius_extra`` cycles/px beyond it."""
    k1, k2 = np.array(lattice.k1), np.array(lattice.k2)
    k = np.asarray(k, dtype=np.float64)
    band = math.sqrt(math.log(1 / _NEGLIGIBLE) / (2 * math.pi**2)) / sigma + radius_extra
    top = int(_OPTICS_CUTOFF / min(np.hypot(*k1), np.hypot(*k2))) + 1
    # every order (n, m) at once, n the slower index: the orders in the loops' order
    n, m = (a.ravel() for a in np.meshgrid(np.arange(-top, top + 1),
                                           np.arange(-top, top + 1), indexing="ij"))
    h = n[:, None] * k1 + m[:, None] * k2
    keep = ((n != 0) | (m != 0)) & (np.hypot(h[:, 0], h[:, 1]) <= _OPTICS_CUTOFF) \
        & ~np.all(np.isclose(h, k), axis=1)  # as np.allclose, order by order
    d = _fold(h) - k
    d = d - np.round(d)  # the carrier's own images one cycle/px away
    delta = np.hypot(d[:, 0], d[:, 1])
    return [(int(n[i]), int(m[i]), h[i], k + d[i], float(delta[i]))
            for i in np.flatnonzero(keep & (delta <= band))]


def _measured_harmonics(ref, w, lattice, j, k, sigma, mean, floor) -> list[dict]:
    """The harmonics that fold near carrier ``k`` (index ``j``), their amplitudes
    relative to the carrier's fitted on ``ref`` (the image less its ``mean``) with
    weights ``w``, less the ``floor`` (:func:`_floor`) in quadrature."""
    H, W = ref.shape
    res = 1.0 / min(H, W)  # a bin of the spectrum, cycles/px
    near = _harmonics_near(lattice, k, sigma)
    if not near:
        return []
    # harmonics just outside the band are fitted too, lest they leak into those in it;
    # a fold closer than _APART bins (along each axis) to the carrier or to another
    # fold is one frequency with it: not fitted, not measured
    fit = _harmonics_near(lattice, k, sigma, radius_extra=4 * res)
    freqs = np.array([k, *(f for *_, f, _ in fit)])
    gap = np.hypot(*((freqs[:, None, :] - freqs[None, :, :]) * np.array([W, H])).T)
    np.fill_diagonal(gap, np.inf)
    fit = [x for x, g in zip(fit, gap[1:], strict=True) if g.min() >= _APART]
    yy = (np.arange(H) - (H - 1) / 2) / H
    xx = (np.arange(W) - (W - 1) / 2) / W
    # the carrier and every harmonic times 1, x, y: what the lighting's division left
    # of the carrier's variation, and a print whose lines' width drifts across the
    # specimen, which changes a harmonic's share of the light from place to place (an
    # even harmonic of lines half a pitch wide changes sign where the width crosses
    # half the pitch: its average over the image is nil where it is not)
    sep = _separable(w)
    low_rank = None if sep is not None else _low_rank(w)

    # the powers less their weighted means: a square's mean, left in, makes it one
    # with the constant (the carrier's mean amplitude inflated 40 to 90 times)
    mx, my = w.sum(axis=0), w.sum(axis=1)
    powx = [xx**p - (np.sum(mx * xx**p) / np.sum(mx) if p == 2 else 0.0) for p in range(3)]
    powy = [yy**p - (np.sum(my * yy**p) / np.sum(my) if p == 2 else 0.0) for p in range(3)]

    def waves(f, kind):
        px, py = _POWERS[kind]
        return (np.exp(2j * np.pi * f[0] * np.arange(W)) * powx[px],
                np.exp(2j * np.pi * f[1] * np.arange(H)) * powy[py])

    def solve(cols):
        # the normal equations through the Gram matrix's pseudo-inverse, which the
        # inflation needs anyway: a few columns of well-separated frequencies (those
        # closer are left out above) keep it well conditioned, and a column it
        # cannot resolve is inflated beyond _INFLATION
        pairs = [waves(fit_f[t] if t >= 0 else k, kind) for t, kind in cols] + \
            [waves(e, kind) for e in others for kind in range(_HARMONIC_TERMS)]
        EX = np.array([x for x, _ in pairs])  # (n, W)
        EY = np.array([y for _, y in pairs])  # (n, H)
        if sep is not None:
            # separable weights (no mask, or a rectangle): the Gram matrix is the
            # product of the two axes' and the projections two matrix products,
            # (H + W) n^2 and H W n operations instead of H W n^2
            wy, wx = sep
            gram = ((EY.conj() * wy) @ EY.T) * ((EX.conj() * wx) @ EX.T)
            M = (ref * wx) @ EX.conj().T  # (H, n)
            rhs = np.sum(EY.conj().T * wy[:, None] * M, axis=0)
        else:
            # a mask's window is smooth (softened over a pitch) and of low rank: a
            # sum of a few separable terms (10 to 20 for a rectangular or round hole,
            # to 1e-10 of the largest), each as cheap as the separable case, instead
            # of the H W n^2 products of the full design matrix; the projections use
            # that sum too, so that the fit is an exact least squares with its weights
            us, ss, vs = low_rank
            EYc, EXc = EY.conj(), EX.conj()
            gram = sum(sr * (((EYc * u) @ EY.T) * ((EXc * v) @ EX.T))
                       for sr, u, v in zip(ss, us.T, vs, strict=True))
            wl = (us * ss) @ vs
            M = (ref * wl) @ EXc.T  # (H, n)
            rhs = np.sum(EYc.T * M, axis=0)
        return gram, rhs

    fit_f = [f for *_, f, _ in fit]
    rw = ref * w
    # the image's other strong terms, fitted too (after the columns above): the other
    # carrier and both conjugates, whose window's leak near the carrier would
    # otherwise pass for the folds nearest it
    kk = [np.asarray(lattice.k1, dtype=np.float64), np.asarray(lattice.k2, dtype=np.float64)]
    others = [kk[1 - j], -kk[0], -kk[1]]
    # the carrier times 1, x, y (column t = -1), and every harmonic t the same: an
    # envelope whose fold lies near the carrier's is inflated (its variance, counted
    # at each point below, grows), but its drift is what is sought
    cols = [(-1, c) for c in range(_CARRIER_TERMS)] + \
        [(t, c) for t in range(len(fit)) for c in range(_HARMONIC_TERMS)]
    gram, rhs = solve(cols)
    cx, cy = (float(np.sum(mx * xx**2) / np.sum(mx)), float(np.sum(my * yy**2) / np.sum(my)))
    # the envelopes at points over the region the window weighs (its Hann window
    # above a third of its peak): the local amplitudes
    at = np.array([[(px**a - (cx if a == 2 else 0.0)) * (py**b - (cy if b == 2 else 0.0))
                    for a, b in _POWERS]
                   for px in _SPREAD for py in _SPREAD])  # (P, _CARRIER_TERMS)
    # two fits: the carrier's envelope linear (its curvature then leaks into the
    # folds a few bins from it along the curvature's direction) and quadratic (then
    # a pair of folds either side of the carrier, across it, resembles the
    # curvature, and its envelopes take the model's residue); a harmonic of the
    # print is in both, each fit's leak is its own: the smaller share is kept
    lin = np.r_[np.arange(_LINEAR_TERMS), np.arange(_CARRIER_TERMS, len(gram))]
    fits = [_Fit(gram[np.ix_(lin, lin)], rhs[lin], at[:, :_LINEAR_TERMS], _LINEAR_TERMS,
                 _INFLATION_LINEAR),
            _Fit(gram, rhs, at, _CARRIER_TERMS, _INFLATION)]
    index: dict = {}
    for q, (t, _) in enumerate(cols[_CARRIER_TERMS:]):
        index.setdefault(tuple(fit[t][:2]), []).append(q)
    folds = np.array(fit_f).reshape(-1, 2)
    out = []
    for n, m, h, f, delta in near:
        idx = index.get((n, m))
        ring = functools.cache(functools.partial(
            _ring_floor, rw, w, k, f - k, np.vstack([folds, [k]]), (W, H)))
        shares = [] if idx is None else [
            r for fi in fits
            if (r := fi.share(idx, delta, sigma, mean, h, k, floor, ring)) is not None]
        measured = bool(shares)
        if measured:
            r = min(shares)
        elif np.hypot(*h) > _MODEL_CUTOFF:
            # one that cannot be seen, above the cut-off of an f/5.6 lens, is left
            # to those below it: the sharp print's amplitudes summed to 3 cycles/px
            # take every harmonic at its largest and in phase, 12 times the error of
            # sharp lines at pitch 4 px (tests/test_noise_sources.py)
            continue
        else:
            r = _sharp_term(lattice, n, m, k, j)
        out.append({"order": [n, m], "carrier": j + 1, "relative_amplitude": r,
                    "fold_distance": delta, "transfer": _transfer(delta, sigma),
                    "change": float(np.hypot(*(h - k))), "measured": measured})
    return out


class _Fit:
    """One weighted least-squares fit of the carrier's envelope (its first ``nc``
    columns) and the harmonics' (three columns each, after it): the Gram matrix
    ``gram`` and the projections ``rhs``; ``at`` the carrier's terms at the points
    where the local shares are taken; a harmonic is measured where its variance is at
    most ``limit`` times what it would be alone."""

    def __init__(self, gram, rhs, at, nc, limit):
        self.inv = _inverse(gram)
        self.coef = self.inv @ rhs
        self.inflation = np.abs(np.real(np.diag(self.inv))) * np.real(np.diag(gram))
        self.nc, self.limit = nc, limit
        self.a_loc = np.abs(at @ self.coef[:nc])
        self.at = at

    def share(self, idx, delta, sigma, mean, h, k, floor, ring) -> float | None:
        """The harmonic of columns ``idx`` (after the carrier's) relative to the
        carrier, its largest over the points, less the noise; None if not measured."""
        idx = [self.nc + q for q in idx]
        a_loc, inflation = self.a_loc, self.inflation
        if not (inflation[idx[0]] <= self.limit and inflation[0] <= self.limit
                and a_loc.min() > 0):
            return None
        # the sensor's noise and the print's defects add their power at every
        # frequency, and the specimen's reflectance (a hole, an edge, a stain)
        # modulates the carrier, spreading its spectrum around it: both taken out
        # in quadrature, as measured where no harmonic folds, at random frequencies
        # and on the ring of the fold's distance around the carrier (``ring()``),
        # times the inflation of the harmonic's variance by its neighbours; an
        # envelope's value at a point is noisier than its mean by its variance
        # there over the mean's (the block of the inverse Gram matrix)
        pts = self.at[:, :len(idx)]
        blk = self.inv[np.ix_(idx, idx)]
        gain = np.real(np.einsum("pi,ij,pj->p", pts, blk, pts.conj())) / max(
            np.real(blk[0, 0]), 1e-300)
        loc2 = np.abs(pts @ self.coef[idx]) ** 2
        # (a share that counts for nothing even whole needs no floor)
        whole = math.sqrt(float(loc2.max())) / float(a_loc.min()) * _transfer(delta, sigma)
        near_floor = 0.0 if whole < _NEGLIGIBLE else ring()
        noise2 = gain * float(inflation[idx[0]]) * max(floor, near_floor)
        # a noise amplitude's power is exponential about its mean: the largest of
        # the 9 points of tens of harmonics would add tens of noise-level terms; one
        # whose power stands under _SIGNIFICANT times the noise's is taken as noise
        r2 = np.where(loc2 > _SIGNIFICANT * noise2, loc2 - noise2, 0.0) \
            / np.maximum(a_loc, 1e-300) ** 2
        # a print's reflectance is not negative: none of its Fourier coefficients
        # exceeds its mean, and the pixel's integration then multiplies each by
        # mtf(h): what is fitted beyond that is the carrier's modulation, not a
        # harmonic
        r_pts = np.minimum(np.sqrt(np.maximum(r2, 0.0)),
                           abs(mean) / np.maximum(a_loc, 1e-300) * _mtf(h) / _mtf(k))
        return float(r_pts.max())


def _inverse(gram):
    """The Gram matrix's inverse: by Cholesky where it is positive definite (a tenth
    of the cost of the pseudo-inverse's eigen-decomposition), else its pseudo-inverse."""
    try:
        c = scipy.linalg.cho_factor(gram, lower=True, check_finite=False)
        inv = scipy.linalg.cho_solve(c, np.eye(len(gram), dtype=gram.dtype),
                                     check_finite=False)
        if np.all(np.isfinite(inv)):
            return inv
    except np.linalg.LinAlgError:
        pass
    return np.linalg.pinv(gram, hermitian=True)


# A harmonic's power at a point below this many times the noise's there is taken as
# noise: a noise amplitude exceeds it with probability exp(-9) = 1.2e-4, once in
# about 20 images of 50 harmonics at 9 points.
_SIGNIFICANT = 9.0

# The singular values of a mask's window below this share of the largest are left
# out: the weights that remain differ from the window by as little.
_RANK_TOLERANCE = 1e-10


def _low_rank(w):
    """``(U, s, Vt)`` of the window ``w``: its singular vectors and values down to
    ``_RANK_TOLERANCE`` of the largest, ``w = U diag(s) Vt`` to that share."""
    u, sv, vt = np.linalg.svd(w, full_matrices=False)
    keep = sv > _RANK_TOLERANCE * sv[0]
    return u[:, keep], sv[keep], vt[keep]


def _separable(w):
    """``(wy, wx)`` with ``w == outer(wy, wx)`` (to rounding), or None."""
    total = float(w.sum())
    if not total > 0:
        return None
    wy, wx = w.sum(axis=1), w.sum(axis=0) / total
    if np.allclose(np.outer(wy, wx), w, rtol=0.0, atol=1e-12 * float(w.max())):
        return wy, wx
    return None


# The points, in fractions of the measured region's side from its centre, where the
# harmonics' local share of the carrier is taken: where its Hann window exceeds a
# third of its peak (cos^2(pi x) >= 1/3 for |x| <= 0.3).
_SPREAD = (-0.3, 0.0, 0.3)


# Offsets on the ring around a carrier where the power beside a fold is measured.
_RING = 12


def _ring_floor(rw, w, k, d, avoid, size) -> float:
    """The mean power at the carrier ``k`` plus ``d`` turned by ``_RING`` angles around
    it, away (``_APART`` bins or more) from every frequency in ``avoid``: what the
    carrier's own spectrum, spread by the specimen's reflectance, puts at the fold's
    distance from it."""
    total = float(np.sum(w))
    scale = np.asarray(size, dtype=np.float64)
    at = []
    for t in np.arange(1, _RING) * (2 * math.pi / _RING):
        c, s = math.cos(t), math.sin(t)
        f = k + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
        gaps = np.hypot(*((_fold(avoid - f)) * scale).T)
        if gaps.min() >= _APART:
            at.append(f)
    return float(np.mean(np.abs(_dtfts(rw, at) / total) ** 2)) if at else 0.0


def _floor(ref, w, lattice) -> float:
    """The mean power of a fitted amplitude where no harmonic folds: the image's
    weighted transform over the weights' sum, at up to 24 fixed frequencies 4 bins or
    more from every harmonic's fold and 8 from zero."""
    H, W = ref.shape
    res = 1.0 / min(H, W)
    k1, k2 = np.array(lattice.k1), np.array(lattice.k2)
    top = int(_OPTICS_CUTOFF / min(np.hypot(*k1), np.hypot(*k2))) + 1
    n, m = np.meshgrid(np.arange(-top, top + 1), np.arange(-top, top + 1))
    h = n.reshape(-1, 1) * k1 + m.reshape(-1, 1) * k2
    folds = _fold(h[np.hypot(h[:, 0], h[:, 1]) <= _OPTICS_CUTOFF])
    trial = np.random.default_rng(0).uniform(-0.5, 0.5, (400, 2))  # the same each call
    d = _fold(trial[:, None, :] - folds[None, :, :])
    free = trial[np.all(np.hypot(d[..., 0], d[..., 1]) > 4 * res, axis=1)
                 & (np.hypot(*trial.T) > 8 * res)][:24]
    if free.size == 0:
        return 0.0
    total = float(np.sum(w))
    return float(np.mean(np.abs(_dtfts(ref * w, free) / total) ** 2))


def _mtf(f):
    """The pixel's integration of a harmonic of frequency ``f`` (cycles/px)."""
    return abs(float(np.sinc(f[0]) * np.sinc(f[1])))


def _sharp_term(lattice, n, m, k, j) -> float:
    """A sharp grid's harmonic ``(n, m)`` relative to its fundamental ``j``: lines of
    amplitudes ``1 / |n|`` along each axis and their crossings' products."""
    h = n * np.array(lattice.k1) + m * np.array(lattice.k2)
    return _mtf(h) / _mtf(k) / (max(1, abs(n)) * max(1, abs(m)))


def _bound(records, lattice, sigma, *, observable, pattern, sharpness, method) -> dict:
    """The result dict of :func:`aliasing_bias` from its harmonics' records."""
    kinv = np.abs(np.linalg.inv(np.array([lattice.k1, lattice.k2])))  # px per cycle
    amp, per_e, ripple = np.zeros(2), np.zeros(2), np.zeros(2)
    for r in records:
        j = r["carrier"] - 1
        t = r["relative_amplitude"] * r["transfer"]
        amp[j] += t
        per_e[j] += t * r["change"]
        ripple[j] += t * 2 * r["fold_distance"]
    u = _LOCAL * kinv @ (2 * amp) / (2 * math.pi)
    # the two images' terms: each moves its phase by 2 pi |h - k| . grad(u) per px
    e = _LOCAL * kinv @ per_e
    rip = _LOCAL * kinv @ ripple
    keep = sorted(records, key=lambda r: -r["relative_amplitude"] * r["transfer"])
    return {"phase_rad": [float(x) for x in amp], "u_px": float(u.max()),
            "u_px_components": [float(x) for x in u],
            "strain_per_strain": float(e.max()), "strain_ripple": float(rip.max()),
            "harmonics": [{k: v for k, v in r.items() if k != "change"}
                          for r in keep if r["relative_amplitude"] * r["transfer"]
                          > _NEGLIGIBLE],
            "sigma": float(sigma), "sharpness": [float(x) for x in sharpness],
            "observable": bool(observable), "pattern": pattern, "method": method}


def aliasing_bound_at(alias: dict, sigma: float) -> float:
    """The displacement bound ``u_px`` of :func:`aliasing_bias`'s result ``alias`` had
    the window's standard deviation been ``sigma`` px (the same harmonics, their
    transfer through the wider or narrower window)."""
    scale = alias["u_px"] / max(1e-300, _total(alias, alias["sigma"]))
    return scale * _total(alias, sigma)


def _total(alias, sigma):
    return sum(r["relative_amplitude"] * _transfer(r["fold_distance"], sigma)
               for r in alias["harmonics"])


def aliasing_advice(alias: dict, lattice, noise_px: float) -> str:
    """What brings the bound ``alias`` of :func:`aliasing_bias` below ``noise_px``: a
    larger sigma (the smallest that does, if one up to 4 times the present does), and
    otherwise, or besides, the nearest pitch at which the harmonics fold away from the
    carriers (the amplitudes measured, those not measured from a sharp print scaled
    as the measured ones)."""
    sigma = alias["sigma"]
    rec = alias["harmonics"]
    if not rec:
        return ("use a larger sigma, a pitch that is not a whole number of pixels, or a "
                "print closer to a sine (slightly defocused)")
    main = rec[0]
    n, m = main["order"]
    out = [f"the strongest, harmonic ({n}, {m}) at {main['relative_amplitude']:.2g} of the "
           f"carrier, folds {main['fold_distance']:.3g} cycles/px from carrier "
           f"k{main['carrier']}, where the window (sigma {sigma:.3g} px) passes "
           f"{main['transfer']:.0%} of it"]
    wider = [s for s in sigma * np.linspace(1.1, 4.0, 30)
             if aliasing_bound_at(alias, s) <= noise_px]
    if wider:
        s = float(wider[0])
        out.append(f"a sigma of {s:.3g} px brings it below the noise (spatial resolution "
                   f"{SPATIAL_RESOLUTION_PER_SIGMA * s:.3g} px)")
    else:
        out.append(f"a larger sigma cannot damp it (sigma {4 * sigma:.3g} px still leaves "
                   f"{aliasing_bound_at(alias, 4 * sigma):.2g} px)")
    pitch = float(np.mean(lattice.pitches))
    better = _better_pitch(alias, lattice, noise_px)
    if better is not None:
        out.append(f"a pitch of {better:.3g} px instead of {pitch:.3g} (a magnification "
                   f"{better / pitch:.3g} times the present) folds the harmonics away from "
                   "the carriers")
    out.append("a print closer to a sine (slightly defocused) lowers the harmonics "
               "themselves")
    return "; ".join(out)


def _better_pitch(alias, lattice, noise_px):
    """The pitch nearest the present (within 15 %) at which the bound, the same print
    imaged at another magnification, falls below ``noise_px``; None if none does."""
    sigma = alias["sigma"]
    amp = {(*r["order"], r["carrier"]): r["relative_amplitude"]
           for r in alias["harmonics"]}
    ks = [np.array(lattice.k1), np.array(lattice.k2)]
    sharp = [r["relative_amplitude"] / t for r in alias["harmonics"]
             if (t := _sharp_term(lattice, *r["order"], ks[r["carrier"] - 1],
                                  r["carrier"] - 1)) > 0.01]
    c = min(1.0, max(sharp)) if sharp else 1.0
    kinv = np.abs(np.linalg.inv(np.array([lattice.k1, lattice.k2])))
    for step in np.arange(0.01, 0.151, 0.01):
        for s in (1 + step, 1 - step):
            lat = dataclasses.replace(lattice, k1=tuple(ks[0] / s), k2=tuple(ks[1] / s))
            tot = np.zeros(2)
            for j, k in enumerate((ks[0] / s, ks[1] / s)):
                for n, m, _, _, d in _harmonics_near(lat, k, sigma):
                    r = amp.get((n, m, j + 1), c * _sharp_term(lat, n, m, k, j))
                    tot[j] += r * _transfer(d, sigma)
            if float(np.max(s * kinv @ (2 * tot))) / (2 * math.pi) <= noise_px:
                return float(np.mean(lattice.pitches)) * s
    return None


def _model_bound(ref, w, lattice, sigma, records) -> dict:
    """:func:`aliasing_bias` where some harmonics could not be measured: the sharp
    grid's amplitudes for those (a checkerboard's when the image is one), scaled by
    the sharpness seen on the others of the same parity.

    A line's profile sets its odd and even harmonics apart: a symmetric profile of
    half-pitch lines, or the paper's ``sin^3`` (harmonics 1 and 3), has no even ones,
    while lines 0.35 pitch wide have both. An unseen harmonic of one family is scaled
    by the sharpness seen on that family's harmonics of its parity; cross terms, or a
    parity with nothing seen, by the largest seen on any."""
    ks = [np.array(lattice.k1), np.array(lattice.k2)]
    checker = _is_checkerboard(ref, w, lattice)
    seen = [(r["relative_amplitude"] / t, _parity(*r["order"]))
            for r in records if r["measured"]
            and (t := _model_term(lattice, *r["order"], ks, r["carrier"] - 1, checker)) > 0.01]
    seen += _sharpness_elsewhere(ref, w, lattice, checker)
    c_all = max(c for c, _ in seen) if seen else 1.0
    by_parity = {p: max(c for c, q in seen if q == p) for p in (0, 1)
                 if any(q == p for _, q in seen)}
    out = []
    for r in records:
        if not r["measured"]:
            c = by_parity.get(_parity(*r["order"]), c_all)
            r = dict(r, relative_amplitude=c * _model_term(lattice, *r["order"], ks,
                                                           r["carrier"] - 1, checker))
        out.append(r)
    what = "checkerboard, 1/|n^2 - m^2|" if checker else "lines, 1/|n| 1/|m|"
    return _bound(out, lattice, sigma, observable=False,
                  pattern="checkerboard" if checker else "lines",
                  sharpness=[by_parity.get(1, c_all), by_parity.get(0, c_all)],
                  method="harmonics n k1 + m k2 folded within the window's band of a carrier, "
                         "weighted by the window's transfer; those whose fold cannot be told "
                         f"from the carrier's take a sharp print's amplitude ({what}, times "
                         "the pixel integration, scaled by the sharpness seen on the "
                         "others of their parity); twice one image's error (reference and "
                         "deformed)")


def _parity(n: int, m: int) -> int | None:
    """A harmonic of one family's parity (``n`` or ``m`` odd: 1, even: 0); None for a
    cross term."""
    return abs(n + m) % 2 if n == 0 or m == 0 else None


def _sharpness_elsewhere(ref, w, lattice, checker) -> list[tuple[float, int | None]]:
    """The print's harmonics relative to the sharp model's, where they fold away from
    the carriers, from zero and from the Nyquist lines: per fold, the amplitude seen
    there over the largest model amplitude of the harmonics that fold onto it (they
    cannot be told apart; the largest is taken to hold what is seen), with their
    parity (None when harmonics of both parities fold there)."""
    H, W = ref.shape
    scale = np.array([W, H])  # cycles/px to bins
    ks = [np.array(lattice.k1), np.array(lattice.k2)]
    a1 = 0.5 * float(np.sum(np.abs(_dtfts(ref * w, ks))))
    if not a1 > 0:
        return []
    top = int(_OPTICS_CUTOFF / min(np.hypot(*ks[0]), np.hypot(*ks[1]))) + 1
    groups: list[list] = []
    special = [np.zeros(2), *ks, -ks[0], -ks[1]]
    # one family's harmonics only: a grid of lines added rather than crossed has no
    # cross terms, and they would make it read as a sine
    for n, m in [(n, 0) for n in range(2, top + 1)] + [(0, m) for m in range(2, top + 1)]:
        h = n * ks[0] + m * ks[1]
        if np.hypot(*h) <= _OPTICS_CUTOFF:
            _group(groups, _fold(h), _model_term(lattice, n, m, ks, 0 if m == 0 else 1,
                                                 checker), special, scale, (n + m) % 2)
    kept = [(g, t, par) for g, t, par in groups if t > 0.01]
    seen = np.abs(_dtfts(ref * w, [g for g, _, _ in kept]))
    return [(float(a) / a1 / t, par) for a, (_, t, par) in zip(seen, kept, strict=True)]


def _group(groups: list, f, term, special, scale, parity: int) -> None:
    """Add the fold ``f`` of a harmonic of model amplitude ``term`` and ``parity`` to
    ``groups`` (``[fold, largest term, parity or None]``, folds within _APART bins, or
    of each other's conjugate, one group), unless it lies within 4 bins of a
    ``special`` frequency or of the Nyquist lines."""
    if min(float(np.hypot(*(_fold(f - c) * scale))) for c in special) < 4 or \
            np.any((0.5 - np.abs(f)) * scale < 4):
        return
    for g in groups:
        if min(np.hypot(*(_fold(g[0] - s * f) * scale)) for s in (1, -1)) < _APART:
            g[1] = max(g[1], term)
            if g[2] != parity:
                g[2] = None
            return
    groups.append([f, term, parity])


def _model_term(lattice, n, m, ks, j, checker) -> float:
    if not checker:
        return _sharp_term(lattice, n, m, ks[j], j)
    # a checkerboard's amplitudes are in the basis of its fundamentals; only n + m odd
    if (n + m) % 2 == 0:
        return 0.0
    h = n * ks[0] + m * ks[1]
    return _mtf(h) / _mtf(ks[j]) / abs(n * n - m * m)


def _is_checkerboard(ref, w, lattice) -> bool:
    """A checkerboard has the cross harmonics ``2 k1 + k2`` (n + m odd) but not
    ``k1 + k2`` (n + m even); crossed lines have both."""
    k1, k2 = np.array(lattice.k1), np.array(lattice.k2)
    a = np.abs(_dtfts(ref * w, [k1, k2, *(_fold(k1 + s * k2) for s in (1, -1)),
                                *(_fold(2 * k1 + s * k2) for s in (1, -1))]))
    a1 = 0.5 * (a[0] + a[1])
    if not a1 > 0:
        return False
    even, odd = max(a[2:4]) / a1, max(a[4:6]) / a1
    return bool(odd > 0.03 and even < 0.1 * odd + 0.01)


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
            # a side on the crop's border is not an edge of the specimen: the Hann
            # window fades there already
            lo, hi = (a + n if a > 0 else 0), (b - n if b < size else size)
            side = np.zeros(size)
            side[lo:max(lo, hi)] = 1.0
            sides.append(ndimage.gaussian_filter1d(side, p))
        return np.outer(hy * sides[0], hx * sides[1])
    m = ndimage.binary_erosion(m, iterations=n, border_value=1)
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
