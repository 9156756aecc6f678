"""Systematic errors the uncertainty maps do not cover: the grid's harmonics aliasing onto
the carriers (:func:`aliasing_bias`) and the window's smoothing of strain gradients
(:func:`smoothing_bias`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import ndimage

from .._validation import (
    as_image,
    check_positive,
)
from ..phase import filled_box
from ._maps import _ATTENUATION, SPATIAL_RESOLUTION_PER_SIGMA

__all__ = ["aliasing_advice", "aliasing_bias", "aliasing_bound_at", "smoothing_bias"]

# The smoothing bias's bound over its second-order estimate: Gaussian features 1.5 to
# 3 sigma wide have actual peak errors 1.25 to 2.5 times the estimate (smoothing_bias).
_SMOOTHING_FACTOR = 3.0

# The surroundings a feature's departure is taken from, in sigmas: a feature up to 3
# sigma wide (std) stands out of the median over them.
_BACKGROUND_SIGMAS = 20.0


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
    the window's band of a carrier are fitted jointly with the carrier (its amplitude
    allowed to vary linearly across the image) by weighted least squares, a Hann
    window times the mask, on the image divided by its local mean over two pitches
    (the lighting, whose variation would widen the carrier's peak over the bins where
    the folds lie). The power that noise and print defects put at every frequency,
    measured where no harmonic folds, is taken out in quadrature, and no amplitude
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

    Figures (``tests/test_aliasing.py``): one harmonic of a direct sum, its amplitude
    to 2 % and the measured error 0.8 times the bound; photographs of printed lines
    0.2 to 0.5 pitch wide at pitches 4 to 7 px turned by 0.6 degree (noise-free,
    stretched by 2 % and -0.6 %), largest errors 0.007 to 0.13 px, bounds 1.1 to 9.4
    times them; a photographed sine grid, under half the noise std.
    """
    img = as_image(image, allow_uniform=True).astype(np.float64)
    sigma = check_positive(sigma, "sigma")
    box = _central(img.shape)
    img = img[box]
    w = _aliasing_window(img.shape, lattice,
                         None if mask is None else np.asarray(mask, dtype=bool)[box])
    # the lighting divided out: the local mean over two pitches, where the grid's
    # carriers are damped by exp(-8 pi^2) below 1e-34
    inside = (w > 0).astype(np.float64)
    s = 2.0 * float(np.mean(lattice.pitches))
    light = ndimage.gaussian_filter(img * inside, s) / np.maximum(
        ndimage.gaussian_filter(inside, s), 1e-12)
    img = np.where(light > 0, img / np.where(light > 0, light, 1.0), 0.0)
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


# The smallest share of the carrier's amplitude, after the window, that counts.
_NEGLIGIBLE = 1e-4

# Largest side of the region the harmonics are measured on, px: a central crop
# resolves the folds (1 / 256 cycle/px) at a bounded cost.
_MEASURE_SIDE = 256

# A harmonic is measured when its fit's variance is at most this many times what it
# would be alone: beyond, its fold overlaps another's or the carrier's.
_INFLATION = 2.0

# Folds closer than this, in bins of the spectrum, are not told apart (the Hann
# window's main lobe is 2 bins wide each side).
_APART = 1.5

