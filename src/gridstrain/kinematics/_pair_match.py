"""Whether a deformed image shows the reference's specimen: its content compared with the
reference's once warped back by the measured displacement (:func:`pair_match`).

A grid's phases say how the lattice moved, not whose lattice it is: two grids of the same
pitch from two specimens give a smooth, plausible "displacement". What tells them apart
is what the grid does not carry: printing defects, the reflectance of the surface, dust
on the specimen. Below the grid's frequency the image is the grid's mean level times that
content and the lighting. With the Lagrangian convention ``ref(x) ~ def(x + u(x))``
(:mod:`gridstrain.conventions`), the deformed image warped back by the measured ``u``
shows the reference's content at the same pixels when the pair belongs together.

The statistic
-------------
``X`` and ``Y`` are the logarithms of the two images low-passed by a Gaussian of one
pitch (which removes the grid: its transfer at the grid's frequency is
``exp(-2 pi^2) = 3e-9``) and sampled every pitch, the deformed one warped back, each
less its local linear fit over :data:`_HIGH_PASS` pitches, :data:`_PASSES` times
(:class:`_HighPass`). The logarithm turns the lighting and the grid's contrast into
additive terms, and the high-pass removes them where they are smooth: a gradient of
illumination fixed to the camera, a lamp dimmed between the states. What remains is the
content at scales of one to a few pitches, and the sensor noise.

``rho`` is the correlation of ``X`` and ``Y`` over the valid pixels. The noise model
predicts the noise variances ``N_x``, ``N_y`` of ``X`` and ``Y`` (the mean images'
per-pixel variances pushed through the filters), hence the content's variances
``S = var - N`` and the correlation a matching pair shows,
``rho_match = sqrt(S_x S_y / ((S_x + N_x)(S_y + N_y)))``. ``match = rho / rho_match`` is
about 1 for a pair that belongs together and about 0 for two specimens. Its sampling
spread comes from Bartlett's formula for the correlation of two autocorrelated fields,
``Var(rho) = sum_tau C_xx(tau) C_yy(tau) / (N sum X^2 sum Y^2)`` (``C`` the
autocorrelation sums, ``N`` the pixels), ``rho_sd``, which needs no model of the
content.

The decision
------------
The check is conclusive only when both images hold content well above their noise
(``S >= 3 N``: a noise model off by a factor 2 then moves ``rho_match`` by less than 25
%) and above what a bare grid leaves below its frequency (a relative std of 2e-3: the
moire of the grid's harmonics with the pixels, 1e-4 to 2e-4, changes with the strain
and is no evidence of the specimen; absence of texture is not evidence of a foreign
specimen), and a matching pair stands clear of the thresholds below. A conclusive pair is a
mismatch when ``match < 0.5``, and nothing matches when, moreover, ``rho < 3 rho_sd``
(no correlation at all).

The false-alarm rate follows from Fisher's transformation: for a pair that belongs
together, ``atanh(rho)`` is about normal around ``atanh(rho_match)`` with the spread
``rho_sd`` (``1 / sqrt(N_eff)``, the effective number of independent samples that
Bartlett's formula counts). The check is conclusive only when ``atanh(rho_match) -
atanh(rho_match / 2) >= 5 rho_sd`` and ``rho_match >= 6 rho_sd``, so a pair that
belongs together is called a mismatch with a probability of at most ``Phi(-5) = 2.9e-7``
per state, and "nothing matches" with less (``rho_sd`` is the measured scatter
within 2 % on fields of 400 independent patches; on fields of 90, the scatter is 15 %
larger: ``Phi(-5 / 1.15) = 7e-6``). Two unrelated specimens (``rho`` about
normal around 0 with the spread ``rho_sd``) are called a mismatch with a probability of
at least ``Phi(3) = 99.87 %`` once conclusive. These rates hold for content that moves
with the specimen; what the model does not cover is the real risk: a surface that
changes its look between the states (paint flaking, a specular reflection that moves).
Content fixed to the camera (dust on the sensor, vignetting, what the high-pass
leaves of the lighting) matches the unwarped deformed image instead: a pair whose
content matches only there is inconclusive (it may be a pair moved far whose only
content is on the camera), and a mismatch needs both correlations to fail.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import ndimage

from ._grid_free import _gaussian_at, frame_weights

# The high-pass's Gaussian, in pitches: printing defects and texture of one to a few
# pitches pass; the lighting (a lamp's spot spans hundreds of periods) leaves
# (s/scale)^6 of itself after the three passes.
_HIGH_PASS = 2.0
# The high-pass applied this many times: n passes leave (s^2/2 lap)^n of the lighting's
# logarithm, its terms of degree below 2n removed.
_PASSES = 3
# Samples this many low-pass stds from a border or an invalid pixel: the low-pass of a
# grid cut by an edge departs from its mean level by about exp(-d^2 / 2 s^2) of the
# grid's contrast, 3e-4 at 4 stds.
_REACH = 4.0
# Draws of the noise through the filters (:func:`_noise_gain`): the mean of X^2 over
# N_eff independent samples each, within sqrt(2 / (3 N_eff)), 4 % for 400.
_DRAWS = 3
# Content at least this many times its noise in both images: a noise model off by a
# factor 2 moves the expected correlation by less than 25 %.
_MIN_SNR = 3.0
# ... and at least this relative std (of the logarithm, 0.2 % of the light) in both:
# what a bare grid leaves below its frequency (the moire of its harmonics with the
# pixels, the lighting the high-pass leaves) is 1e-4 to 2e-4 in nearly noise-free
# images (lines, checkerboards and sines at pitches 4 to 7 px, strain bumps of 3 to
# 20 %), and it changes with the strain: taken for content it refused true pairs.
# Printing defects, texture and stains are percents (1.0 % for blots of 5 to 20 %
# and 1.5 to 4 px).
_MIN_CONTENT = 2e-3
# A matching pair's correlation at least this many sampling spreads (in Fisher's z)
# above the mismatch threshold: the false-alarm probability is Phi(-5).
_MIN_SEPARATION = 5.0
# A conclusive pair keeping less than this fraction of the expected correlation does
# not belong together.
_MISMATCH = 0.5
# No correlation at all: below this many sampling spreads.
_NOTHING = 3.0


@dataclass(frozen=True)
class PairMatch:
    """How the deformed image's content matches the reference's after the warp.

    Attributes
    ----------
    match : float
        ``rho / rho_match``: about 1 when the pair belongs together, 0 for two
        specimens; NaN when not measurable.
    rho : float
        Correlation of the two images' content, the deformed one warped back by the
        measured displacement (or not warped, ``warped`` False, when only content
        fixed to the camera matches: the verdict is then inconclusive).
    rho_match : float
        The correlation a matching pair shows given the predicted noise.
    rho_sd : float
        Sampling spread of ``rho`` between unrelated contents (Bartlett's formula).
    snr : (float, float)
        Content variance over predicted noise variance, reference and deformed.
    conclusive : bool
        Whether both images hold enough content for the check (see the module).
    verdict : {"match", "mismatch", "nothing matches", "inconclusive", "same record"}
        ("same record": the series' frames come from one file, not compared)
    warped : bool
        Whether the figures are those of the warped image.
    """

    match: float
    rho: float
    rho_match: float
    rho_sd: float
    snr: tuple[float, float]
    conclusive: bool
    verdict: str
    warped: bool

    def as_dict(self) -> dict:
        """The record as plain numbers, for the result's file and summary."""
        d = asdict(self)
        d["snr"] = [float(v) for v in self.snr]
        return d


class _HighPass:
    """The local linear fit of a field over the samples ``w`` (Gaussian weights of std
    ``s`` samples), removed :data:`_PASSES` times (:meth:`__call__`).

    Inside the region the fit at a sample is the Gaussian average (the weights are
    symmetric), which maps a quadratic ``q`` to ``q + s^2/2 lap q``: each pass removes
    one more order of the lighting's logarithm, ``n`` passes leaving ``(s^2/2
    lap)^n``. At the region's edge a plain average would leave the gradient times the
    weights' off-centre shift; the linear fit leaves none. The fit's matrix depends on
    the region alone: inverted once for every field."""

    def __init__(self, w: np.ndarray, s: float):
        self.w, self.s = w, s
        H, W = w.shape
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
        self.yy, self.xx = yy - H / 2, xx - W / 2
        xx, yy, g = self.xx, self.yy, self._g
        wf = w.astype(np.float64)
        # the weighted moments about each sample, from those about the origin
        m0, mx, my = g(wf), g(wf * xx), g(wf * yy)
        cx, cy = mx - xx * m0, my - yy * m0
        cxx = g(wf * xx * xx) - 2 * xx * mx + xx * xx * m0
        cxy = g(wf * xx * yy) - xx * my - yy * mx + xx * yy * m0
        cyy = g(wf * yy * yy) - 2 * yy * my + yy * yy * m0
        # a sample with too few neighbours to fit a slope (a thin strip, an isolated
        # sample) gets a slope of nearly zero, not a singular system
        cxx = cxx + 1e-6 * s * s * m0
        cyy = cyy + 1e-6 * s * s * m0
        M = np.stack([np.stack([m0, cx, cy], -1), np.stack([cx, cxx, cxy], -1),
                      np.stack([cy, cxy, cyy], -1)], -2)
        M[~w] = np.eye(3)
        self.row = np.linalg.inv(M)[..., 0, :]  # the fit's value: the first unknown

    def _g(self, f: np.ndarray) -> np.ndarray:
        return ndimage.gaussian_filter(f, self.s, mode="constant")

    def __call__(self, a: np.ndarray) -> np.ndarray:
        xx, yy, g, w = self.xx, self.yy, self._g, self.w
        out = np.where(w, a, 0.0)
        for _ in range(_PASSES):
            f0, fx, fy = g(out), g(out * xx), g(out * yy)
            fit = (self.row[..., 0] * f0 + self.row[..., 1] * (fx - xx * f0)
                   + self.row[..., 2] * (fy - yy * f0))
            out = np.where(w, out - fit, 0.0)
        return out


def _low_pass(a: np.ndarray, m: np.ndarray, s: float, q: int = 1) -> np.ndarray:
    """Gaussian average of std ``s`` of ``a`` over the pixels ``m`` (normalised),
    sampled every ``q`` px: each axis filtered, then decimated, before the other."""

    def smooth(f):
        # along the rows first, where the pixels are contiguous, on the whole frame;
        # then along the columns, on the q times fewer columns kept and summed at the
        # rows kept only (the same bits: _gaussian_at)
        f = ndimage.gaussian_filter1d(f, s, axis=1, mode="constant")[:, ::q]
        return _gaussian_at(f, s, q, 0)

    if m.all():
        return smooth(a) / frame_weights(m.shape, s, q)
    return smooth(np.where(m, a, 0.0)) / np.maximum(smooth(m.astype(np.float64)), 1e-12)


def _noise_gain(high_pass: _HighPass, s1: float, q: int) -> float:
    """Mean of ``X^2`` over the samples for a pixel noise of unit variance: the noise
    low-passed by the Gaussian of std ``s1`` px and sampled every ``q`` px is a
    Gaussian field of variance ``1 / (4 pi s1^2)`` and covariance ``exp(-d^2 / 4
    s1^2)``, drawn here as white noise on the samples smoothed by a Gaussian of std
    ``s1 / q`` samples, and put through ``high_pass`` (whose linear fits, at the
    region's edges, remove more noise than in its interior). :data:`_DRAWS` draws of a
    fixed seed: the result does not depend on the run."""
    g = s1 / q
    kernel = np.exp(-0.5 * (np.arange(-int(4 * g + 1), int(4 * g + 1) + 1) / g) ** 2)
    kernel /= kernel.sum()
    scale = math.sqrt(1 / (4 * math.pi * s1 * s1)) / float(np.sum(kernel**2))
    rng = np.random.default_rng(0)
    w = high_pass.w
    total = 0.0
    for _ in range(_DRAWS):
        z = ndimage.gaussian_filter(rng.standard_normal(w.shape), g, mode="wrap")
        total += float(np.mean(high_pass(scale * z)[w] ** 2))
    return total / _DRAWS


def _bartlett_sd(x: np.ndarray, y: np.ndarray, w: np.ndarray, reach: int) -> float:
    """Sampling spread of the correlation of ``x`` and ``y`` (zero outside ``w``)
    between unrelated fields: autocorrelations summed over lags up to ``reach``."""
    H, W = x.shape
    shape = (2 * H, 2 * W)

    def acf(a):
        f = np.fft.rfft2(a, shape)
        c = np.fft.irfft2(np.abs(f) ** 2, shape)
        r = min(reach, H - 1, W - 1)
        rows = np.r_[0:r + 1, shape[0] - r:shape[0]]
        cols = np.r_[0:r + 1, shape[1] - r:shape[1]]
        return c[np.ix_(rows, cols)]

    n = int(w.sum())
    sxx, syy = float(np.sum(x**2)), float(np.sum(y**2))
    if n < 2 or sxx <= 0 or syy <= 0:
        return math.nan
    return math.sqrt(max(float(np.sum(acf(x) * acf(y))), 0.0) / (n * sxx * syy))


def pair_match(reference, deformed, u, valid, *, pitch: float, noise,
               mask=None) -> PairMatch:
    """Whether ``deformed`` shows the specimen of ``reference`` (see the module).

    Parameters
    ----------
    reference, deformed : (H, W) array_like
        The two (mean) images, grey levels.
    u : (2, H, W) array_like
        The measured displacement ``(u_x, u_y)``, px, Lagrangian: the reference's pixel
        ``x`` is seen at ``x + u(x)`` in ``deformed``.
    valid : (H, W) bool array_like
        Where ``u`` is measured (the reference's mask within it).
    pitch : float
        The grid's largest pitch, px: the low-pass's std.
    noise : (float, float)
        Per-pixel noise variance of ``reference`` and of ``deformed``, grey levels^2
        (a frame's variance over the number of frames averaged); NaN when unknown.
    mask : (H, W) bool array_like, optional
        The specimen's pixels in ``reference`` (default: all): the content is
        low-passed over them alone.

    Returns
    -------
    PairMatch
    """
    ref = np.asarray(reference, dtype=np.float64)
    cur = np.asarray(deformed, dtype=np.float64)
    v = np.asarray(valid, dtype=bool)
    H, W = ref.shape
    s1 = float(pitch)
    # the low-passed content is sampled every pitch: the low-pass's transfer at the
    # samples' Nyquist frequency is exp(-pi^2 / 2) = 0.007
    q = max(1, int(s1))
    none = PairMatch(math.nan, math.nan, math.nan, math.nan, (math.nan, math.nan), False,
                     "inconclusive", True)
    if not v.any() or not all(math.isfinite(n) and n > 0 for n in noise):
        return none
    m = np.ones(v.shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    low_r = _low_pass(ref, m, s1, q)
    low_d = _low_pass(cur, np.ones(cur.shape, dtype=bool), s1, q)
    yy, xx = np.mgrid[0:H:q, 0:W:q].astype(np.float64)
    # u at the samples; where it is not measured the sample is not used (w below)
    vq = v[::q, ::q]
    ux = np.where(vq, np.asarray(u[0])[::q, ::q], 0.0)
    uy = np.where(vq, np.asarray(u[1])[::q, ::q], 0.0)
    yw, xw = yy + uy, xx + ux
    # a sample is used where u is measured and its warped point inside the frame, both
    # _REACH low-pass stds from what the low-pass did not see or must not see (the
    # frame's borders, the pixels off the specimen: a hole's dark background)
    d = _REACH * s1
    # (the distance on the samples, q px apart: within q px of the pixels')
    inner = q * ndimage.distance_transform_edt(np.pad(m[::q, ::q], 1))[1:-1, 1:-1] > d + q
    w = inner & vq & (yw >= d) & (yw <= H - 1 - d) & (xw >= d) & (xw <= W - 1 - d)
    if w.sum() < 16:
        return none
    # the samples are a pitch apart, where the low-pass leaves 0.7 % at their Nyquist
    # frequency: a cubic spline interpolates them to about 1e-3 of the content
    low_w = ndimage.map_coordinates(low_d, [yw / q, xw / q], order=3, mode="nearest")
    low_f = low_d
    floor = 1.0  # a grey level: the logarithm of a black pixel stays finite
    s2q = _HIGH_PASS * s1 / q
    high_pass = _HighPass(w, s2q)
    x = high_pass(np.log(np.maximum(low_r, floor)))
    ys = {warped: high_pass(np.log(np.maximum(a, floor)))
          for warped, a in ((True, low_w), (False, low_f))}
    n = float(w.sum())
    gain = _noise_gain(high_pass, s1, q)
    # relative noise of a low-passed level l: Var / l^2, through the filters
    nx = gain * noise[0] * float(np.mean(1.0 / np.maximum(low_r[w], floor) ** 2))
    ny = gain * noise[1] * float(np.mean(1.0 / np.maximum(low_w[w], floor) ** 2))
    vx = float(np.sum(x**2)) / n
    reach = math.ceil(4 * (s2q + s1 / q))
    found = {}
    for warped, y in ys.items():
        vy = float(np.sum(y**2)) / n
        sx, sy = max(vx - nx, 0.0), max(vy - ny, 0.0)
        rho = float(np.sum(x * y)) / math.sqrt(max(vx * vy, 1e-300)) / n
        rho_match = math.sqrt(sx * sy / ((sx + nx) * (sy + ny)))
        sd = _bartlett_sd(x, y, w, reach)
        gap = math.atanh(min(rho_match, 1 - 1e-12)) - math.atanh(_MISMATCH * rho_match)
        conclusive = bool(sx >= _MIN_SNR * nx and sy >= _MIN_SNR * ny
                          and min(sx, sy) >= _MIN_CONTENT**2 and math.isfinite(sd)
                          and sd > 0 and gap >= _MIN_SEPARATION * sd
                          and rho_match >= 2 * _NOTHING * sd)
        match = rho / rho_match if rho_match > 0 else math.nan
        found[warped] = (match, rho, rho_match, sd, (sx / nx, sy / ny), conclusive)
    match, rho, rho_match, sd, snr, conclusive = found[True]
    warped = True
    if not conclusive:
        verdict = "inconclusive"
    elif match >= _MISMATCH:
        verdict = "match"
    elif found[False][0] >= _MISMATCH:
        # the content matches where it was, not where the specimen took it: content
        # fixed to the camera, which says nothing of the specimen
        match, rho, rho_match, sd, snr, _ = found[False]
        verdict, warped, conclusive = "inconclusive", False, False
    elif rho < _NOTHING * sd and found[False][1] < _NOTHING * found[False][3]:
        verdict = "nothing matches"
    else:
        verdict = "mismatch"
    return PairMatch(float(match), float(rho), float(rho_match), float(sd),
                     (float(snr[0]), float(snr[1])), conclusive, verdict, bool(warped))
