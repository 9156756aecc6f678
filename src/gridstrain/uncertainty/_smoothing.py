"""The window's smoothing of strain gradients: a systematic error the uncertainty maps
do not cover (:func:`smoothing_bias`), estimated from the measured field.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from .._validation import check_positive
from ._maps import _ATTENUATION

__all__ = ["smoothing_bias"]

# The smoothing bias's bound over its second-order estimate: Gaussian features 1.5 to
# 3 sigma wide have actual peak errors 1.25 to 2.5 times the estimate (smoothing_bias).
_SMOOTHING_FACTOR = 3.0

# The surroundings a feature's departure is taken from, in sigmas: a feature up to 3
# sigma wide (std) stands out of the median over them.
_BACKGROUND_SIGMAS = 20.0

def smoothing_bias(strain, valid, *, sigma: float, keep: list | None = None) -> dict:
    """The window's smoothing of strain gradients, estimated from the measured field.

    Parameters
    ----------
    strain : (3, H, W) array_like
        Measured ``(e_xx, e_yy, e_xy)``, NaN where not valid.
    valid : (H, W) bool array_like
    sigma : float
        Window standard deviation, px.
    keep : list of one item, optional
        Held by a caller that estimates fields of one valid region again and again (a
        record's states): the edge fit's solved normal equations, half of this
        function's time, are kept in it and used again while the region, the window
        and the decimation are the same (``[None]`` to start; the records are the
        same as without it).

    Returns
    -------
    dict
        Per component ``(e_xx, e_yy, e_xy)``, dimensionless:

        - ``max`` (3,): the bound on the window's bias, ``factor`` times the largest
          ``|sigma^2 / 2 lap(e)|`` over the valid pixels;
        - ``estimate_max`` and ``p95`` (3,): the largest value and the 95th
          percentile of ``|sigma^2 / 2 lap(e)|`` itself;
        - ``attenuation`` (3,): the fraction by which the window lowers the peak
          where the estimate is largest, ``feature_error / (|departure| +
          feature_error)``, with the
          departure the measured strain's from its median over 20 sigma around
          (meaningful where ``max`` stands above the noise);
        - ``feature_error`` (3,): the peak error of the Gaussian feature whose
          departure and curvatures the smoothed field shows there (see Notes);
        - ``below_resolution`` (3,) bool: a feature is seen (the estimate's peak
          stands 8 times above its median over the map, and above 1e-6) and its
          peak is lowered by more than 10 %, the attenuation that defines the
          spatial resolution (:func:`metrology`), or it is narrower than 0.7 sigma;

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
    independent images). That estimate times ``factor = 3`` bounds features from
    about ``1.2 sigma`` (band) or ``1.6 sigma`` (bump) up, 3 times the error for wide
    ones. Narrower ones are deconvolved: where the estimate peaks, the departure of
    the twice-smoothed field from its surroundings and its curvatures along the
    Hessian's principal directions give a Gaussian feature's width along each
    (``s2^2 = -departure / curvature = w^2 + 2 sigma^2``; a direction with no
    curvature is a band's) and its peak error (:func:`_feature_error`); the bound
    ``max`` is the larger of the two, 1.5 times that error. On noise-free
    independent images (``tests/test_bounds.py``) the feature error is 0.92 to
    1.2 times the actual peak error for bands and bumps 0.7 to 5 sigma wide, and
    the bound 1.4 to 2.8 times it. A feature narrower than 0.7 sigma is taken as
    one of 0.7 sigma, which it may exceed: ``below_resolution`` says so. Noise adds
    to the largest value: about 1.1 times the strain noise std on a uniform field,
    so a bound below ~3.5 noise std is noise.

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
    p95, mx, att, model, below = [], [], [], [], []
    wsum = ndimage.gaussian_filter(v.astype(np.float64), sig)
    np.maximum(wsum, 1e-12, out=wsum)
    ii, jj = np.nonzero(inner)
    half = round(_BACKGROUND_SIGMAS * sig / 2)
    # the edge fit's normal equations depend on the valid pixels only: solved once for
    # the three components (their SVDs were most of this function's time)
    fit = _EdgeFit(v, inner, sig, keep) if np.any(v & ~inner) else None
    for c in e:
        filled = np.where(v, c, 0.0)
        sm = np.divide(ndimage.gaussian_filter(filled, sig), wsum, out=filled)
        lap = ndimage.laplace(sm)
        b = lap[inner] if inner.any() else np.array([])
        del lap
        b *= 0.5 * sig**2  # sigma^2 / 2 times the Laplacian per px^2 (samples of s px)
        np.abs(b, out=b)
        p95.append(float(np.percentile(b, 95)) if b.size else math.nan)
        mx.append(float(b.max()) if b.size else math.nan)
        if not b.size:
            att.append(math.nan)
            model.append(math.nan)
            below.append(False)
            continue
        # the feature where the estimate peaks: its departure from the surroundings
        # and its curvatures, from which a Gaussian feature's width and its error
        i, j = ii[int(np.argmax(b))], jj[int(np.argmax(b))]
        box = (slice(max(0, i - half), i + half + 1), slice(max(0, j - half), j + half + 1))
        level = float(np.median(c[box][v[box]]))
        dep = float(c[i, j]) - level
        err, narrow = _feature_error(sm, i, j, float(sm[i, j]) - level, sig)
        a = err / (abs(dep) + err) if err > 0 else 0.0
        # detected: the estimate's peak stands out of its typical level (noise alone
        # puts the largest of a map's values at about 6 times their median)
        typical = max(_DETECT * float(np.median(b)), _SMALLEST)
        seen = mx[-1] > typical
        # a feature at the valid region's edge (a hole's, the frame's) peaks where the
        # twice-smoothed field is cut: taken from the measured field itself there
        edge = _edge_feature(c, v, fit, sig, half) if fit is not None else None
        if edge is not None and edge[0] > err and edge[3] > typical:
            err, narrow, a, _ = edge
            seen = True
        # a feature not seen is noise, whose curvatures make no feature: the bound
        # is then the Laplacian term's alone
        model.append(err if seen else 0.0)
        att.append(a)
        below.append(bool(seen and (narrow or a > _ATTENUATION)))

    def clean(v):
        return [x if math.isfinite(x) else None for x in v]

    bound = [max(_SMOOTHING_FACTOR * x, _FEATURE_MARGIN * y) for x, y in zip(mx, model,
                                                                        strict=True)]
    return {"max": clean(bound), "estimate_max": clean(mx), "p95": clean(p95),
            "feature_error": clean(model), "attenuation": clean(att),
            "below_resolution": below,
            "factor": _SMOOTHING_FACTOR,
            "definition": "max: a bound on the window's smoothing bias, the larger of "
                          "factor x the largest |sigma^2/2 laplacian(e)| of the measured "
                          "strain smoothed by the window, over the valid pixels, and "
                          f"{_FEATURE_MARGIN:g} x the peak error of the Gaussian feature "
                          "whose departure and curvatures the smoothed strain shows where "
                          "that term peaks (feature_error, its width taken at least "
                          f"{_NARROWEST:g} sigma); estimate_max, p95: the Laplacian term"}


class _EdgeFit:
    """The weighted least-squares quadratic fit on the band of valid pixels outside
    ``inner`` (see :func:`_edge_feature`), for any field on those pixels: the moments
    of the valid pixels are filtered separably, and each band pixel's 6 x 6 normal
    equations inverted once where they are well conditioned. ``keep`` (a one-item
    list, or None): the solved equations of the last region given with it (its
    decimated valid pixels, band and window), used again for the same region: the
    states of a record share their valid region, and solving them is half of
    :func:`smoothing_bias`'s time (8.7 of 16.4 ms on a 250 x 400 state at sigma = 5
    px); read-only, its inverse 6 x 6 matrices 288 bytes a pixel of the band."""

    _POWERS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))

    def __init__(self, v: np.ndarray, inner: np.ndarray, sig: float,
                 keep: list | None = None):
        self.v = v
        self.band = v & ~inner
        r = _EDGE_FIT * sig
        self.t = np.arange(-math.ceil(4 * r), math.ceil(4 * r) + 1, dtype=np.float64)
        self.g = np.exp(-0.5 * (self.t / r) ** 2)
        self._at = _band_taps(self.band, len(self.t) // 2)
        last = keep[0] if keep is not None else None
        if last is not None and last[0] == sig and last[1].shape == v.shape \
                and np.array_equal(last[1], v) and np.array_equal(last[2], self.band):
            self.ok, self.inv, self.bi, self.bj = last[3]
            return
        vf = v.astype(np.float64)
        mom = self.moments(vf, [(a, b) for a in range(5) for b in range(5 - a)])
        P = self._POWERS
        M = np.stack([np.stack([mom[p[0] + q[0], p[1] + q[1]] for q in P], axis=-1)
                      for p in P], axis=-2)  # (n, 6, 6)
        # symmetric and positive semi-definite: its condition number is the ratio of
        # its extreme eigenvalues (eigvalsh costs a fraction of cond's SVD)
        lam = np.linalg.eigvalsh(M)
        with np.errstate(divide="ignore", invalid="ignore"):
            self.ok = lam[:, -1] < 1e8 * lam[:, 0]
        self.inv = np.linalg.inv(M[self.ok]) if self.ok.any() else None
        bi, bj = np.nonzero(self.band)
        self.bi, self.bj = bi[self.ok], bj[self.ok]
        solved = (self.ok, self.inv, self.bi, self.bj)
        for a in solved:
            if a is not None:
                a.flags.writeable = False
        if keep is not None:
            keep[0] = (sig, v.copy(), self.band.copy(), solved)

    def moments(self, f, powers) -> dict:
        """``{(a, b): m}``: the moments ``sum g(s) g(t) s^a t^b f(i + t, j + s)`` (``s``
        along the rows, ``t`` down the columns; zero beyond the frame) at the band
        pixels, for each ``(a, b)`` of ``powers``: separable, the sums along the rows
        taken only where the sums down the columns need them."""
        def taps(p):
            return self.g * self.t**p

        if self._at is None:  # a band that is most of the map: whole-map filters
            rows = {a: ndimage.correlate1d(f, taps(a), axis=1, mode="constant")
                    for a in {a for a, _ in powers}}
            return {(a, b): ndimage.correlate1d(rows[a], taps(b), axis=0,
                                                mode="constant")[self.band]
                    for a, b in powers}
        first = sorted({a for a, _ in powers})
        rows = self._at.along_rows(f, np.stack([taps(a) for a in first], axis=1))
        out = {}
        for k, a in enumerate(first):
            second = [b for a2, b in powers if a2 == a]
            cols = self._at.down_columns(rows[:, k], np.stack([taps(b) for b in second],
                                                              axis=1))
            out.update({(a, b): cols[:, n] for n, b in enumerate(second)})
        return out

    def coefficients(self, c: np.ndarray) -> np.ndarray:
        """``(n, 6)``: the fitted quadratic's coefficients at the well-conditioned band
        pixels."""
        mf = np.where(self.v, c, 0.0)
        mom = self.moments(mf, self._POWERS)
        rhs = np.stack([mom[p] for p in self._POWERS], axis=-1)[self.ok]
        return np.einsum("nij,nj->ni", self.inv, rhs)


def _band_taps(band: np.ndarray, R: int):
    """:class:`_BandTaps` of ``band``, or None where the band and the pixels within
    ``R`` rows of it are more than an eighth of the map (whole-map filters then: the
    gathers hold ``2 R + 1`` values a pixel, and a thin band, a frame's or a hole's
    edge, is a few percent of it)."""
    need = ndimage.binary_dilation(band, structure=np.ones((2 * R + 1, 1), bool))
    if 8 * np.count_nonzero(need) > band.size:
        return None
    return _BandTaps(band, need, R)


class _BandTaps:
    """A separable filter of ``2 R + 1`` taps along each axis (zero beyond the frame)
    evaluated at the pixels of ``band`` alone: the sums along the rows at the pixels
    within ``R`` rows of the band, then those down the columns at the band's own. The
    band along the valid region's edge is a thin part of the map, and the sums a few
    percent of the whole-map filters' (:func:`_band_taps`)."""

    def __init__(self, band: np.ndarray, need: np.ndarray, R: int):
        H, W = band.shape
        self.shape, self.R = (H, W), R
        off = np.arange(-R, R + 1)
        self.ni, self.nj = np.nonzero(need)
        # flat indices into the map padded by R zeros on each side of its rows
        self.rows = (self.ni * (W + 2 * R) + self.nj + R)[:, None] + off[None, :]
        bi, bj = np.nonzero(band)
        # ... and into the first sums' map padded by R zero rows above and below
        self.cols = ((bi + R) * W + bj)[:, None] + (off * W)[None, :]

    def along_rows(self, f: np.ndarray, taps: np.ndarray) -> np.ndarray:
        """``(n_need, k)``: ``f`` (H, W) filtered along its rows by each column of
        ``taps`` (2 R + 1, k) at the pixels the second sums need."""
        R = self.R
        return np.pad(f, ((0, 0), (R, R))).ravel()[self.rows] @ taps

    def down_columns(self, h: np.ndarray, taps: np.ndarray) -> np.ndarray:
        """``(n_band, k)``: the first sums ``h`` (n_need,) filtered down the columns
        by each column of ``taps`` (2 R + 1, k) at the band pixels."""
        H, W = self.shape
        full = np.zeros((H + 2 * self.R, W))
        full[self.ni + self.R, self.nj] = h
        return full.ravel()[self.cols] @ taps


def _edge_feature(c, v, fit: _EdgeFit, sig, half):
    """``(error, narrow, attenuation, estimate)`` of the Gaussian feature that the
    measured field ``c`` (samples; ``v`` its valid pixels) shows on the band of
    ``fit`` (the valid pixels along the valid region's edge), or None.

    The field is not smoothed again there (the window would be cut by the edge): a
    quadratic is fitted at each pixel of the band by least squares over its valid
    neighbours, weighted by a Gaussian of ``_EDGE_FIT`` sigma (one-sided where the
    edge cuts it: :class:`_EdgeFit`). Where ``sigma^2 / 2`` times the fitted
    Laplacian peaks, the fitted value's departure from the median over ``half``
    samples around and the fitted curvatures give a Gaussian feature of the measured
    field, of width ``s^2 = w^2 + sigma^2`` along each principal direction, and its
    peak error ``dep (prod(s / w) - 1)``."""
    if fit.inv is None:
        return None
    coef = fit.coefficients(c)
    est = 0.5 * sig**2 * np.abs(2 * (coef[:, 3] + coef[:, 5]))
    k = int(np.argmax(est))
    i, j = fit.bi[k], fit.bj[k]
    box = (slice(max(0, i - half), i + half + 1), slice(max(0, j - half), j + half + 1))
    level = float(np.median(c[box][v[box]]))
    dep = float(coef[k, 0]) - level
    hess = _log_curvatures(c - level, v, i, j, dep, sig)
    if hess is None:
        return None
    narrow, inflate = False, 1.0
    for lm in np.linalg.eigvalsh(hess):
        ssq = -1.0 / lm if lm < 0 else math.inf
        if not ssq > 0 or not math.isfinite(ssq):
            continue
        wsq = ssq - sig**2
        if wsq < (_NARROWEST * sig) ** 2:
            narrow = True
            wsq = (_NARROWEST * sig) ** 2
            ssq = wsq + sig**2
        inflate *= math.sqrt(ssq / wsq)
    err = abs(dep) * (inflate - 1.0)
    # its estimate, or nothing where it does not stand out of the band's own (the
    # fit on the measured field is noisier than the field smoothed again)
    seen = float(est[k]) if est[k] > _DETECT * float(np.median(est)) else 0.0
    return err, narrow, (err / (abs(dep) + err) if err > 0 else 0.0), seen


def _log_curvatures(d, v, i, j, dep, sig):
    """The Hessian of ``ln |d|`` at ``(i, j)``, a quadratic fitted by least squares to
    the valid pixels within 2 sigma where ``d`` has ``dep``'s sign and exceeds a
    fifth of ``|dep|``: a Gaussian feature ``exp(-x^2 / 2 s^2)`` along a principal
    direction is a parabola of curvature ``-1 / s^2`` there, whatever the fit's
    extent (a quadratic fitted to the feature itself flattens it). None when too few
    pixels."""
    H, W = d.shape
    rad = math.ceil(2 * sig)
    r0, r1, c0, c1 = max(0, i - rad), min(H, i + rad + 1), max(0, j - rad), min(W, j + rad + 1)
    dy, dx = np.mgrid[r0 - i:r1 - i, c0 - j:c1 - j].astype(np.float64)
    val = d[r0:r1, c0:c1] * math.copysign(1.0, dep)
    use = v[r0:r1, c0:c1] & (val > 0.2 * abs(dep)) & (dx**2 + dy**2 <= (2 * sig) ** 2)
    if np.count_nonzero(use) < 12:
        return None
    x, y = dx[use], dy[use]
    A = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=1)
    coef = np.linalg.lstsq(A, np.log(val[use]), rcond=None)[0]
    return np.array([[2 * coef[3], coef[4]], [coef[4], 2 * coef[5]]])