# The powers of (x, y) that multiply the carrier in the fit.
_POWERS = ((0, 0), (1, 0), (0, 1))
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
    # the carrier times 1, x, y: what the lighting's division left of its variation
    cols = [(k, c) for c in range(_CARRIER_TERMS)] + [(f, 0) for *_, f, _ in fit]
    sw = np.sqrt(w)

    def basis(f, kind):
        px, py = _POWERS[kind]
        ex = np.exp(2j * np.pi * f[0] * np.arange(W)) * xx**px
        ey = np.exp(2j * np.pi * f[1] * np.arange(H)) * yy**py
        return (sw * np.outer(ey, ex)).ravel()

    A = np.stack([basis(f, kind) for f, kind in cols], axis=1)
    b = (sw * ref).ravel()
    AH = A.conj().T
    gram = AH @ A
    # the normal equations through the Gram matrix's pseudo-inverse, which the
    # inflation needs anyway: a few columns of well-separated frequencies (those
    # closer are left out above) keep it well conditioned, and a column it cannot
    # resolve is inflated beyond _INFLATION and not taken as measured
    inv = np.linalg.pinv(gram, hermitian=True)
    coef = inv @ (AH @ b)
    inflation = np.abs(np.real(np.diag(inv))) * np.real(np.diag(gram))
    a_j = abs(coef[0])
    index = {(n, m): _CARRIER_TERMS + i for i, (n, m, *_) in enumerate(fit)}
    folds = np.array([f for *_, f, _ in fit]).reshape(-1, 2)
    out = []
    for n, m, h, f, delta in near:
        i = index.get((n, m))
        measured = bool(i is not None and inflation[i] <= _INFLATION
                        and inflation[0] <= _INFLATION and a_j > 0)
        # the sensor's noise and the print's defects add their power at every
        # frequency, and the specimen's reflectance (a hole, an edge, a stain)
        # modulates the carrier, spreading its spectrum around it: both taken out in
        # quadrature, as measured where no harmonic folds, at random frequencies and
        # on the ring of the fold's distance around the carrier
        near_floor = _ring_floor(ref, w, k, f - k, np.vstack([folds, [k]]), (W, H)) \
            if measured else 0.0
        f2 = max(floor, near_floor) / max(a_j, 1e-300) ** 2
        r = float(math.sqrt(max(0.0, abs(coef[i] / a_j) ** 2 - f2))) if measured \
            else _sharp_term(lattice, n, m, k, j)
        # a print's reflectance is not negative: none of its Fourier coefficients
        # exceeds its mean, and the pixel's integration then multiplies each by
        # mtf(h): what is fitted beyond that is the carrier's modulation, not a harmonic
        if measured:
            r = min(r, abs(mean) / a_j * _mtf(h) / _mtf(k))
        out.append({"order": [n, m], "carrier": j + 1, "relative_amplitude": r,
                    "fold_distance": delta, "transfer": _transfer(delta, sigma),
                    "change": float(np.hypot(*(h - k))), "measured": measured})
    return out


# Offsets on the ring around a carrier where the power beside a fold is measured.
_RING = 12


def _ring_floor(ref, w, k, d, avoid, size) -> float:
    """The mean power at the carrier ``k`` plus ``d`` turned by ``_RING`` angles around
    it, away (``_APART`` bins or more) from every frequency in ``avoid``: what the
    carrier's own spectrum, spread by the specimen's reflectance, puts at the fold's
    distance from it."""
    total = float(np.sum(w))
    scale = np.asarray(size, dtype=np.float64)
    powers = []
    for t in np.arange(1, _RING) * (2 * math.pi / _RING):
        c, s = math.cos(t), math.sin(t)
        f = k + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
        gaps = np.hypot(*((_fold(avoid - f)) * scale).T)
        if gaps.min() >= _APART:
            powers.append(abs(_dtft(ref, w, f) / total) ** 2)
    return float(np.mean(powers)) if powers else 0.0


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
    return float(np.mean([abs(_dtft(ref, w, f) / total) ** 2 for f in free]))


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
    a1 = 0.5 * (abs(_dtft(ref, w, ks[0])) + abs(_dtft(ref, w, ks[1])))
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
    return [(abs(_dtft(ref, w, g)) / a1 / t, par) for g, t, par in groups if t > 0.01]


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
    a1 = 0.5 * (abs(_dtft(ref, w, k1)) + abs(_dtft(ref, w, k2)))
    if not a1 > 0:
        return False
    even = max(abs(_dtft(ref, w, _fold(k1 + s * k2))) for s in (1, -1)) / a1
    odd = max(abs(_dtft(ref, w, _fold(2 * k1 + s * k2))) for s in (1, -1)) / a1
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