# The Gaussian weights of the quadratic fitted at the valid region's edge, in sigmas.
_EDGE_FIT = 0.75

# The bound over the Gaussian feature's peak error (feature_error), for features of
# other shapes and the noise on the curvatures (tests/test_bounds.py).
_FEATURE_MARGIN = 1.5

# The narrowest feature, in sigmas, whose error the bound covers: one whose smoothed
# image is narrower than that of a Gaussian feature of this width is taken as one, and
# below_resolution says so.
_NARROWEST = 0.7

# A feature is taken as seen where the smoothing estimate's peak exceeds this many
# times the estimate's median over the map, and _SMALLEST (a strain no measurement
# resolves).
_DETECT = 8.0
_SMALLEST = 1e-6


def _feature_error(sm, i, j, dep, sig) -> tuple[float, bool]:
    """The peak error of the window's smoothing for the Gaussian feature whose image
    ``sm`` (the measured field smoothed once more, in samples) shows the departure
    ``dep`` and the curvatures (the Hessian's eigenvalues) at ``(i, j)``, with ``sig``
    the window's sigma in samples; and whether that feature is narrower than
    ``_NARROWEST`` sigma (its width then taken as that).

    A feature ``A exp(-x^2 / 2 w^2)`` along each principal direction (a band along
    one, a bump along both) is measured as ``g * e``, of width ``s^2 = w^2 + sigma^2``
    and peak ``A prod(w / s)``; smoothed again, ``s2^2 = w^2 + 2 sigma^2``, peak
    ``A prod(w / s2)`` and curvature ``-peak / s2^2`` along each direction: the
    curvature and the departure give ``s2``, hence ``w``, and the error at the peak,
    ``A (1 - prod(w / s)) = dep prod(s2 / w) - dep prod(s2 / s)``. A direction with no
    curvature of the peak's sign is flat (a band): its factors are 1."""
    H, W = sm.shape
    if not (0 < i < H - 1 and 0 < j < W - 1) or dep == 0:
        return 0.0, False
    dxx = sm[i, j + 1] - 2 * sm[i, j] + sm[i, j - 1]
    dyy = sm[i + 1, j] - 2 * sm[i, j] + sm[i - 1, j]
    dxy = 0.25 * (sm[i + 1, j + 1] - sm[i + 1, j - 1] - sm[i - 1, j + 1]
                      + sm[i - 1, j - 1])
    hess = np.array([[dxx, dxy], [dxy, dyy]])
    lam = np.linalg.eigvalsh(hess)
    narrow = False
    inflate, keep = 1.0, 1.0
    for lm in lam:
        s2sq = -dep / lm if lm != 0 else math.inf
        if not s2sq > 0 or not math.isfinite(s2sq):
            continue  # flat, or curving away from the peak: a band's direction
        wsq = s2sq - 2 * sig**2
        if wsq < (_NARROWEST * sig) ** 2:
            narrow = True
            wsq = (_NARROWEST * sig) ** 2
            s2sq = wsq + 2 * sig**2
        inflate *= math.sqrt(s2sq / wsq)
        keep *= math.sqrt(s2sq / (wsq + sig**2))
    return abs(dep) * (inflate - keep), narrow
